/* A hand-written C EKF of the 9-state aircraft (models/aircraft.py's output_error_model: body
   velocities, rates and Euler angles driven by the controls, twelve measured outputs), the C of
   aircraft_ekf_peer.py: the right-hand side of Eq. 6.16-6.22 with its 9 x 9 Jacobian derived by
   hand, RK4 with its tangent, the inputs linear between samples, the trapezoidal discrete process
   noise, and the Joseph update with a Cholesky factor of the 12 x 12 innovation covariance; loops
   over fixed-size arrays, no allocation. bench_export_c.py checks its states against the
   generated code's. */
#include <math.h>
#include <string.h>
#include "hand.h"

#define NX 9
#define NY 12


void hand_aircraft_init(hand_aircraft_t *s, double dt, const double *c, const double *bias, const double *Qc,
                        const double *R, const double *x0, const double *P0, const double *frame) {
  airframe_t *af = &s->af;
  af->G = frame[0]; af->rho = frame[1]; af->S = frame[2]; af->b = frame[3]; af->cbar = frame[4]; af->m = frame[5];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) { af->I[i][j] = frame[6 + 3 * i + j]; af->Iinv[i][j] = frame[15 + 3 * i + j]; }
  s->dt = dt;
  memcpy(s->c, c, sizeof s->c);
  memcpy(s->bias, bias, sizeof s->bias);
  memcpy(s->Qc, Qc, sizeof s->Qc);
  memcpy(s->R, R, sizeof s->R);
  memcpy(s->x, x0, sizeof s->x);
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NX; ++j) s->P[i][j] = P0[i + NX * j];
}

/* f (9) and its Jacobian A (9 x 9) at (x, uc); FM (6) the specific forces and moments' right-hand
   sides and dFM (6 x 9) their gradients. */
static void aero(const airframe_t *af, const double *x, const double *uc, const double *c, double *f, double A[NX][NX],
                 double *FM, double dFM[6][NX]) {
  const double G = af->G, rho = af->rho, S = af->S, b = af->b, cbar = af->cbar, m = af->m;
  double u = x[0], v = x[1], w = x[2], p = x[3], q = x[4], r = x[5], phi = x[6], th = x[7];
  double de = uc[0], da = uc[1], dr = uc[2], Tc = uc[3];
  double V2 = u * u + v * v + w * w, V = sqrt(V2), uw2 = u * u + w * w;
  double alpha = atan2(w, u), s = v / V, beta = asin(s);
  double dV[3] = {u / V, v / V, w / V}, dal[3] = {-w / uw2, 0.0, u / uw2};
  double k = 1.0 / sqrt(1.0 - s * s), V3 = V2 * V;
  double dbe[3] = {-k * v * u / V3, k * (1.0 / V - v * v / V3), -k * v * w / V3};
  double qn = q * cbar / V, pn = p * b / (2.0 * V), rn = r * b / (2.0 * V);
  double coef[6], dC[6][6], scale[6] = {1.0 / m, 1.0 / m, 1.0 / m, b, cbar, b};
  coef[0] = c[0] + c[1] * alpha + c[2] * alpha * alpha + c[3] * qn + c[4] * de + c[5] * Tc;
  coef[1] = c[6] + c[7] * beta + c[8] * pn + c[9] * rn + c[10] * da + c[11] * dr;
  coef[2] = c[12] + c[13] * alpha + c[14] * qn + c[15] * de;
  coef[3] = c[16] + c[17] * beta + c[18] * pn + c[19] * rn + c[20] * da + c[21] * dr;
  coef[4] = c[22] + c[23] * alpha + c[24] * qn + c[25] * de;
  coef[5] = c[26] + c[27] * beta + c[28] * pn + c[29] * rn + c[30] * da + c[31] * dr;
  memset(dC, 0, sizeof dC);  /* columns alpha, beta, V, p, q, r */
  dC[0][0] = c[1] + 2.0 * c[2] * alpha; dC[0][2] = -c[3] * qn / V; dC[0][4] = c[3] * cbar / V;
  dC[1][1] = c[7]; dC[1][2] = -(c[8] * pn + c[9] * rn) / V; dC[1][3] = c[8] * b / (2.0 * V); dC[1][5] = c[9] * b / (2.0 * V);
  dC[2][0] = c[13]; dC[2][2] = -c[14] * qn / V; dC[2][4] = c[14] * cbar / V;
  dC[3][1] = c[17]; dC[3][2] = -(c[18] * pn + c[19] * rn) / V; dC[3][3] = c[18] * b / (2.0 * V);
  dC[3][5] = c[19] * b / (2.0 * V);
  dC[4][0] = c[23]; dC[4][2] = -c[24] * qn / V; dC[4][4] = c[24] * cbar / V;
  dC[5][1] = c[27]; dC[5][2] = -(c[28] * pn + c[29] * rn) / V; dC[5][3] = c[28] * b / (2.0 * V);
  dC[5][5] = c[29] * b / (2.0 * V);
  double qS = 0.5 * rho * V2 * S, dqS = rho * V * S;
  for (int i = 0; i < 6; ++i) {
    for (int j = 0; j < NX; ++j) dFM[i][j] = 0.0;
    FM[i] = qS * coef[i] * scale[i];
    for (int j = 0; j < 3; ++j) {
      double dCj = dC[i][0] * dal[j] + dC[i][1] * dbe[j] + dC[i][2] * dV[j];
      dFM[i][j] = (dqS * dV[j] * coef[i] + qS * dCj) * scale[i];
    }
    for (int j = 0; j < 3; ++j) dFM[i][3 + j] = qS * dC[i][3 + j] * scale[i];
  }
  double sph = sin(phi), cph = cos(phi), sth = sin(th), cth = cos(th);
  memset(A, 0, sizeof(double) * NX * NX);
  f[0] = FM[0] - q * w + r * v - G * sth;
  f[1] = FM[1] - r * u + p * w + G * cth * sph;
  f[2] = FM[2] - p * v + q * u + G * cth * cph;
  for (int j = 0; j < 6; ++j) { A[0][j] = dFM[0][j]; A[1][j] = dFM[1][j]; A[2][j] = dFM[2][j]; }
  A[0][2] -= q; A[0][1] += r; A[0][4] -= w; A[0][5] += v; A[0][7] = -G * cth;
  A[1][0] -= r; A[1][2] += p; A[1][3] += w; A[1][5] -= u; A[1][7] = -G * sth * sph; A[1][6] = G * cth * cph;
  A[2][1] -= p; A[2][0] += q; A[2][3] -= v; A[2][4] += u; A[2][7] = -G * sth * cph; A[2][6] = -G * cth * sph;
  const double (*In)[3] = af->I;
  double Io[3], gyro[3], dg[3][3];
  for (int i = 0; i < 3; ++i) Io[i] = In[i][0] * p + In[i][1] * q + In[i][2] * r;
  gyro[0] = q * Io[2] - r * Io[1]; gyro[1] = r * Io[0] - p * Io[2]; gyro[2] = p * Io[1] - q * Io[0];
  for (int j = 0; j < 3; ++j) {
    dg[0][j] = q * In[2][j] - r * In[1][j];
    dg[1][j] = r * In[0][j] - p * In[2][j];
    dg[2][j] = p * In[1][j] - q * In[0][j];
  }
  dg[0][1] += Io[2]; dg[0][2] -= Io[1]; dg[1][0] -= Io[2]; dg[1][2] += Io[0]; dg[2][0] += Io[1]; dg[2][1] -= Io[0];
  for (int i = 0; i < 3; ++i) {
    double acc = 0.0;
    for (int k2 = 0; k2 < 3; ++k2) acc += af->Iinv[i][k2] * (FM[3 + k2] - gyro[k2]);
    f[3 + i] = acc;
    for (int j = 0; j < 6; ++j) {
      acc = 0.0;
      for (int k2 = 0; k2 < 3; ++k2) acc += af->Iinv[i][k2] * (dFM[3 + k2][j] - (j >= 3 ? dg[k2][j - 3] : 0.0));
      A[3 + i][j] = acc;
    }
  }
  double tth = sth / cth;
  f[6] = p + q * sph * tth + r * cph * tth;
  f[7] = q * cph - r * sph;
  f[8] = (q * sph + r * cph) / cth;
  A[6][3] = 1.0; A[6][4] = sph * tth; A[6][5] = cph * tth;
  A[6][6] = q * cph * tth - r * sph * tth; A[6][7] = (q * sph + r * cph) / (cth * cth);
  A[7][4] = cph; A[7][5] = -sph; A[7][6] = -q * sph - r * cph;
  A[8][4] = sph / cth; A[8][5] = cph / cth; A[8][6] = (q * cph - r * sph) / cth;
  A[8][7] = (q * sph + r * cph) * sth / (cth * cth);
}

void hand_aircraft_ekf_step(hand_aircraft_t *s, const double *y, const double *u_now, const double *u_next) {
  const airframe_t *afp = &s->af;
  const double *c = s->c, *bias = s->bias, *Qc = s->Qc, *R = s->R, dt = s->dt;
  double *x = s->x;
  double (*P)[NX] = s->P;
  double f[NX], A[NX][NX], h[NY], H[NY][NX], S[NY][NY], L[NY][NY], PHt[NX][NY], K[NX][NY];
  double Z[NY][NX], M[NX][NX], T[NX][NX], xs[NX], Fs[NX][NX], kx[4][NX], kF[4][NX][NX], uc[4], FM[6], dFM[6][NX];

  aero(afp, x, u_now, c, f, A, FM, dFM);
  double u = x[0], v = x[1], w = x[2], V2 = u * u + v * v + w * w, V = sqrt(V2), uw2 = u * u + w * w;
  double sv = v / V, kb = 1.0 / sqrt(1.0 - sv * sv), V3 = V2 * V;
  h[0] = V; h[1] = atan2(w, u); h[2] = asin(sv);
  for (int i = 0; i < 3; ++i) { h[3 + i] = x[3 + i] + bias[3 + i]; h[6 + i] = x[6 + i]; h[9 + i] = FM[i] + bias[i]; }
  memset(H, 0, sizeof H);
  H[0][0] = u / V; H[0][1] = v / V; H[0][2] = w / V;
  H[1][0] = -w / uw2; H[1][2] = u / uw2;
  H[2][0] = -kb * v * u / V3; H[2][1] = kb * (1.0 / V - v * v / V3); H[2][2] = -kb * v * w / V3;
  for (int i = 0; i < 6; ++i) H[3 + i][3 + i] = 1.0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < NX; ++j) H[9 + i][j] = dFM[i][j];
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NY; ++j) {
      double acc = 0.0;
      for (int k2 = 0; k2 < NX; ++k2) acc += P[i][k2] * H[j][k2];
      PHt[i][j] = acc;
    }
  for (int i = 0; i < NY; ++i)
    for (int j = 0; j <= i; ++j) {
      double acc = R[i + NY * j];
      for (int k2 = 0; k2 < NX; ++k2) acc += H[i][k2] * PHt[k2][j];
      S[i][j] = S[j][i] = acc;
    }
  for (int j = 0; j < NY; ++j) {
    double acc = S[j][j];
    for (int k2 = 0; k2 < j; ++k2) acc -= L[j][k2] * L[j][k2];
    L[j][j] = sqrt(acc);
    for (int i = j + 1; i < NY; ++i) {
      acc = S[i][j];
      for (int k2 = 0; k2 < j; ++k2) acc -= L[i][k2] * L[j][k2];
      L[i][j] = acc / L[j][j];
    }
  }
  for (int i = 0; i < NX; ++i) {  /* K = PHt S^-1: L L' K' = PHt' */
    for (int j = 0; j < NY; ++j) {
      double acc = PHt[i][j];
      for (int k2 = 0; k2 < j; ++k2) acc -= L[j][k2] * K[i][k2];
      K[i][j] = acc / L[j][j];
    }
    for (int j = NY - 1; j >= 0; --j) {
      double acc = K[i][j];
      for (int k2 = j + 1; k2 < NY; ++k2) acc -= L[k2][j] * K[i][k2];
      K[i][j] = acc / L[j][j];
    }
  }
  for (int i = 0; i < NX; ++i) {
    double acc = 0.0;
    for (int j = 0; j < NY; ++j) acc += K[i][j] * (y[j] - h[j]);
    xs[i] = x[i] + acc;
  }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NX; ++j) {
      double acc = i == j ? 1.0 : 0.0;
      for (int k2 = 0; k2 < NY; ++k2) acc -= K[i][k2] * H[k2][j];
      M[i][j] = acc;
    }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NX; ++j) {
      double acc = 0.0;
      for (int k2 = 0; k2 < NX; ++k2) acc += M[i][k2] * P[k2][j];
      T[i][j] = acc;
    }
  for (int i = 0; i < NY; ++i)
    for (int j = 0; j < NX; ++j) {
      double acc = 0.0;
      for (int k2 = 0; k2 < NY; ++k2) acc += R[i + NY * k2] * K[j][k2];
      Z[i][j] = acc;
    }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j <= i; ++j) {
      double acc = 0.0;
      for (int k2 = 0; k2 < NX; ++k2) acc += T[i][k2] * M[j][k2];
      for (int k2 = 0; k2 < NY; ++k2) acc += K[i][k2] * Z[k2][j];
      P[i][j] = P[j][i] = acc;
    }
  for (int i = 0; i < NX; ++i) { x[i] = xs[i]; s->xf[i] = x[i]; }
  static const double frac[4] = {0.0, 0.5, 0.5, 1.0};
  for (int s_ = 0; s_ < 4; ++s_) {
    for (int j = 0; j < 4; ++j) uc[j] = (1.0 - frac[s_]) * u_now[j] + frac[s_] * u_next[j];
    if (s_ == 0) {
      for (int i = 0; i < NX; ++i) { xs[i] = x[i]; for (int j = 0; j < NX; ++j) Fs[i][j] = i == j ? 1.0 : 0.0; }
    } else {
      double a = s_ < 3 ? 0.5 * dt : dt;
      for (int i = 0; i < NX; ++i) {
        xs[i] = x[i] + a * kx[s_ - 1][i];
        for (int j = 0; j < NX; ++j) Fs[i][j] = (i == j ? 1.0 : 0.0) + a * kF[s_ - 1][i][j];
      }
    }
    aero(afp, xs, uc, c, f, A, FM, dFM);
    for (int i = 0; i < NX; ++i) {
      kx[s_][i] = f[i];
      for (int j = 0; j < NX; ++j) {
        double acc = 0.0;
        for (int k2 = 0; k2 < NX; ++k2) acc += A[i][k2] * Fs[k2][j];
        kF[s_][i][j] = acc;
      }
    }
  }
  for (int i = 0; i < NX; ++i) {
    x[i] += dt / 6.0 * (kx[0][i] + 2.0 * kx[1][i] + 2.0 * kx[2][i] + kx[3][i]);
    for (int j = 0; j < NX; ++j)
      Fs[i][j] = (i == j ? 1.0 : 0.0) + dt / 6.0 * (kF[0][i][j] + 2.0 * kF[1][i][j] + 2.0 * kF[2][i][j] + kF[3][i][j]);
  }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NX; ++j) {
      double acc = 0.0;
      for (int k2 = 0; k2 < NX; ++k2) acc += Fs[i][k2] * (P[k2][j] + 0.5 * dt * Qc[k2 + NX * j]);
      T[i][j] = acc;
    }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j <= i; ++j) {
      double acc = 0.5 * dt * Qc[i + NX * j];
      for (int k2 = 0; k2 < NX; ++k2) acc += T[i][k2] * Fs[j][k2];
      P[i][j] = P[j][i] = acc;
    }
}

/* The right-hand side f (9) at (x, uc) and the specific forces FM[0..2], without the Jacobian:
   the part of aero() a UKF needs. */
static void rhs_only(const airframe_t *af, const double *x, const double *uc, const double *c, double *f,
                     double *FM) {
  const double G = af->G, b = af->b, cbar = af->cbar;
  double u = x[0], v = x[1], w = x[2], p = x[3], q = x[4], r = x[5], phi = x[6], th = x[7];
  double V2 = u * u + v * v + w * w, V = sqrt(V2), alpha = atan2(w, u), beta = asin(v / V);
  double qn = q * cbar / V, pn = p * b / (2.0 * V), rn = r * b / (2.0 * V), coef[6];
  double scale[6] = {1.0 / af->m, 1.0 / af->m, 1.0 / af->m, b, cbar, b}, qS = 0.5 * af->rho * V2 * af->S;
  coef[0] = c[0] + c[1] * alpha + c[2] * alpha * alpha + c[3] * qn + c[4] * uc[0] + c[5] * uc[3];
  coef[1] = c[6] + c[7] * beta + c[8] * pn + c[9] * rn + c[10] * uc[1] + c[11] * uc[2];
  coef[2] = c[12] + c[13] * alpha + c[14] * qn + c[15] * uc[0];
  coef[3] = c[16] + c[17] * beta + c[18] * pn + c[19] * rn + c[20] * uc[1] + c[21] * uc[2];
  coef[4] = c[22] + c[23] * alpha + c[24] * qn + c[25] * uc[0];
  coef[5] = c[26] + c[27] * beta + c[28] * pn + c[29] * rn + c[30] * uc[1] + c[31] * uc[2];
  for (int i = 0; i < 6; ++i) FM[i] = qS * coef[i] * scale[i];
  double sph = sin(phi), cph = cos(phi), sth = sin(th), cth = cos(th), Io[3], gyro[3];
  f[0] = FM[0] - q * w + r * v - G * sth;
  f[1] = FM[1] - r * u + p * w + G * cth * sph;
  f[2] = FM[2] - p * v + q * u + G * cth * cph;
  for (int i = 0; i < 3; ++i) Io[i] = af->I[i][0] * p + af->I[i][1] * q + af->I[i][2] * r;
  gyro[0] = q * Io[2] - r * Io[1]; gyro[1] = r * Io[0] - p * Io[2]; gyro[2] = p * Io[1] - q * Io[0];
  for (int i = 0; i < 3; ++i) {
    double acc = 0.0;
    for (int k2 = 0; k2 < 3; ++k2) acc += af->Iinv[i][k2] * (FM[3 + k2] - gyro[k2]);
    f[3 + i] = acc;
  }
  double tth = sth / cth;
  f[6] = p + q * sph * tth + r * cph * tth;
  f[7] = q * cph - r * sph;
  f[8] = (q * sph + r * cph) / cth;
}

/* Cholesky of the symmetric m x m A (row-major, lower triangle read) into L (lower). */
static void cholesky(int m, const double *A, double *L) {
  for (int j = 0; j < m; ++j) {
    double acc = A[j * m + j];
    for (int k = 0; k < j; ++k) acc -= L[j * m + k] * L[j * m + k];
    L[j * m + j] = sqrt(acc);
    for (int i = j + 1; i < m; ++i) {
      acc = A[i * m + j];
      for (int k = 0; k < j; ++k) acc -= L[i * m + k] * L[j * m + k];
      L[i * m + j] = acc / L[j * m + j];
    }
    for (int i = 0; i < j; ++i) L[i * m + j] = 0.0;
  }
}

/* The 2n + 1 sigma points (rows of X) of (x, P): x -+ the columns of the Cholesky factor of
   spread (P + jitter I), jitter 1e-14 of the mean variance plus 1e-300 (as casest). */
static void sigma_points(const double *x, const double P[NX][NX], double spread, double X[2 * NX + 1][NX]) {
  double A[NX * NX], L[NX * NX], trace = 0.0;
  for (int i = 0; i < NX; ++i) trace += P[i][i];
  double jitter = 1e-14 * trace / NX + 1e-300;
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NX; ++j) A[i * NX + j] = spread * (P[i][j] + (i == j ? jitter : 0.0));
  cholesky(NX, A, L);
  for (int i = 0; i < NX; ++i) {
    X[0][i] = x[i];
    for (int k = 0; k < NX; ++k) {
      X[1 + k][i] = x[i] + L[i * NX + k];
      X[1 + NX + k][i] = x[i] - L[i * NX + k];
    }
  }
}

void hand_aircraft_ukf_step(hand_aircraft_t *st, const double *y, const double *u_now, const double *u_next,
                            double alpha, double beta, double kappa) {
  enum { NS = 2 * NX + 1 };
  const airframe_t *afp = &st->af;
  const double *c = st->c, *bias = st->bias, *Qc = st->Qc, *R = st->R, dt = st->dt;
  double *x = st->x;
  double (*P)[NX] = st->P;
  double lam = alpha * alpha * (NX + kappa) - NX, Wm[NS], Wc[NS];
  Wm[0] = lam / (NX + lam);
  Wc[0] = Wm[0] + 1.0 - alpha * alpha + beta;
  for (int i = 1; i < NS; ++i) Wm[i] = Wc[i] = 1.0 / (2.0 * (NX + lam));
  double X[NS][NX], Z[NS][NY], z[NY], S[NY * NY], L[NY * NY], C[NX][NY], K[NX][NY];
  double f[NX], FM[6], k1[NX], k2[NX], k3[NX], k4[NX], s[NX], ua[4], um[4], ub[4];

  /* update: the outputs of the sigma points of x(k|k-1) */
  sigma_points(x, P, NX + lam, X);
  for (int j = 0; j < NY; ++j) z[j] = 0.0;
  for (int p = 0; p < NS; ++p) {
    const double *xp = X[p];
    double V = sqrt(xp[0] * xp[0] + xp[1] * xp[1] + xp[2] * xp[2]);
    rhs_only(afp, xp, u_now, c, f, FM);
    Z[p][0] = V; Z[p][1] = atan2(xp[2], xp[0]); Z[p][2] = asin(xp[1] / V);
    for (int i = 0; i < 3; ++i) { Z[p][3 + i] = xp[3 + i] + bias[3 + i]; Z[p][6 + i] = xp[6 + i]; Z[p][9 + i] = FM[i] + bias[i]; }
    for (int j = 0; j < NY; ++j) z[j] += Wm[p] * Z[p][j];
  }
  for (int i = 0; i < NY; ++i)
    for (int j = 0; j <= i; ++j) {
      double acc = R[i + NY * j];
      for (int p = 0; p < NS; ++p) acc += Wc[p] * (Z[p][i] - z[i]) * (Z[p][j] - z[j]);
      S[i * NY + j] = S[j * NY + i] = acc;
    }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j < NY; ++j) {
      double acc = 0.0;
      for (int p = 0; p < NS; ++p) acc += Wc[p] * (X[p][i] - x[i]) * (Z[p][j] - z[j]);
      C[i][j] = acc;
    }
  cholesky(NY, S, L);
  for (int i = 0; i < NX; ++i) {  /* K = C S^-1: L L' K' = C' */
    for (int j = 0; j < NY; ++j) {
      double acc = C[i][j];
      for (int k = 0; k < j; ++k) acc -= L[j * NY + k] * K[i][k];
      K[i][j] = acc / L[j * NY + j];
    }
    for (int j = NY - 1; j >= 0; --j) {
      double acc = K[i][j];
      for (int k = j + 1; k < NY; ++k) acc -= L[k * NY + j] * K[i][k];
      K[i][j] = acc / L[j * NY + j];
    }
  }
  for (int i = 0; i < NX; ++i) {
    double acc = 0.0;
    for (int j = 0; j < NY; ++j) acc += K[i][j] * (y[j] - z[j]);
    s[i] = x[i] + acc;
  }
  for (int i = 0; i < NX; ++i)  /* P - K S K' = P - K C' */
    for (int j = 0; j <= i; ++j) {
      double acc = 0.0;
      for (int k = 0; k < NY; ++k) acc += K[i][k] * C[j][k];
      P[i][j] = P[j][i] = P[i][j] - acc;
    }
  memcpy(x, s, sizeof(double) * NX);
  for (int i = 0; i < NX; ++i) st->xf[i] = x[i];
  /* predict: each sigma point through one RK4 step, the inputs linear between samples */
  sigma_points(x, P, NX + lam, X);
  for (int j = 0; j < 4; ++j) {
    ua[j] = u_now[j]; ub[j] = u_next[j]; um[j] = 0.5 * (ua[j] + ub[j]);
  }
  for (int i = 0; i < NX; ++i) x[i] = 0.0;
  for (int p = 0; p < NS; ++p) {
    double *xp = X[p];
    rhs_only(afp, xp, ua, c, k1, FM);
    for (int i = 0; i < NX; ++i) s[i] = xp[i] + 0.5 * dt * k1[i];
    rhs_only(afp, s, um, c, k2, FM);
    for (int i = 0; i < NX; ++i) s[i] = xp[i] + 0.5 * dt * k2[i];
    rhs_only(afp, s, um, c, k3, FM);
    for (int i = 0; i < NX; ++i) s[i] = xp[i] + dt * k3[i];
    rhs_only(afp, s, ub, c, k4, FM);
    for (int i = 0; i < NX; ++i) {
      xp[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
      x[i] += Wm[p] * xp[i];
    }
  }
  for (int i = 0; i < NX; ++i)
    for (int j = 0; j <= i; ++j) {
      double acc = Qc[i + NX * j] * dt;
      for (int p = 0; p < NS; ++p) acc += Wc[p] * (X[p][i] - x[i]) * (X[p][j] - x[j]);
      P[i][j] = P[j][i] = acc;
    }
}

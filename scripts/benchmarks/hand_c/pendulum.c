/* Hand-written C EKF and UKF of the pendulum of scripts/benchmarks/filter_case.py (angle and rate
   driven by a torque held over each interval; outputs the bob's position L sin(ang), -L cos(ang)),
   written as a careful engineer writes them for this one model: the EKF with the RK4 step and its
   tangent and the 2x2 algebra as scalars (as ekf_numba_peer.py); the UKF with van der Merwe's
   sigma points, RK4 on each, and the Cholesky factors of 2x2 and 2x2 innovation covariances by
   hand. Each is a step function over a state struct, as a flight computer calls a filter once per
   sample (as casest's generated filters are called). The same filters as casest's ExtendedKalmanFilter and UnscentedKalmanFilter on this model
   (bench_export_c.py checks their states against the generated code's). */
#include <math.h>
#include "hand.h"

#define G 9.81
#define DT 0.05
#define SUB 4

static void rhs(double a0, double a1, double u, double c, double L, double *f0, double *f1) {
  *f0 = a1;
  *f1 = -G / L * sin(a0) - c * a1 + u;
}

/* One interval of RK4 (SUB substeps, the torque held) of (x0, x1). */
static void rk4(double *x0, double *x1, double u, double c, double L) {
  const double h = DT / SUB;
  double a0 = *x0, a1 = *x1, k1a, k1b, k2a, k2b, k3a, k3b, k4a, k4b;
  for (int s = 0; s < SUB; ++s) {
    rhs(a0, a1, u, c, L, &k1a, &k1b);
    rhs(a0 + 0.5 * h * k1a, a1 + 0.5 * h * k1b, u, c, L, &k2a, &k2b);
    rhs(a0 + 0.5 * h * k2a, a1 + 0.5 * h * k2b, u, c, L, &k3a, &k3b);
    rhs(a0 + h * k3a, a1 + h * k3b, u, c, L, &k4a, &k4b);
    a0 += h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a);
    a1 += h / 6.0 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b);
  }
  *x0 = a0;
  *x1 = a1;
}

void hand_pendulum_init(hand_pendulum_t *s, double c, double L, double q_rate, double r_var, double p0) {
  s->x0 = 1.0; s->x1 = 0.0; s->P00 = p0; s->P01 = 0.0; s->P11 = p0;
  s->c = c; s->L = L; s->q = q_rate; s->r = r_var;
}

void hand_pendulum_ekf_step(hand_pendulum_t *st, const double *y, double u) {
  const double h = DT / SUB, c = st->c, L = st->L, q_rate = st->q, r_var = st->r;
  double x0 = st->x0, x1 = st->x1, P00 = st->P00, P01 = st->P01, P11 = st->P11;
  /* update (Joseph form), H = [[L cos x0, 0], [L sin x0, 0]] */
  double s0 = sin(x0), c0 = cos(x0), H00 = L * c0, H10 = L * s0;
  double S00 = H00 * P00 * H00 + r_var, S01 = H00 * P00 * H10, S11 = H10 * P00 * H10 + r_var;
  double HP00 = H00 * P00, HP01 = H00 * P01, HP10 = H10 * P00, HP11 = H10 * P01;
  double det = S00 * S11 - S01 * S01, i00 = S11 / det, i01 = -S01 / det, i11 = S00 / det;
  double K00 = i00 * HP00 + i01 * HP10, K10 = i00 * HP01 + i01 * HP11;
  double K01 = i01 * HP00 + i11 * HP10, K11 = i01 * HP01 + i11 * HP11;
  double e0 = y[0] - L * s0, e1 = y[1] + L * c0;
  x0 += K00 * e0 + K01 * e1;
  x1 += K10 * e0 + K11 * e1;
  double B00 = 1.0 - (K00 * H00 + K01 * H10), B10 = -(K10 * H00 + K11 * H10);
  double T00 = B00 * P00, T01 = B00 * P01, T10 = B10 * P00 + P01, T11 = B10 * P01 + P11;
  double n00 = T00 * B00 + r_var * (K00 * K00 + K01 * K01);
  double n01 = T00 * B10 + T01 + r_var * (K00 * K10 + K01 * K11);
  double n11 = T10 * B10 + T11 + r_var * (K10 * K10 + K11 * K11);
  P00 = n00; P01 = n01; P11 = n11;
  st->xf0 = x0;
  st->xf1 = x1;
  /* RK4 with its tangent F */
  double a0 = x0, a1 = x1, F00 = 1.0, F01 = 0.0, F10 = 0.0, F11 = 1.0;
  for (int s = 0; s < SUB; ++s) {
    double b0 = a0, b1 = a1, G00 = F00, G01 = F01, G10 = F10, G11 = F11;
    double ka[4], kb[4], j00[4], j01[4], j10[4], j11[4];
    for (int stage = 0; stage < 4; ++stage) {
      double j = -G / L * cos(b0);
      ka[stage] = b1;
      kb[stage] = -G / L * sin(b0) - c * b1 + u;
      j00[stage] = G10; j01[stage] = G11; j10[stage] = j * G00 - c * G10; j11[stage] = j * G01 - c * G11;
      if (stage < 3) {
        double a = stage < 2 ? 0.5 * h : h;
        b0 = a0 + a * ka[stage]; b1 = a1 + a * kb[stage];
        G00 = F00 + a * j00[stage]; G01 = F01 + a * j01[stage]; G10 = F10 + a * j10[stage]; G11 = F11 + a * j11[stage];
      }
    }
    a0 += h / 6.0 * (ka[0] + 2.0 * ka[1] + 2.0 * ka[2] + ka[3]);
    a1 += h / 6.0 * (kb[0] + 2.0 * kb[1] + 2.0 * kb[2] + kb[3]);
    F00 += h / 6.0 * (j00[0] + 2.0 * j00[1] + 2.0 * j00[2] + j00[3]);
    F01 += h / 6.0 * (j01[0] + 2.0 * j01[1] + 2.0 * j01[2] + j01[3]);
    F10 += h / 6.0 * (j10[0] + 2.0 * j10[1] + 2.0 * j10[2] + j10[3]);
    F11 += h / 6.0 * (j11[0] + 2.0 * j11[1] + 2.0 * j11[2] + j11[3]);
  }
  /* P = F P F' + 0.5 dt (F Qc F' + Qc), Qc = diag(0, q) */
  double FP00 = F00 * P00 + F01 * P01, FP01 = F00 * P01 + F01 * P11;
  double FP10 = F10 * P00 + F11 * P01, FP11 = F10 * P01 + F11 * P11;
  st->P00 = FP00 * F00 + FP01 * F01 + 0.5 * DT * (F01 * q_rate * F01);
  st->P01 = FP00 * F10 + FP01 * F11 + 0.5 * DT * (F01 * q_rate * F11);
  st->P11 = FP10 * F10 + FP11 * F11 + 0.5 * DT * (F11 * q_rate * F11 + q_rate);
  st->x0 = a0;
  st->x1 = a1;
}

/* The 5 sigma points of (x, P) with weights' spread n + lambda: the lower Cholesky factor of
   (n + lambda) (P + jitter I), jitter 1e-14 of the mean variance plus 1e-300 (as casest). */
static void sigma(double x0, double x1, double P00, double P01, double P11, double spread, double *s0, double *s1) {
  double jit = 1e-14 * (P00 + P11) / 2.0 + 1e-300;
  double A00 = spread * (P00 + jit), A01 = spread * P01, A11 = spread * (P11 + jit);
  double L00 = sqrt(A00), L10 = A01 / L00, L11 = sqrt(A11 - L10 * L10);
  s0[0] = x0; s1[0] = x1;
  s0[1] = x0 + L00; s1[1] = x1 + L10;   /* columns of L */
  s0[2] = x0;       s1[2] = x1 + L11;
  s0[3] = x0 - L00; s1[3] = x1 - L10;
  s0[4] = x0;       s1[4] = x1 - L11;
}

void hand_pendulum_ukf_step(hand_pendulum_t *st, const double *y, double u, double alpha, double beta,
                            double kappa) {
  const int N = 2;
  const double c = st->c, L = st->L, r_var = st->r;
  double lam = alpha * alpha * (N + kappa) - N, Wm[5], Wc[5];
  Wm[0] = lam / (N + lam);
  Wc[0] = Wm[0] + 1.0 - alpha * alpha + beta;
  for (int i = 1; i < 5; ++i) Wm[i] = Wc[i] = 1.0 / (2.0 * (N + lam));
  double x0 = st->x0, x1 = st->x1, P00 = st->P00, P01 = st->P01, P11 = st->P11, s0[5], s1[5], z0[5], z1[5];
  /* update */
  sigma(x0, x1, P00, P01, P11, N + lam, s0, s1);
  double m0 = 0.0, m1 = 0.0;
  for (int i = 0; i < 5; ++i) {
    z0[i] = L * sin(s0[i]); z1[i] = -L * cos(s0[i]);
    m0 += Wm[i] * z0[i]; m1 += Wm[i] * z1[i];
  }
  double S00 = r_var, S01 = 0.0, S11 = r_var, C00 = 0.0, C01 = 0.0, C10 = 0.0, C11 = 0.0;
  for (int i = 0; i < 5; ++i) {
    double d0 = z0[i] - m0, d1 = z1[i] - m1, e0 = s0[i] - x0, e1 = s1[i] - x1;
    S00 += Wc[i] * d0 * d0; S01 += Wc[i] * d0 * d1; S11 += Wc[i] * d1 * d1;
    C00 += Wc[i] * e0 * d0; C01 += Wc[i] * e0 * d1; C10 += Wc[i] * e1 * d0; C11 += Wc[i] * e1 * d1;
  }
  double det = S00 * S11 - S01 * S01, i00 = S11 / det, i01 = -S01 / det, i11 = S00 / det;
  double K00 = C00 * i00 + C01 * i01, K01 = C00 * i01 + C01 * i11;
  double K10 = C10 * i00 + C11 * i01, K11 = C10 * i01 + C11 * i11;
  double e0 = y[0] - m0, e1 = y[1] - m1;
  x0 += K00 * e0 + K01 * e1;
  x1 += K10 * e0 + K11 * e1;
  /* P - K S K' */
  double KS00 = K00 * S00 + K01 * S01, KS01 = K00 * S01 + K01 * S11;
  double KS10 = K10 * S00 + K11 * S01, KS11 = K10 * S01 + K11 * S11;
  P00 -= KS00 * K00 + KS01 * K01;
  P01 -= 0.5 * ((KS00 * K10 + KS01 * K11) + (KS10 * K00 + KS11 * K01));
  P11 -= KS10 * K10 + KS11 * K11;
  st->xf0 = x0;
  st->xf1 = x1;
  /* predict: each sigma point through the RK4 step */
  sigma(x0, x1, P00, P01, P11, N + lam, s0, s1);
  double a0 = 0.0, a1 = 0.0;
  for (int i = 0; i < 5; ++i) {
    rk4(&s0[i], &s1[i], u, c, L);
    a0 += Wm[i] * s0[i]; a1 += Wm[i] * s1[i];
  }
  P00 = 0.0; P01 = 0.0; P11 = st->q * DT;
  for (int i = 0; i < 5; ++i) {
    double d0 = s0[i] - a0, d1 = s1[i] - a1;
    P00 += Wc[i] * d0 * d0; P01 += Wc[i] * d0 * d1; P11 += Wc[i] * d1 * d1;
  }
  st->x0 = a0; st->x1 = a1; st->P00 = P00; st->P01 = P01; st->P11 = P11;
}

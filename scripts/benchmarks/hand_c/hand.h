/* The hand-written C filters bench_export_c.py times against casest's generated C, each a step
   function over a state struct called once per sample. Arrays are row-major. */
#ifndef HAND_H
#define HAND_H
/* the pendulum's filter state: x(k+1|k) and P(k+1|k) after a step, x(k|k) in xf0, xf1 */
typedef struct { double x0, x1, P00, P01, P11, xf0, xf1, c, L, q, r; } hand_pendulum_t;
void hand_pendulum_init(hand_pendulum_t *s, double c, double L, double q_rate, double r_var, double p0);
void hand_pendulum_ekf_step(hand_pendulum_t *s, const double *y, double u);
void hand_pendulum_ukf_step(hand_pendulum_t *s, const double *y, double u, double alpha, double beta, double kappa);
typedef struct {
  double G, rho, S, b, cbar, m;
  double I[3][3], Iinv[3][3];
} airframe_t;
/* the aircraft's filter state: x(k+1|k) and P(k+1|k) after a step, x(k|k) in xf; its constants */
typedef struct {
  double x[9], P[9][9], xf[9], c[32], bias[6], Qc[81], R[144], dt;
  airframe_t af;
} hand_aircraft_t;
/* frame: gravity, air density, wing area, span, chord, mass, the inertia (3 x 3, row-major), its
   inverse; Qc, R, P0 column-major */
void hand_aircraft_init(hand_aircraft_t *s, double dt, const double *c, const double *bias, const double *Qc,
                        const double *R, const double *x0, const double *P0, const double *frame);
void hand_aircraft_ekf_step(hand_aircraft_t *s, const double *y, const double *u_now, const double *u_next);
void hand_aircraft_ukf_step(hand_aircraft_t *s, const double *y, const double *u_now, const double *u_next,
                            double alpha, double beta, double kappa);
#endif

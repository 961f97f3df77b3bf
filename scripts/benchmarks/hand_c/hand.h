/* The hand-written C filters bench_export_c.py times against casest's generated C. Records are
   row-major (one sample after the other); out receives x(k|k) at every sample. */
#ifndef HAND_H
#define HAND_H
void hand_pendulum_ekf(int n, const double *Y, const double *U, double c, double L, double q_rate, double r_var,
                       double p0, double *out);
void hand_pendulum_ukf(int n, const double *Y, const double *U, double c, double L, double q_rate, double r_var,
                       double p0, double alpha, double beta, double kappa, double *out);
/* frame: gravity, air density, wing area, span, chord, mass, the inertia (3 x 3, row-major), its inverse */
void hand_aircraft_ekf(int n, const double *Y, const double *U, double dt, const double *c, const double *bias,
                       const double *Qc, const double *R, const double *x0, const double *P0, const double *frame,
                       double *out);
void hand_aircraft_ukf(int n, const double *Y, const double *U, double dt, const double *c, const double *bias,
                       const double *Qc, const double *R, const double *x0, const double *P0, const double *frame,
                       double alpha, double beta, double kappa, double *out);
#endif

/* mt_solver.h: variable-step, error-controlled Rosenbrock integrator (RODAS4) for stiff ODEs.
 *
 * Method: RODAS4 of Hairer & Wanner, "Solving Ordinary Differential Equations II" (2nd ed., 1996),
 * section IV.7: 6 stages, order 4 with an embedded order-3 error estimate, L-stable and stiffly
 * accurate. Coefficients in the (A, C, gamma_i, alpha_i, m) form used by Sandu et al.,
 * "Benchmarking stiff ODE solvers for atmospheric chemistry II: Rosenbrock solvers",
 * Atmos. Environ. 31 (1997). The Jacobian is evaluated exactly once per step; linear systems are
 * solved by a small dense LU factorisation with partial pivoting (mt_lu_*).
 *
 * The solver knows nothing about FMI: it integrates x' = f(t, x) through callbacks.
 */
#ifndef MT_SOLVER_H
#define MT_SOLVER_H

#include <stddef.h>

/* x' = f(t, x). Returns 0 on success, nonzero when f could not be evaluated. */
typedef int (*mt_rhs_fn)(void *ctx, double t, const double *x, double *dx);
/* J = df/dx (n x n, column-major) and dfdt = df/dt at (t, x). Returns 0 on success. */
typedef int (*mt_jac_fn)(void *ctx, double t, const double *x, double *J, double *dfdt);
/* Optional: f(t, x), J and dfdt at one point in one call (cheaper when they share work). */
typedef int (*mt_fjac_fn)(void *ctx, double t, const double *x, double *f, double *J, double *dfdt);

enum {
    MT_SOLVER_OK = 0,
    MT_SOLVER_NONFINITE = 1,  /* f or J not finite at an accepted point */
    MT_SOLVER_UNDERFLOW = 2,  /* step size below the resolution of t */
    MT_SOLVER_MAXSTEPS = 3,   /* more than max_steps steps in one call */
    MT_SOLVER_EVAL = 4        /* a callback reported failure */
};

typedef struct {
    int n;
    double rtol;          /* relative tolerance */
    const double *scale;  /* per-state nominal values; absolute tolerance = rtol * scale[i] */
    double h;             /* step size proposal carried from call to call; 0: choose one */
    long max_steps;       /* bound on steps per mt_solver_integrate call */
    mt_fjac_fn fjac;      /* when set, used instead of f and jac at the start of each step (NULL after init) */
    long n_accepted, n_rejected, n_rhs, n_jac;  /* statistics since mt_solver_init */
    int fail_index;       /* state index responsible for a failure, -1 if none */
    int worst_index;      /* state with the largest weighted error in the last rejected step */
    double fail_time;     /* time of a failure */
    double *work;         /* workspace */
    int *pivot;
} mt_solver;

int mt_solver_init(mt_solver *s, int n);
void mt_solver_free(mt_solver *s);

/* Integrate x from *t to tend (> *t); on success *t == tend. On failure *t and x hold the last
 * accepted point and s->fail_index / s->fail_time describe the failure. */
int mt_solver_integrate(mt_solver *s, mt_rhs_fn f, mt_jac_fn jac, void *ctx, double *t, double tend, double *x);

/* One RODAS4 step of size h from (t, x) to xnew, without error control; *err receives the
 * weighted RMS norm of the embedded error estimate. Used by the convergence-order test. */
int mt_rosenbrock_step(mt_solver *s, mt_rhs_fn f, mt_jac_fn jac, void *ctx, double t, double h,
                       const double *x, double *xnew, double *err);

/* Dense LU factorisation with partial pivoting of the n x n column-major matrix A (in place).
 * Returns 0, or k + 1 when the pivot of column k is zero. */
int mt_lu_factor(double *A, int n, int *pivot);
/* Solve A x = b in place (b becomes x) with the factors of mt_lu_factor. */
void mt_lu_solve(const double *A, int n, const int *pivot, double *b);

#endif

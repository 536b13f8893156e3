/* mt_solver.c: RODAS4 Rosenbrock integrator with step-size control and a dense LU solver.
 * See mt_solver.h for the method and its references. */
#include "mt_solver.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define NSTAGE 6
#define GAMMA_DIAG 0.25

/* Strictly lower-triangular A and C stored row-wise: (i, j) at i*(i-1)/2 + j, 0-based, j < i. */
static const double ROS_A[15] = {
    1.544000000000000e+00,
    0.9466785280815826e+00, 0.2557011698983284e+00,
    3.314825187068521e+00, 2.896124015972201e+00, 0.9986419139977817e+00,
    1.221224509226641e+00, 6.019134481288629e+00, 12.53708332932087e+00, -0.6878860361058950e+00,
    1.221224509226641e+00, 6.019134481288629e+00, 12.53708332932087e+00, -0.6878860361058950e+00, 1.0};
static const double ROS_C[15] = {
    -5.668800000000000e+00,
    -2.430093356833875e+00, -0.2063599157091915e+00,
    -0.1073529058151375e+00, -9.594562251023355e+00, -20.47028614809616e+00,
    7.496443313967647e+00, -10.24680431464352e+00, -33.99990352819905e+00, 11.70890893206160e+00,
    8.083246795921522e+00, -7.981132988064893e+00, -31.52159432874371e+00, 16.31930543123136e+00,
    -6.058818238834054e+00};
static const double ROS_M[NSTAGE] = {1.221224509226641e+00, 6.019134481288629e+00, 12.53708332932087e+00,
                                     -0.6878860361058950e+00, 1.0, 1.0};
static const double ROS_E[NSTAGE] = {0.0, 0.0, 0.0, 0.0, 0.0, 1.0};
static const double ROS_ALPHA[NSTAGE] = {0.0, 0.386, 0.210, 0.630, 1.0, 1.0};
static const double ROS_GAMMA[NSTAGE] = {0.25, -0.1043, 0.1035, -0.3620000000000023e-01, 0.0, 0.0};
static const double ELO = 4.0;                  /* order of the error estimate + 1 */
static const double FAC_MIN = 0.2, FAC_MAX = 6.0, FAC_SAFE = 0.9, FAC_REJECT = 0.1;

/* Workspace layout. */
#define W_K(s) ((s)->work)
#define W_F0(s) ((s)->work + NSTAGE * (s)->n)
#define W_FCN(s) (W_F0(s) + (s)->n)
#define W_TMP(s) (W_FCN(s) + (s)->n)
#define W_NEW(s) (W_TMP(s) + (s)->n)
#define W_DFDT(s) (W_NEW(s) + (s)->n)
#define W_J(s) (W_DFDT(s) + (s)->n)
#define W_G(s) (W_J(s) + (s)->n * (s)->n)

int mt_solver_init(mt_solver *s, int n)
{
    size_t nw = (size_t)(NSTAGE + 5) * (size_t)n + 2 * (size_t)n * (size_t)n;
    memset(s, 0, sizeof *s);
    s->n = n;
    s->rtol = 1e-8;
    s->max_steps = 1000000;
    s->fail_index = -1;
    s->worst_index = 0;
    s->work = calloc(nw ? nw : 1, sizeof(double));
    s->pivot = calloc(n ? (size_t)n : 1, sizeof(int));
    if (!s->work || !s->pivot) {
        mt_solver_free(s);
        return -1;
    }
    return 0;
}

void mt_solver_free(mt_solver *s)
{
    free(s->work);
    free(s->pivot);
    s->work = NULL;
    s->pivot = NULL;
}

int mt_lu_factor(double *A, int n, int *pivot)
{
    int i, j, k;
    for (k = 0; k < n; k++) {
        int p = k;
        double big = fabs(A[k + k * n]);
        for (i = k + 1; i < n; i++) {
            if (fabs(A[i + k * n]) > big) {
                big = fabs(A[i + k * n]);
                p = i;
            }
        }
        pivot[k] = p;
        if (big == 0.0 || !isfinite(big)) return k + 1;
        if (p != k) {
            for (j = 0; j < n; j++) {
                double tmp = A[k + j * n];
                A[k + j * n] = A[p + j * n];
                A[p + j * n] = tmp;
            }
        }
        for (i = k + 1; i < n; i++) A[i + k * n] /= A[k + k * n];
        for (j = k + 1; j < n; j++) {
            double akj = A[k + j * n];
            if (akj != 0.0)
                for (i = k + 1; i < n; i++) A[i + j * n] -= A[i + k * n] * akj;
        }
    }
    return 0;
}

void mt_lu_solve(const double *A, int n, const int *pivot, double *b)
{
    int i, k;
    for (k = 0; k < n; k++) { /* P b: the factorisation swapped whole rows, L included */
        if (pivot[k] != k) {
            double tmp = b[k];
            b[k] = b[pivot[k]];
            b[pivot[k]] = tmp;
        }
    }
    for (k = 0; k < n; k++) { /* bk and col in locals: b[i] = ... could alias them for the compiler */
        const double *col = A + (size_t)k * n;
        double bk = b[k];
        for (i = k + 1; i < n; i++) b[i] -= col[i] * bk;
    }
    for (k = n - 1; k >= 0; k--) {
        const double *col = A + (size_t)k * n;
        double bk = b[k] / col[k];
        b[k] = bk;
        for (i = 0; i < k; i++) b[i] -= col[i] * bk;
    }
}

static int first_nonfinite(const double *v, int n)
{
    int i;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) return i;
    return -1;
}

static double atol_of(const mt_solver *s, int i)
{
    return s->rtol * (s->scale ? fabs(s->scale[i]) : 1.0);
}

/* The stages of one step with J, dfdt, f0 at (t, x) already in the workspace.
 * Returns 0 with xnew and *err, 1 when the step must be rejected (singular matrix or
 * non-finite stage), MT_SOLVER_EVAL when f failed. */
static int stages(mt_solver *s, mt_rhs_fn f, void *ctx, double t, double h, const double *x, double *xnew,
                  double *err)
{
    int n = s->n, i, j, k, worst = 0;
    double *K = W_K(s), *fcn = W_FCN(s), *tmp = W_TMP(s), *G = W_G(s);
    const double *J = W_J(s), *f0 = W_F0(s), *dfdt = W_DFDT(s);
    double diag = 1.0 / (h * GAMMA_DIAG), sum = 0.0, big = -1.0;
    for (k = 0; k < n * n; k++) G[k] = -J[k];
    for (k = 0; k < n; k++) G[k + k * n] += diag;
    if (mt_lu_factor(G, n, s->pivot) != 0) return 1;
    for (i = 0; i < NSTAGE; i++) {
        int off = i * (i - 1) / 2;
        double *Ki = K + (size_t)i * n;
        if (i == 0) {
            memcpy(fcn, f0, (size_t)n * sizeof(double));
        } else {
            for (k = 0; k < n; k++) tmp[k] = x[k];
            for (j = 0; j < i; j++)
                for (k = 0; k < n; k++) tmp[k] += ROS_A[off + j] * K[(size_t)j * n + k];
            s->n_rhs++;
            if (f(ctx, t + ROS_ALPHA[i] * h, tmp, fcn) != 0) return MT_SOLVER_EVAL;
        }
        for (k = 0; k < n; k++) Ki[k] = fcn[k] + h * ROS_GAMMA[i] * dfdt[k];
        for (j = 0; j < i; j++) {
            double hc = ROS_C[off + j] / h;
            for (k = 0; k < n; k++) Ki[k] += hc * K[(size_t)j * n + k];
        }
        mt_lu_solve(G, n, s->pivot, Ki);
        j = first_nonfinite(Ki, n);
        if (j >= 0) {
            s->worst_index = j;
            return 1;
        }
    }
    for (k = 0; k < n; k++) {
        double xn = x[k], e = 0.0, sc;
        for (i = 0; i < NSTAGE; i++) {
            xn += ROS_M[i] * K[(size_t)i * n + k];
            e += ROS_E[i] * K[(size_t)i * n + k];
        }
        xnew[k] = xn;
        sc = atol_of(s, k) + s->rtol * fmax(fabs(x[k]), fabs(xn));
        sum += (e / sc) * (e / sc);
        if (!(fabs(e / sc) <= big)) {
            big = fabs(e / sc);
            worst = k;
        }
    }
    s->worst_index = worst;
    *err = n > 0 ? sqrt(sum / n) : 0.0;
    return isfinite(*err) ? 0 : 1;
}

static int eval_point(mt_solver *s, mt_rhs_fn f, mt_jac_fn jac, void *ctx, double t, const double *x)
{
    int n = s->n, bad;
    s->n_rhs++;
    if (s->fjac) {
        s->n_jac++;
        if (s->fjac(ctx, t, x, W_F0(s), W_J(s), W_DFDT(s)) != 0) return MT_SOLVER_EVAL;
    } else if (f(ctx, t, x, W_F0(s)) != 0) {
        return MT_SOLVER_EVAL;
    }
    bad = first_nonfinite(W_F0(s), n);
    if (bad < 0) {
        if (!s->fjac) {
            s->n_jac++;
            if (jac(ctx, t, x, W_J(s), W_DFDT(s)) != 0) return MT_SOLVER_EVAL;
        }
        bad = first_nonfinite(W_DFDT(s), n);
        if (bad < 0) {
            int k = first_nonfinite(W_J(s), n * n);
            bad = k < 0 ? -1 : k % n;
        }
    }
    if (bad >= 0) {
        s->fail_index = bad;
        s->fail_time = t;
        return MT_SOLVER_NONFINITE;
    }
    return MT_SOLVER_OK;
}

int mt_rosenbrock_step(mt_solver *s, mt_rhs_fn f, mt_jac_fn jac, void *ctx, double t, double h,
                       const double *x, double *xnew, double *err)
{
    int rc = eval_point(s, f, jac, ctx, t, x);
    if (rc != MT_SOLVER_OK) return rc;
    rc = stages(s, f, ctx, t, h, x, xnew, err);
    return rc == 1 ? MT_SOLVER_NONFINITE : rc;
}

static double initial_step(const mt_solver *s, const double *x, double span)
{
    int n = s->n, k;
    double d0 = 0.0, d1 = 0.0, h;
    const double *f0 = W_F0(s);
    for (k = 0; k < n; k++) {
        double sc = atol_of(s, k) + s->rtol * fabs(x[k]);
        d0 += (x[k] / sc) * (x[k] / sc);
        d1 += (f0[k] / sc) * (f0[k] / sc);
    }
    d0 = sqrt(d0 / n);
    d1 = sqrt(d1 / n);
    h = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    return fmin(h, span);
}

int mt_solver_integrate(mt_solver *s, mt_rhs_fn f, mt_jac_fn jac, void *ctx, double *t, double tend, double *x)
{
    int n = s->n, rejected_before = 0, first = 1, rc;
    long steps = 0;
    double h = s->h, err;
    double *xnew = W_NEW(s);
    s->fail_index = -1;
    if (n == 0 || !(tend > *t)) {
        if (tend > *t) *t = tend;
        return MT_SOLVER_OK;
    }
    rc = eval_point(s, f, jac, ctx, *t, x);
    if (rc != MT_SOLVER_OK) return rc;
    if (!(h > 0.0)) h = initial_step(s, x, tend - *t);
    for (;;) {
        double remaining = tend - *t, hs = h, hmin;
        int last = 0;
        hmin = 16.0 * DBL_EPSILON * fmax(fmax(fabs(*t), fabs(tend)), 1e-300);
        if (remaining <= hmin) { /* below the resolution of t: nothing left to integrate */
            *t = tend;
            return MT_SOLVER_OK;
        }
        if (++steps > s->max_steps) {
            s->fail_time = *t;
            s->fail_index = s->worst_index;
            return MT_SOLVER_MAXSTEPS;
        }
        if (hs >= remaining) {
            hs = remaining;
            last = 1;
        }
        if (hs < hmin) {
            s->fail_time = *t;
            s->fail_index = s->worst_index;
            return MT_SOLVER_UNDERFLOW;
        }
        rc = stages(s, f, ctx, *t, hs, x, xnew, &err);
        if (rc == MT_SOLVER_EVAL) {
            s->fail_time = *t;
            return rc;
        }
        if (rc == 1) { /* singular iteration matrix or non-finite stage: retry with a much smaller step */
            h = hs * 0.25;
            rejected_before = 1;
            s->n_rejected++;
            continue;
        }
        if (err <= 1.0) {
            double fac = fmin(FAC_MAX, fmax(FAC_MIN, FAC_SAFE / pow(fmax(err, 1e-16), 1.0 / ELO)));
            if (rejected_before) fac = fmin(1.0, fac);
            memcpy(x, xnew, (size_t)n * sizeof(double));
            *t = last ? tend : *t + hs;
            s->n_accepted++;
            rejected_before = 0;
            first = 0;
            if (last) {
                s->h = fmax(hs * fac, h);
                return MT_SOLVER_OK;
            }
            h = hs * fac;
            rc = eval_point(s, f, jac, ctx, *t, x);
            if (rc != MT_SOLVER_OK) return rc;
        } else {
            s->n_rejected++;
            if (first || rejected_before)
                h = hs * FAC_REJECT;
            else
                h = hs * fmax(FAC_MIN, FAC_SAFE / pow(err, 1.0 / ELO));
            rejected_before = 1;
        }
    }
}

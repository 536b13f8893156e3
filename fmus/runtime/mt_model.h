/* mt_model.h: the contract between a generated model and the model-agnostic FMI runtime.
 *
 * The Python pipeline (fmus/) generates, per model, CasADi C code for the functions below
 * and one descriptor `mt_model MT_MODEL` (model.c). The runtime (mt_runtime.c, fmi2.c, fmi3.c)
 * knows nothing about any particular model.
 *
 * Variables. Every FMU variable is a Float64 addressed by its value reference (vr). vr 0 is
 * time (FMI 3.0 independent variable; unused in FMI 2.0). For vr >= 1 the variable lives in
 * one of the blocks below, in this order, contiguous, index i within its block:
 *   MT_STATE       x[nx]    continuous states
 *   MT_DERIVATIVE  dx[nx]   their derivatives
 *   MT_INPUT       u[nu]
 *   MT_OUTPUT      y[ny]    computed variables (outputs and calculated locals) of the continuous part
 *   MT_HELD        yd[nyd]  outputs of the sampled part, held between samples
 *   MT_DISCRETE    z[nz]    discrete states of the sampled part
 *   MT_PARAMETER   p[np]    tunable parameters
 * so vr = 1 + offset(block) + i, with the offsets following the order above.
 *
 * Sampled part (nz + nyd > 0): at t = t0 + k*Ts, Ts = p[ts_index], the runtime calls
 *   sample(z, u, p) -> (z_next, yd)      yd = C z + D u held until the next sample, z <- z_next.
 * In Co-Simulation, the sample at time t uses the inputs set before the doStep that starts at t
 * (and at t0, the inputs at exit of initialisation); in Model Exchange, it is a time event.
 */
#ifndef MT_MODEL_H
#define MT_MODEL_H

typedef long long mt_int; /* casadi_int */

/* A CasADi-generated function: eval and its work-size query, as CasADi's code generator emits them. */
typedef struct {
    int (*eval)(const double **arg, double **res, mt_int *iw, double *w, int mem);
    int (*work)(mt_int *sz_arg, mt_int *sz_res, mt_int *sz_iw, mt_int *sz_w);
} mt_function;

typedef struct {
    const char *identifier;   /* modelIdentifier */
    const char *token;        /* guid / instantiationToken */
    int nx, nu, ny, nyd, nz, np;
    int ts_index;             /* index in p of the sample period, -1 when nz + nyd == 0 */

    /* Per variable, indexed by vr (0 .. nvr-1, nvr = 1 + 2*nx + nu + ny + nyd + nz + np). */
    int nvr;
    const char *const *names; /* Modelica names, for log messages */
    const double *start;      /* XML start values (NaN where the XML has none) */
    const double *min, *max;  /* -inf / +inf when not declared; checked on parameters and inputs */
    const double *nominal;    /* 1 where not declared; scales the solver's absolute tolerance on states */

    /* Continuous part; each may have eval == 0 when nx == 0 (resp. ny == 0). */
    mt_function x0;    /* (p)          -> x0[nx]        initial states (start values may depend on p) */
    mt_function ode;   /* (t, x, u, p) -> dx[nx] */
    mt_function out;   /* (t, x, u, p) -> y[ny] */
    mt_function jac;   /* (t, x, u, p) -> J[(nx+ny) x (nx+nu)], dense, column-major:
                          d[dx; y] / d[x; u], for directional derivatives and the implicit solver */
    mt_function dfdt;  /* (t, x, u, p) -> d(dx)/dt [nx], explicit time derivative; eval == 0 when dx does
                          not depend on t (zero) */
    mt_function ode_jac; /* (t, x, u, p) -> (dx[nx], d(dx)/dx [nx x nx] dense, column-major): what the solver
                            needs at each accepted point, in one evaluation; eval == 0: use ode and jac */

    /* Sampled part; eval == 0 when nz + nyd == 0. */
    mt_function sample; /* (z, u, p) -> (z_next[nz], yd[nyd]) */
    mt_function sample_matrix; /* (p) -> S [(nz+nyd) x (nz+nu)] dense, column-major, with [z_next; yd] = S [z; u]
                                  when the sampled part is linear in z and u; eval == 0 otherwise */
} mt_model;

extern const mt_model MT_MODEL;

#endif

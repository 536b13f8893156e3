/* mt_runtime.c: model-agnostic FMU runtime (see mt_runtime.h). */
#include "mt_runtime.h"

#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { B_TIME, B_X, B_DX, B_U, B_Y, B_YD, B_Z, B_P, B_NONE };
static const char *const BLOCK_KIND[] = {"the independent variable", "a continuous state", "a state derivative",
                                         "an input", "a computed variable", "a sampled output",
                                         "a discrete state", "a parameter", "unknown"};

/* ------------------------------------------------------------------------------------------ */
/* Variables                                                                                   */

static int block_of(const mt_model *m, unsigned int vr, int *index)
{
    const int sizes[] = {1, m->nx, m->nx, m->nu, m->ny, m->nyd, m->nz, m->np};
    unsigned int start = 0;
    int b;
    for (b = B_TIME; b < B_NONE; b++) {
        if (vr < start + (unsigned int)sizes[b]) {
            *index = (int)(vr - start);
            return b;
        }
        start += (unsigned int)sizes[b];
    }
    *index = -1;
    return B_NONE;
}

static unsigned int vr_of(const mt_model *m, int block, int index)
{
    const int sizes[] = {1, m->nx, m->nx, m->nu, m->ny, m->nyd, m->nz, m->np};
    unsigned int start = 0;
    int b;
    for (b = B_TIME; b < block; b++) start += (unsigned int)sizes[b];
    return start + (unsigned int)index;
}

static const char *name_of(const mt_model *m, int block, int index)
{
    unsigned int vr = vr_of(m, block, index);
    return (m->names && (int)vr < m->nvr) ? m->names[vr] : "?";
}

static double start_or(const mt_model *m, int block, int index, double fallback)
{
    double s = m->start ? m->start[vr_of(m, block, index)] : NAN;
    return isnan(s) ? fallback : s;
}

/* ------------------------------------------------------------------------------------------ */
/* Logging and the state machine                                                               */

void mt_log(mt_instance *inst, int status, const char *category, const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    if (!inst || !inst->emit) return;
    if (status == MT_OK && !(inst->logging_on && inst->log_events && strcmp(category, "logEvents") == 0))
        return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    inst->emit(inst, status, category, msg);
}

#define LOG_ERROR(inst, ...) mt_log((inst), MT_ERROR, "logStatusError", __VA_ARGS__)
#define LOG_EVENT(inst, ...)                                                                          \
    do {                                                                                              \
        if ((inst)->logging_on && (inst)->log_events) mt_log((inst), MT_OK, "logEvents", __VA_ARGS__); \
    } while (0)

static const char *mode_name(int mode)
{
    switch (mode) {
    case MT_INSTANTIATED: return "Instantiated";
    case MT_INIT: return "Initialization Mode";
    case MT_EVENT: return "Event Mode";
    case MT_CONTINUOUS: return "Continuous-Time Mode";
    case MT_STEP: return "Step Mode";
    case MT_TERMINATED: return "Terminated";
    case MT_FAILED: return "Error (after a failed call; only getters, reset and free are allowed)";
    default: return "unknown";
    }
}

int mt_allowed(mt_instance *inst, int mask, const char *fn)
{
    const char *hint = "";
    if (!inst) return 0;
    if (inst->mode & mask) return 1;
    if (inst->mode == MT_INSTANTIATED && (mask & MT_INIT))
        hint = " (allowed from Initialization Mode on: call EnterInitializationMode first)";
    else if ((inst->mode & (MT_INSTANTIATED | MT_INIT)) && (mask & (MT_STEP | MT_EVENT | MT_CONTINUOUS)))
        hint = " (allowed after ExitInitializationMode)";
    LOG_ERROR(inst, "%s: illegal call sequence: not allowed in %s%s", fn, mode_name(inst->mode), hint);
    return 0;
}

int mt_fail(mt_instance *inst)
{
    inst->mode = MT_FAILED;
    return MT_ERROR;
}

int mt_set_debug_logging(mt_instance *inst, int on, size_t n, const char *const *categories)
{
    size_t i;
    inst->logging_on = on;
    if (n == 0) {
        inst->log_events = inst->log_errors = on;
        return MT_OK;
    }
    for (i = 0; i < n; i++) {
        const char *c = categories ? categories[i] : NULL;
        if (c && strcmp(c, "logEvents") == 0)
            inst->log_events = on;
        else if (c && strcmp(c, "logStatusError") == 0)
            inst->log_errors = on;
        else {
            LOG_ERROR(inst, "SetDebugLogging: unknown log category \"%s\" (known: logEvents, logStatusError)",
                      c ? c : "(null)");
            return MT_ERROR;
        }
    }
    return MT_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* CasADi functions                                                                            */

static int call(mt_instance *inst, const mt_function *f, const double *a0, const double *a1, const double *a2,
                const double *a3, double *r0, double *r1)
{
    if (!f->eval) return 0; /* absent function: empty result */
    inst->arg[0] = a0;
    inst->arg[1] = a1;
    inst->arg[2] = a2;
    inst->arg[3] = a3;
    inst->res[0] = r0;
    inst->res[1] = r1;
    return f->eval(inst->arg, inst->res, inst->iw, inst->w, 0);
}

/* Before exit of initialisation the states follow x0(p) except where the user set a start value. */
int mt_refresh_initial_states(mt_instance *inst)
{
    const mt_model *m = inst->m;
    int i;
    if (!(inst->mode & (MT_INSTANTIATED | MT_INIT)) || m->nx == 0) return 0;
    if (call(inst, &m->x0, inst->p, NULL, NULL, NULL, inst->scratch, NULL)) return -1;
    for (i = 0; i < m->nx; i++)
        if (!inst->x_set[i]) inst->x[i] = inst->scratch[i];
    return 0;
}

static int eval_ode(mt_instance *inst, double t, const double *x, double *dx)
{
    return call(inst, &inst->m->ode, &t, x, inst->u, inst->p, dx, NULL);
}

static int eval_out(mt_instance *inst)
{
    return call(inst, &inst->m->out, &inst->t, inst->x, inst->u, inst->p, inst->y, NULL);
}

static int eval_jac(mt_instance *inst, double t, const double *x)
{
    return call(inst, &inst->m->jac, &t, x, inst->u, inst->p, inst->J, NULL);
}

static int solver_rhs(void *ctx, double t, const double *x, double *dx)
{
    return eval_ode((mt_instance *)ctx, t, x, dx);
}

static int solver_jac(void *ctx, double t, const double *x, double *J, double *dfdt)
{
    mt_instance *inst = ctx;
    const mt_model *m = inst->m;
    int nx = m->nx, nr = m->nx + m->ny, r, c;
    if (eval_jac(inst, t, x)) return -1;
    for (c = 0; c < nx; c++)
        for (r = 0; r < nx; r++) J[r + c * nx] = inst->J[r + c * nr];
    if (!m->dfdt.eval) {
        for (r = 0; r < nx; r++) dfdt[r] = 0.0;
        return 0;
    }
    return call(inst, &m->dfdt, &t, x, inst->u, inst->p, dfdt, NULL);
}

/* dx, d(dx)/dx and dfdt in one generated function (mt_model.ode_jac). */
static int solver_fjac(void *ctx, double t, const double *x, double *f, double *J, double *dfdt)
{
    mt_instance *inst = ctx;
    const mt_model *m = inst->m;
    int r;
    if (call(inst, &m->ode_jac, &t, x, inst->u, inst->p, f, J)) return -1;
    if (!m->dfdt.eval) {
        for (r = 0; r < m->nx; r++) dfdt[r] = 0.0;
        return 0;
    }
    return call(inst, &m->dfdt, &t, x, inst->u, inst->p, dfdt, NULL);
}

/* ------------------------------------------------------------------------------------------ */
/* Lifecycle                                                                                   */

static void *zalloc(size_t n, size_t size)
{
    return calloc(n ? n : 1, size);
}

static void max_work(const mt_function *f, mt_int *a, mt_int *r, mt_int *iw, mt_int *w)
{
    mt_int sa = 0, sr = 0, si = 0, sw = 0;
    if (!f->eval || !f->work) return;
    f->work(&sa, &sr, &si, &sw);
    if (sa > *a) *a = sa;
    if (sr > *r) *r = sr;
    if (si > *iw) *iw = si;
    if (sw > *w) *w = sw;
}

/* The registry: a growing array of live instance pointers guarded by a spin lock (GCC atomics: the FMU
 * links only libc and libm). Instances are few per process, so a linear search is cheap next to a step. */
static mt_instance **live_instances;
static size_t live_count, live_capacity;
static volatile int live_lock;

static void registry_lock(void)
{
    while (__sync_lock_test_and_set(&live_lock, 1)) {
    }
}

static void registry_unlock(void) { __sync_lock_release(&live_lock); }

/* Index of ptr among the live instances, or live_count; call with the lock held. */
static size_t registry_find(const void *ptr)
{
    size_t k = 0;
    while (k < live_count && (const void *)live_instances[k] != ptr) k++;
    return k;
}

static int registry_add(mt_instance *inst)
{
    int ok = 1;
    registry_lock();
    if (live_count == live_capacity) {
        size_t capacity = live_capacity ? 2 * live_capacity : 16;
        mt_instance **grown = realloc(live_instances, capacity * sizeof *grown);
        if (grown) {
            live_instances = grown;
            live_capacity = capacity;
        } else {
            ok = 0;
        }
    }
    if (ok) live_instances[live_count++] = inst;
    registry_unlock();
    return ok;
}

static void refuse_pointer(const void *ptr, const char *fn)
{
    fprintf(stderr, "[ERROR] FMU %s: %s: %p is no live instance of this FMU (freed already, or never returned "
            "by Instantiate); the call is refused\n", MT_MODEL.identifier, fn, ptr);
}

mt_instance *mt_instantiate(const char *name, const char *token, int co_simulation, int fmi_version,
                            mt_emit_fn emit, void (*logger)(void), void *env, int logging_on)
{
    const mt_model *m = &MT_MODEL;
    mt_instance *inst = zalloc(1, sizeof *inst);
    mt_int sa = 4, sr = 2, si = 0, sw = 0;
    size_t nr = (size_t)(m->nx + m->ny), nc = (size_t)(m->nx + m->nu), nscratch;
    if (!inst) return NULL;
    inst->m = m;
    inst->emit = emit;
    inst->logger = logger;
    inst->env = env;
    inst->co_simulation = co_simulation;
    inst->fmi_version = fmi_version;
    inst->name = zalloc(strlen(name ? name : "") + 1, 1);
    if (inst->name) strcpy(inst->name, name ? name : "");
    inst->logging_on = logging_on;
    inst->log_events = inst->log_errors = logging_on;
    if (!name || !name[0]) {
        LOG_ERROR(inst, "Instantiate: the instance name must not be empty");
        mt_free(inst);
        return NULL;
    }
    if (!token || strcmp(token, m->token) != 0) {
        LOG_ERROR(inst, "Instantiate: token \"%s\" does not match this FMU's \"%s\" (modelDescription.xml of "
                  "another build?)", token ? token : "(null)", m->token);
        mt_free(inst);
        return NULL;
    }
    max_work(&m->x0, &sa, &sr, &si, &sw);
    max_work(&m->ode, &sa, &sr, &si, &sw);
    max_work(&m->out, &sa, &sr, &si, &sw);
    max_work(&m->jac, &sa, &sr, &si, &sw);
    max_work(&m->dfdt, &sa, &sr, &si, &sw);
    max_work(&m->sample, &sa, &sr, &si, &sw);
    max_work(&m->ode_jac, &sa, &sr, &si, &sw);
    max_work(&m->sample_matrix, &sa, &sr, &si, &sw);
    nscratch = (size_t)m->nx;
    if ((size_t)m->nyd > nscratch) nscratch = (size_t)m->nyd;
    inst->x = zalloc((size_t)m->nx, sizeof(double));
    inst->u = zalloc((size_t)m->nu, sizeof(double));
    inst->p = zalloc((size_t)m->np, sizeof(double));
    inst->z = zalloc((size_t)m->nz, sizeof(double));
    inst->z_pre = zalloc((size_t)m->nz, sizeof(double));
    inst->yd = zalloc((size_t)m->nyd, sizeof(double));
    inst->x_set = zalloc((size_t)m->nx, 1);
    inst->dx = zalloc((size_t)m->nx, sizeof(double));
    inst->y = zalloc((size_t)m->ny, sizeof(double));
    inst->J = zalloc(nr * nc, sizeof(double));
    inst->znext = zalloc((size_t)m->nz, sizeof(double));
    inst->scratch = zalloc(nscratch, sizeof(double));
    inst->S = zalloc((size_t)(m->nz + m->nyd) * (size_t)(m->nz + m->nu), sizeof(double));
    inst->zu = zalloc((size_t)(m->nz + m->nu), sizeof(double));
    inst->arg = zalloc((size_t)sa, sizeof(double *));
    inst->res = zalloc((size_t)sr, sizeof(double *));
    inst->iw = zalloc((size_t)si, sizeof(mt_int));
    inst->w = zalloc((size_t)sw, sizeof(double));
    if (!inst->name || !inst->x || !inst->u || !inst->p || !inst->z || !inst->z_pre || !inst->yd || !inst->x_set ||
        !inst->dx || !inst->y || !inst->J || !inst->znext || !inst->scratch || !inst->S || !inst->zu || !inst->arg || !inst->res ||
        !inst->iw || !inst->w || mt_solver_init(&inst->solver, m->nx) != 0) {
        LOG_ERROR(inst, "Instantiate: out of memory");
        mt_free(inst);
        return NULL;
    }
    inst->solver.scale = m->nominal ? m->nominal + vr_of(m, B_X, 0) : NULL;
    if (m->ode_jac.eval) inst->solver.fjac = solver_fjac;
    mt_reset(inst);
    if (!registry_add(inst)) {
        LOG_ERROR(inst, "Instantiate: out of memory");
        mt_free(inst);
        return NULL;
    }
    return inst;
}

int mt_live(const void *ptr, const char *fn)
{
    size_t k;
    if (!ptr) return 0;
    registry_lock();
    k = registry_find(ptr);
    registry_unlock();
    if (k < live_count) return 1;
    refuse_pointer(ptr, fn);
    return 0;
}

void mt_release(void *ptr, const char *fn)
{
    size_t k;
    int found;
    if (!ptr) return;
    registry_lock();
    k = registry_find(ptr);
    found = k < live_count;
    if (found) live_instances[k] = live_instances[--live_count];
    if (live_count == 0) {
        free(live_instances);
        live_instances = NULL;
        live_capacity = 0;
    }
    registry_unlock();
    if (found)
        mt_free((mt_instance *)ptr);
    else
        refuse_pointer(ptr, fn);
}

void mt_free(mt_instance *inst)
{
    if (!inst) return;
    free(inst->name);
    free(inst->x);
    free(inst->u);
    free(inst->p);
    free(inst->z);
    free(inst->z_pre);
    free(inst->yd);
    free(inst->x_set);
    free(inst->dx);
    free(inst->y);
    free(inst->J);
    free(inst->znext);
    free(inst->scratch);
    free(inst->S);
    free(inst->zu);
    free(inst->arg);
    free(inst->res);
    free(inst->iw);
    free(inst->w);
    mt_solver_free(&inst->solver);
    free(inst);
}

void mt_reset(mt_instance *inst)
{
    const mt_model *m = inst->m;
    int i;
    inst->mode = MT_INSTANTIATED;
    inst->t0 = inst->t = 0.0;
    inst->rtol = 1e-8;
    for (i = 0; i < m->nx; i++) {
        inst->x[i] = start_or(m, B_X, i, 0.0);
        inst->x_set[i] = 0;
    }
    for (i = 0; i < m->nu; i++) inst->u[i] = start_or(m, B_U, i, 0.0);
    for (i = 0; i < m->np; i++) inst->p[i] = m->start ? m->start[vr_of(m, B_P, i)] : NAN;
    for (i = 0; i < m->nz; i++) inst->z[i] = inst->z_pre[i] = start_or(m, B_Z, i, 0.0);
    for (i = 0; i < m->nyd; i++) inst->yd[i] = 0.0;
    inst->k_next = 0;
    inst->at_sample = 0;
    inst->S_valid = 0;
    inst->solver.h = 0.0;
    inst->solver.n_accepted = inst->solver.n_rejected = inst->solver.n_rhs = inst->solver.n_jac = 0;
}

/* ------------------------------------------------------------------------------------------ */
/* Sampled part                                                                                */

int mt_sampled(const mt_instance *inst)
{
    return inst->m->sample.eval && inst->m->ts_index >= 0 && inst->m->nz + inst->m->nyd > 0;
}

static double sample_period(const mt_instance *inst)
{
    return inst->p[inst->m->ts_index];
}

static double sample_time(const mt_instance *inst, long long k)
{
    return inst->t0 + (double)k * sample_period(inst);
}

/* Instants closer than this are the same instant (robust against accumulated rounding of t). */
static double sample_eps(const mt_instance *inst)
{
    return 1e-9 * sample_period(inst) + 8.0 * DBL_EPSILON * fabs(inst->t);
}

/* [z_next; yd] = S [z_from; u] with S = sample_matrix(p), evaluated again only after p changed. */
static int sample_linear(mt_instance *inst, const double *z_from)
{
    const mt_model *m = inst->m;
    int nz = m->nz, nr = m->nz + m->nyd, nc = m->nz + m->nu, r, c;
    if (!inst->S_valid) {
        if (call(inst, &m->sample_matrix, inst->p, NULL, NULL, NULL, inst->S, NULL)) return -1;
        inst->S_valid = 1;
    }
    memcpy(inst->zu, z_from, (size_t)nz * sizeof(double));
    memcpy(inst->zu + nz, inst->u, (size_t)m->nu * sizeof(double));
    for (r = 0; r < nr; r++) {
        double acc = 0.0;
        for (c = 0; c < nc; c++) acc += inst->S[r + (size_t)c * nr] * inst->zu[c];
        if (r < nz)
            inst->znext[r] = acc;
        else
            inst->scratch[r - nz] = acc;
    }
    return 0;
}

/* z <- sample(z_from, u, p), yd <- its output; checks the results. */
static int run_sample(mt_instance *inst, const double *z_from, const char *fn)
{
    const mt_model *m = inst->m;
    int i;
    if (m->sample_matrix.eval ? sample_linear(inst, z_from)
                              : call(inst, &m->sample, z_from, inst->u, inst->p, NULL, inst->znext, inst->scratch)) {
        LOG_ERROR(inst, "%s: evaluation of the sampled part failed at t = %.17g", fn, inst->t);
        return MT_ERROR;
    }
    for (i = 0; i < m->nz; i++)
        if (!isfinite(inst->znext[i])) {
            LOG_ERROR(inst, "%s: discrete state %s = %g is not finite after the sample at t = %.17g", fn,
                      name_of(m, B_Z, i), inst->znext[i], inst->t);
            return MT_ERROR;
        }
    for (i = 0; i < m->nyd; i++)
        if (!isfinite(inst->scratch[i])) {
            LOG_ERROR(inst, "%s: sampled output %s = %g is not finite at t = %.17g", fn, name_of(m, B_YD, i),
                      inst->scratch[i], inst->t);
            return MT_ERROR;
        }
    memcpy(inst->z, inst->znext, (size_t)m->nz * sizeof(double));
    memcpy(inst->yd, inst->scratch, (size_t)m->nyd * sizeof(double));
    return MT_OK;
}

/* Execute sample k_next (at time t_s) with the present inputs. */
static int do_sample(mt_instance *inst, const char *fn)
{
    const mt_model *m = inst->m;
    double ts = sample_time(inst, inst->k_next);
    memcpy(inst->z_pre, inst->z, (size_t)m->nz * sizeof(double));
    if (run_sample(inst, inst->z_pre, fn) != MT_OK) return MT_ERROR;
    LOG_EVENT(inst, "%s: sample %lld at t = %.17g", fn, inst->k_next, ts);
    inst->k_next++;
    inst->at_sample = fabs(ts - inst->t) <= sample_eps(inst);
    return MT_OK;
}

/* Samples due at the current time (and any missed earlier ones). */
static int samples_due(mt_instance *inst, const char *fn)
{
    if (!mt_sampled(inst)) return MT_OK;
    while (sample_time(inst, inst->k_next) <= inst->t + sample_eps(inst))
        if (do_sample(inst, fn) != MT_OK) return MT_ERROR;
    return MT_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Get and set                                                                                 */

/* FMI 3.0 in Instantiated: "get variable start values as defined in modelDescription.xml" (FMI 3.0.2, state
 * Instantiated), or the value set since; nothing is evaluated. Variables without a start value (derivatives,
 * computed variables, states whose start depends on parameters) are refused. FMI 2.0 refuses all getters there. */
static int start_values(mt_instance *inst, const unsigned int *vr, size_t n, double *value, const char *fn)
{
    const mt_model *m = inst->m;
    size_t k;
    for (k = 0; k < n; k++) {
        int i, b = block_of(m, vr[k], &i);
        if (b == B_NONE) {
            LOG_ERROR(inst, "%s: unknown value reference %u (this FMU has 0 .. %d)", fn, vr[k], m->nvr - 1);
            return MT_ERROR;
        }
        if (!(b == B_X || b == B_U || b == B_Z || b == B_P) || !m->start || isnan(m->start[vr[k]])) {
            LOG_ERROR(inst, "%s: %s (value reference %u) is %s without a start value: it is computed from "
                      "Initialization Mode on (call EnterInitializationMode first); in Instantiated only start "
                      "values can be read", fn, b == B_TIME ? "time" : m->names[vr[k]], vr[k], BLOCK_KIND[b]);
            return MT_ERROR;
        }
        value[k] = b == B_X ? inst->x[i] : (b == B_U ? inst->u[i] : (b == B_Z ? inst->z[i] : inst->p[i]));
    }
    return MT_OK;
}

int mt_get_float64(mt_instance *inst, const unsigned int *vr, size_t n, double *value, const char *fn)
{
    const mt_model *m = inst->m;
    int have_dx = 0, have_y = 0, have_yd = 0;
    size_t k;
    if (n > 0 && (!vr || !value)) {
        LOG_ERROR(inst, "%s: null pointer for value references or values", fn);
        return MT_ERROR;
    }
    if (inst->mode == MT_INSTANTIATED) return start_values(inst, vr, n, value, fn);
    if (mt_refresh_initial_states(inst)) {
        LOG_ERROR(inst, "%s: evaluation of the initial states failed", fn);
        return MT_ERROR;
    }
    for (k = 0; k < n; k++) {
        int i, b = block_of(m, vr[k], &i);
        switch (b) {
        case B_TIME: value[k] = inst->t; break;
        case B_X: value[k] = inst->x[i]; break;
        case B_DX:
            if (!have_dx && eval_ode(inst, inst->t, inst->x, inst->dx)) {
                LOG_ERROR(inst, "%s: evaluation of the derivatives failed at t = %.17g", fn, inst->t);
                return MT_ERROR;
            }
            have_dx = 1;
            value[k] = inst->dx[i];
            break;
        case B_U: value[k] = inst->u[i]; break;
        case B_Y:
            if (!have_y && eval_out(inst)) {
                LOG_ERROR(inst, "%s: evaluation of the outputs failed at t = %.17g", fn, inst->t);
                return MT_ERROR;
            }
            have_y = 1;
            value[k] = inst->y[i];
            break;
        case B_YD:
            if (!have_yd && (inst->mode & (MT_INSTANTIATED | MT_INIT))) { /* what the sample at t0 would give */
                if (call(inst, &m->sample, inst->z, inst->u, inst->p, NULL, inst->znext, inst->scratch)) {
                    LOG_ERROR(inst, "%s: evaluation of the sampled part failed", fn);
                    return MT_ERROR;
                }
            } else if (!have_yd) {
                memcpy(inst->scratch, inst->yd, (size_t)m->nyd * sizeof(double));
            }
            have_yd = 1;
            value[k] = inst->scratch[i];
            break;
        case B_Z: value[k] = inst->z[i]; break;
        case B_P: value[k] = inst->p[i]; break;
        default:
            LOG_ERROR(inst, "%s: unknown value reference %u (this FMU has 0 .. %d)", fn, vr[k], m->nvr - 1);
            return MT_ERROR;
        }
    }
    return MT_OK;
}

int mt_set_float64(mt_instance *inst, const unsigned int *vr, size_t n, const double *value, const char *fn)
{
    const mt_model *m = inst->m;
    const int start_modes = MT_INSTANTIATED | MT_INIT;
    int inputs_changed = 0;
    size_t k;
    if (n > 0 && (!vr || !value)) {
        LOG_ERROR(inst, "%s: null pointer for value references or values", fn);
        return MT_ERROR;
    }
    for (k = 0; k < n; k++) {
        int i, b = block_of(m, vr[k], &i);
        double v = value[k];
        const char *name = b == B_NONE ? "" : (b == B_TIME ? "time" : m->names[vr[k]]);
        if (b == B_NONE) {
            LOG_ERROR(inst, "%s: unknown value reference %u (this FMU has 0 .. %d)", fn, vr[k], m->nvr - 1);
            return MT_ERROR;
        }
        if (b == B_TIME || b == B_DX || b == B_Y || b == B_YD) {
            LOG_ERROR(inst, "%s: %s (value reference %u) is %s and cannot be set", fn, name, vr[k], BLOCK_KIND[b]);
            return MT_ERROR;
        }
        if (b == B_U) {
            if (!(inst->mode & (start_modes | MT_STEP | MT_EVENT | MT_CONTINUOUS))) {
                LOG_ERROR(inst, "%s: input %s cannot be set in %s", fn, name, mode_name(inst->mode));
                return MT_ERROR;
            }
        } else if (!(inst->mode & start_modes)) {
            LOG_ERROR(inst, "%s: %s %s can only be set before the end of initialization, not in %s", fn,
                      BLOCK_KIND[b], name, mode_name(inst->mode));
            return MT_ERROR;
        }
        if (!isfinite(v)) {
            LOG_ERROR(inst, "%s: %s %s = %g is not a finite number", fn, BLOCK_KIND[b], name, v);
            return MT_ERROR;
        }
        if (b == B_U && m->min && m->max && (v < m->min[vr[k]] || v > m->max[vr[k]])) {
            LOG_ERROR(inst, "%s: input %s = %.15g is outside its range [%.15g, %.15g]", fn, name, v, m->min[vr[k]],
                      m->max[vr[k]]);
            return MT_ERROR;
        }
        switch (b) {
        case B_X:
            inst->x[i] = v;
            inst->x_set[i] = 1;
            break;
        case B_U:
            inputs_changed |= inst->u[i] != v;
            inst->u[i] = v;
            break;
        case B_Z: inst->z[i] = v; break;
        default:
            inst->p[i] = v;
            inst->S_valid = 0;
            break;
        }
    }
    if (inputs_changed && inst->at_sample && mt_sampled(inst) && !(inst->mode & start_modes)) {
        /* event iteration: redo the sample at this instant with the new inputs */
        if (run_sample(inst, inst->z_pre, fn) != MT_OK) return mt_fail(inst);
        LOG_EVENT(inst, "%s: sample %lld at t = %.17g repeated with new inputs", fn, inst->k_next - 1, inst->t);
    }
    return MT_OK;
}

int mt_wrong_type(mt_instance *inst, const unsigned int *vr, size_t n, const char *type, const char *fn)
{
    if (n == 0) return MT_OK;
    LOG_ERROR(inst, "%s: value reference %u is not of type %s (all variables of this FMU are Float64)", fn,
              vr ? vr[0] : 0u, type);
    return MT_ERROR;
}

/* ------------------------------------------------------------------------------------------ */
/* Initialisation                                                                              */

int mt_setup(mt_instance *inst, int tolerance_defined, double tolerance, double start_time)
{
    if (!isfinite(start_time)) {
        LOG_ERROR(inst, "SetupExperiment: start time %g is not finite", start_time);
        return MT_ERROR;
    }
    if (tolerance_defined && !(tolerance > 0.0 && tolerance < 1.0)) {
        LOG_ERROR(inst, "SetupExperiment: tolerance %g must be in (0, 1)", tolerance);
        return MT_ERROR;
    }
    inst->t0 = inst->t = start_time;
    inst->rtol = tolerance_defined ? tolerance : 1e-8;
    return MT_OK;
}

int mt_exit_initialization(mt_instance *inst)
{
    const mt_model *m = inst->m;
    const char *fn = "ExitInitializationMode";
    int i;
    for (i = 0; i < m->np; i++) {
        unsigned int vr = vr_of(m, B_P, i);
        double v = inst->p[i];
        if (isnan(v)) {
            LOG_ERROR(inst, "%s: parameter %s has no value", fn, m->names[vr]);
            return mt_fail(inst);
        }
        if (m->min && v < m->min[vr]) {
            LOG_ERROR(inst, "%s: parameter %s = %.15g is below its minimum %.15g", fn, m->names[vr], v, m->min[vr]);
            return mt_fail(inst);
        }
        if (m->max && v > m->max[vr]) {
            LOG_ERROR(inst, "%s: parameter %s = %.15g is above its maximum %.15g", fn, m->names[vr], v, m->max[vr]);
            return mt_fail(inst);
        }
    }
    for (i = 0; i < m->nu; i++)
        if (!isfinite(inst->u[i])) {
            LOG_ERROR(inst, "%s: input %s = %g is not finite", fn, name_of(m, B_U, i), inst->u[i]);
            return mt_fail(inst);
        }
    if (mt_sampled(inst)) {
        double ts = sample_period(inst);
        if (!(ts > 0.0) || !isfinite(ts)) {
            LOG_ERROR(inst, "%s: sample period %s = %g must be > 0", fn, name_of(m, B_P, m->ts_index), ts);
            return mt_fail(inst);
        }
    }
    if (mt_refresh_initial_states(inst)) {
        LOG_ERROR(inst, "%s: evaluation of the initial states failed", fn);
        return mt_fail(inst);
    }
    for (i = 0; i < m->nx; i++)
        if (!isfinite(inst->x[i])) {
            LOG_ERROR(inst, "%s: initial value of state %s = %g is not finite (check the parameters)", fn,
                      name_of(m, B_X, i), inst->x[i]);
            return mt_fail(inst);
        }
    if (m->nx > 0) {
        if (eval_ode(inst, inst->t, inst->x, inst->dx)) {
            LOG_ERROR(inst, "%s: evaluation of the derivatives failed at t = %.17g", fn, inst->t);
            return mt_fail(inst);
        }
        for (i = 0; i < m->nx; i++)
            if (!isfinite(inst->dx[i])) {
                LOG_ERROR(inst, "%s: the derivative of state %s is %g at t = %.17g: the parameters are not "
                          "physical (e.g. a zero or negative mass or inertia)", fn, name_of(m, B_X, i), inst->dx[i],
                          inst->t);
                return mt_fail(inst);
            }
    }
    inst->k_next = 0;
    inst->at_sample = 0;
    if (mt_sampled(inst) && do_sample(inst, fn) != MT_OK) return mt_fail(inst);
    inst->solver.h = 0.0;
    inst->solver.rtol = inst->rtol;
    inst->mode = inst->co_simulation ? MT_STEP : MT_EVENT;
    LOG_EVENT(inst, "%s: initialized at t = %.17g", fn, inst->t);
    return MT_OK;
}

int mt_terminate(mt_instance *inst)
{
    inst->mode = MT_TERMINATED;
    LOG_EVENT(inst, "Terminate: t = %.17g, solver steps %ld accepted, %ld rejected, %ld derivative and %ld "
              "Jacobian evaluations", inst->t, inst->solver.n_accepted, inst->solver.n_rejected, inst->solver.n_rhs,
              inst->solver.n_jac);
    return MT_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Co-Simulation                                                                               */

int mt_do_step(mt_instance *inst, double t, double h, const char *fn)
{
    const mt_model *m = inst->m;
    double tend;
    if (!isfinite(t) || !isfinite(h) || h < 0.0) {
        LOG_ERROR(inst, "%s: invalid communication point %g or step size %g (must be finite, step >= 0)", fn, t, h);
        return MT_ERROR;
    }
    if (fabs(t - inst->t) > 1e-9 * fmax(1.0, fabs(inst->t))) {
        LOG_ERROR(inst, "%s: currentCommunicationPoint %.17g does not match the FMU time %.17g", fn, t, inst->t);
        return MT_ERROR;
    }
    inst->t = t;
    tend = t + h;
    if (samples_due(inst, fn) != MT_OK) return mt_fail(inst);
    if (h == 0.0) return MT_OK;
    if (m->nx > 0) {
        double tt = t;
        int rc;
        inst->solver.rtol = inst->rtol;
        rc = mt_solver_integrate(&inst->solver, solver_rhs, solver_jac, inst, &tt, tend, inst->x);
        if (rc != MT_SOLVER_OK) {
            const char *state = inst->solver.fail_index >= 0 ? name_of(m, B_X, inst->solver.fail_index) : "?";
            inst->t = tt;
            switch (rc) {
            case MT_SOLVER_NONFINITE:
                LOG_ERROR(inst, "%s: the derivative of state %s is not finite at t = %.17g (diverging model or "
                          "inputs/parameters outside its range)", fn, state, inst->solver.fail_time);
                break;
            case MT_SOLVER_UNDERFLOW:
                LOG_ERROR(inst, "%s: step size underflow at t = %.17g: the integration of state %s does not "
                          "converge at tolerance %g (diverging model or inputs/parameters outside its range)", fn,
                          inst->solver.fail_time, state, inst->rtol);
                break;
            case MT_SOLVER_MAXSTEPS:
                LOG_ERROR(inst, "%s: more than %ld solver steps in one communication step, stopped at t = %.17g "
                          "(state %s limits the step size: diverging or extremely stiff model)", fn,
                          inst->solver.max_steps, inst->solver.fail_time, state);
                break;
            default:
                LOG_ERROR(inst, "%s: evaluation of the model failed at t = %.17g", fn, inst->solver.fail_time);
            }
            return mt_fail(inst);
        }
    }
    if (mt_sampled(inst)) { /* instants strictly inside (t, tend) use the held inputs */
        while (sample_time(inst, inst->k_next) < tend - sample_eps(inst)) {
            inst->t = sample_time(inst, inst->k_next);
            if (do_sample(inst, fn) != MT_OK) return mt_fail(inst);
        }
    }
    inst->t = tend;
    inst->at_sample = 0;
    return MT_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Model Exchange                                                                              */

int mt_set_time(mt_instance *inst, double t)
{
    if (!isfinite(t)) {
        LOG_ERROR(inst, "SetTime: time %g is not finite", t);
        return MT_ERROR;
    }
    if (t != inst->t) inst->at_sample = 0;
    inst->t = t;
    return MT_OK;
}

static int check_nx(mt_instance *inst, const void *ptr, size_t n, const char *fn)
{
    if (n != (size_t)inst->m->nx) {
        LOG_ERROR(inst, "%s: expected %d continuous states, got %zu", fn, inst->m->nx, n);
        return MT_ERROR;
    }
    if (n > 0 && !ptr) {
        LOG_ERROR(inst, "%s: null pointer", fn);
        return MT_ERROR;
    }
    return MT_OK;
}

int mt_set_states(mt_instance *inst, const double *x, size_t n, const char *fn)
{
    size_t i;
    if (check_nx(inst, x, n, fn)) return MT_ERROR;
    for (i = 0; i < n; i++)
        if (!isfinite(x[i])) {
            LOG_ERROR(inst, "%s: state %s = %g is not finite", fn, name_of(inst->m, B_X, (int)i), x[i]);
            return MT_ERROR;
        }
    memcpy(inst->x, x, n * sizeof(double));
    return MT_OK;
}

int mt_get_states(mt_instance *inst, double *x, size_t n, const char *fn)
{
    if (check_nx(inst, x, n, fn)) return MT_ERROR;
    if (mt_refresh_initial_states(inst)) return MT_ERROR;
    memcpy(x, inst->x, n * sizeof(double));
    return MT_OK;
}

int mt_get_derivatives(mt_instance *inst, double *dx, size_t n, const char *fn)
{
    size_t i;
    if (check_nx(inst, dx, n, fn)) return MT_ERROR;
    if (n == 0) return MT_OK;
    if (mt_refresh_initial_states(inst) || eval_ode(inst, inst->t, inst->x, dx)) {
        LOG_ERROR(inst, "%s: evaluation of the derivatives failed at t = %.17g", fn, inst->t);
        return MT_ERROR;
    }
    for (i = 0; i < n; i++)
        if (!isfinite(dx[i])) {
            LOG_ERROR(inst, "%s: the derivative of state %s is %g at t = %.17g", fn, name_of(inst->m, B_X, (int)i),
                      dx[i], inst->t);
            return MT_ERROR;
        }
    return MT_OK;
}

int mt_get_nominals(mt_instance *inst, double *nominals, size_t n, const char *fn)
{
    size_t i;
    if (check_nx(inst, nominals, n, fn)) return MT_ERROR;
    for (i = 0; i < n; i++)
        nominals[i] = inst->m->nominal ? inst->m->nominal[vr_of(inst->m, B_X, (int)i)] : 1.0;
    return MT_OK;
}

int mt_check_event_indicators(mt_instance *inst, size_t n, const char *fn)
{
    if (n != 0) {
        LOG_ERROR(inst, "%s: this FMU has no event indicators, got a request for %zu", fn, n);
        return MT_ERROR;
    }
    return MT_OK;
}

int mt_update_discrete(mt_instance *inst, int *next_defined, double *next_time)
{
    if (samples_due(inst, "UpdateDiscreteStates") != MT_OK) return mt_fail(inst);
    *next_defined = mt_sampled(inst);
    *next_time = mt_sampled(inst) ? sample_time(inst, inst->k_next) : 0.0;
    return MT_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Directional and adjoint derivatives                                                         */

int mt_derivatives(mt_instance *inst, const unsigned int *unknowns, size_t n_unknowns, const unsigned int *knowns,
                   size_t n_knowns, const double *seed, size_t n_seed, double *sensitivity, size_t n_sensitivity,
                   int adjoint, const char *fn)
{
    const mt_model *m = inst->m;
    int nr = m->nx + m->ny;
    size_t a, b;
    if (n_seed != (adjoint ? n_unknowns : n_knowns) || n_sensitivity != (adjoint ? n_knowns : n_unknowns)) {
        LOG_ERROR(inst, "%s: %zu seeds and %zu sensitivities do not fit %zu unknowns and %zu knowns", fn, n_seed,
                  n_sensitivity, n_unknowns, n_knowns);
        return MT_ERROR;
    }
    if ((n_unknowns && !unknowns) || (n_knowns && !knowns) || (n_seed && !seed) || (n_sensitivity && !sensitivity)) {
        LOG_ERROR(inst, "%s: null pointer argument", fn);
        return MT_ERROR;
    }
    for (a = 0; a < n_unknowns; a++) {
        int i, bl = block_of(m, unknowns[a], &i);
        if (bl != B_X && bl != B_DX && bl != B_Y) {
            LOG_ERROR(inst, "%s: unknown %u (%s) is %s; derivatives are available for states, state derivatives "
                      "and computed outputs of the continuous part", fn, unknowns[a],
                      bl == B_NONE ? "?" : (bl == B_TIME ? "time" : m->names[unknowns[a]]), BLOCK_KIND[bl]);
            return MT_ERROR;
        }
    }
    for (b = 0; b < n_knowns; b++) {
        int i, bl = block_of(m, knowns[b], &i);
        if (bl != B_X && bl != B_U) {
            LOG_ERROR(inst, "%s: known %u (%s) is %s; derivatives are available with respect to states and "
                      "inputs", fn, knowns[b], bl == B_NONE ? "?" : (bl == B_TIME ? "time" : m->names[knowns[b]]),
                      BLOCK_KIND[bl]);
            return MT_ERROR;
        }
    }
    if (mt_refresh_initial_states(inst) || (nr > 0 && m->nx + m->nu > 0 && eval_jac(inst, inst->t, inst->x))) {
        LOG_ERROR(inst, "%s: evaluation of the Jacobian failed at t = %.17g", fn, inst->t);
        return MT_ERROR;
    }
    for (a = 0; a < n_sensitivity; a++) sensitivity[a] = 0.0;
    for (a = 0; a < n_unknowns; a++) {
        int i, bu = block_of(m, unknowns[a], &i);
        int row = bu == B_DX ? i : (bu == B_Y ? m->nx + i : -1);
        for (b = 0; b < n_knowns; b++) {
            int j, bk = block_of(m, knowns[b], &j);
            int col = bk == B_X ? j : m->nx + j;
            double d;
            if (row < 0)
                d = (bk == B_X && j == i) ? 1.0 : 0.0; /* a state with respect to the states */
            else
                d = inst->J[(size_t)row + (size_t)col * (size_t)nr];
            if (adjoint)
                sensitivity[b] += d * seed[a];
            else
                sensitivity[a] += d * seed[b];
        }
    }
    return MT_OK;
}

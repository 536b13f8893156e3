/* mt_snapshot.c: FMU state snapshots (GetFMUState / SetFMUState / (De)SerializeFMUState) of mt_runtime.
 *
 * The serialised form is the snapshot itself: magic, 8 header ints (token length, nx, nu, ny, nyd, nz, np,
 * interface type), the token, mode, at_sample, the sample counter (int64), t0, t, rtol, the solver's step
 * size h, then x[nx], the x_set flags[nx] (0 or 1, as doubles), u[nu], p[np], z[nz], z_pre[nz], yd[nyd].
 * A blob from outside (a file, another process) is checked field by field before anything is restored.
 */
#include "mt_runtime.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define LOG_ERROR(inst, ...) mt_log((inst), MT_ERROR, "logStatusError", __VA_ARGS__)

static const char MAGIC[8] = {'M', 'T', 'S', 'T', 'A', 'T', 'E', '1'};
#define HEADER_INTS 8 /* token length, nx, nu, ny, nyd, nz, np, co_simulation */

typedef struct {
    unsigned char *p;
    const unsigned char *q;
} cursor;

static size_t snapshot_size(const mt_model *m)
{
    size_t tok = strlen(m->token);
    size_t ndbl = 4 + (size_t)m->nx * 2 + (size_t)m->nu + (size_t)m->np + 2 * (size_t)m->nz + (size_t)m->nyd;
    return sizeof MAGIC + HEADER_INTS * sizeof(int32_t) + tok + 2 * sizeof(int32_t) + sizeof(int64_t) +
           ndbl * sizeof(double);
}

static void put(cursor *c, const void *src, size_t n)
{
    memcpy(c->p, src, n);
    c->p += n;
}

static void get(cursor *c, void *dst, size_t n)
{
    memcpy(dst, c->q, n);
    c->q += n;
}

static void put_i32(cursor *c, int v)
{
    int32_t x = (int32_t)v;
    put(c, &x, sizeof x);
}

static int get_i32(cursor *c)
{
    int32_t x;
    get(c, &x, sizeof x);
    return (int)x;
}

static double get_f64(cursor *c)
{
    double x;
    get(c, &x, sizeof x);
    return x;
}

mt_snapshot *mt_snapshot_take(mt_instance *inst, mt_snapshot *reuse)
{
    const mt_model *m = inst->m;
    size_t size = snapshot_size(m), tok = strlen(m->token);
    mt_snapshot *s = reuse;
    cursor c;
    int64_t k = inst->k_next;
    int i;
    if (mt_refresh_initial_states(inst)) return NULL;
    if (!s || s->size != size) {
        free(s);
        s = malloc(sizeof *s + size);
        if (!s) {
            LOG_ERROR(inst, "GetFMUState: out of memory");
            return NULL;
        }
        s->size = size;
    }
    c.p = s->data;
    put(&c, MAGIC, sizeof MAGIC);
    put_i32(&c, (int)tok);
    put_i32(&c, m->nx);
    put_i32(&c, m->nu);
    put_i32(&c, m->ny);
    put_i32(&c, m->nyd);
    put_i32(&c, m->nz);
    put_i32(&c, m->np);
    put_i32(&c, inst->co_simulation);
    put(&c, m->token, tok);
    put_i32(&c, inst->mode);
    put_i32(&c, inst->at_sample);
    put(&c, &k, sizeof k);
    put(&c, &inst->t0, sizeof(double));
    put(&c, &inst->t, sizeof(double));
    put(&c, &inst->rtol, sizeof(double));
    put(&c, &inst->solver.h, sizeof(double));
    put(&c, inst->x, (size_t)m->nx * sizeof(double));
    for (i = 0; i < m->nx; i++) {
        double flag = inst->x_set[i];
        put(&c, &flag, sizeof flag);
    }
    put(&c, inst->u, (size_t)m->nu * sizeof(double));
    put(&c, inst->p, (size_t)m->np * sizeof(double));
    put(&c, inst->z, (size_t)m->nz * sizeof(double));
    put(&c, inst->z_pre, (size_t)m->nz * sizeof(double));
    put(&c, inst->yd, (size_t)m->nyd * sizeof(double));
    return s;
}

/* Checks magic, header sizes, byte count and token; leaves c after the token. */
static int check_header(mt_instance *inst, const unsigned char *data, size_t size, cursor *c, const char *fn)
{
    const mt_model *m = inst->m;
    size_t tok = strlen(m->token);
    const int expect[HEADER_INTS] = {(int)tok, m->nx, m->nu, m->ny, m->nyd, m->nz, m->np, inst->co_simulation};
    static const char *const what[HEADER_INTS] = {"token length", "nx", "nu", "ny", "nyd", "nz", "np",
                                                  "interface type"};
    int i;
    if (!data) {
        LOG_ERROR(inst, "%s: null FMU state", fn);
        return MT_ERROR;
    }
    if (size < sizeof MAGIC + HEADER_INTS * sizeof(int32_t) || memcmp(data, MAGIC, sizeof MAGIC) != 0) {
        LOG_ERROR(inst, "%s: not an FMU state of a motiontwin FMU (bad header)", fn);
        return MT_ERROR;
    }
    c->q = data + sizeof MAGIC;
    for (i = 0; i < HEADER_INTS; i++) {
        int v = get_i32(c);
        if (v != expect[i]) {
            LOG_ERROR(inst, "%s: FMU state of another model or interface: %s is %d, expected %d", fn, what[i], v,
                      expect[i]);
            return MT_ERROR;
        }
    }
    if (size != snapshot_size(m)) {
        LOG_ERROR(inst, "%s: FMU state has %zu bytes, expected %zu", fn, size, snapshot_size(m));
        return MT_ERROR;
    }
    if (memcmp(c->q, m->token, tok) != 0) {
        LOG_ERROR(inst, "%s: FMU state was saved by another model (token differs from %s)", fn, m->token);
        return MT_ERROR;
    }
    c->q += tok;
    return MT_OK;
}

static int refuse(mt_instance *inst, const char *fn, const char *field, double value, const char *rule)
{
    LOG_ERROR(inst, "%s: FMU state refused: %s = %.17g %s", fn, field, value, rule);
    return MT_ERROR;
}

/* n doubles of one kind of variable (first value reference vr0): finite, or NaN where nan_ok (a parameter
 * without a value before initialisation); inside [min, max] where ranged. */
static int check_values(mt_instance *inst, cursor *c, int n, unsigned int vr0, const char *kind, int nan_ok,
                        int ranged, const char *fn)
{
    const mt_model *m = inst->m;
    char field[256];
    int i;
    for (i = 0; i < n; i++) {
        unsigned int vr = vr0 + (unsigned int)i;
        double v = get_f64(c);
        snprintf(field, sizeof field, "%s %s", kind, m->names && (int)vr < m->nvr ? m->names[vr] : "?");
        if (isnan(v) && nan_ok) continue;
        if (!isfinite(v)) return refuse(inst, fn, field, v, "is not finite");
        if (ranged && m->min && v < m->min[vr]) return refuse(inst, fn, field, v, "is below its minimum");
        if (ranged && m->max && v > m->max[vr]) return refuse(inst, fn, field, v, "is above its maximum");
    }
    return MT_OK;
}

/* Field-by-field check of everything after the token (c positioned there). */
static int check_fields(mt_instance *inst, cursor *c, const char *fn)
{
    const mt_model *m = inst->m;
    const unsigned int vr_x = 1, vr_u = vr_x + 2u * (unsigned)m->nx, vr_z = vr_u + (unsigned)(m->nu + m->ny + m->nyd),
                       vr_p = vr_z + (unsigned)m->nz, vr_yd = vr_u + (unsigned)(m->nu + m->ny);
    int mode = get_i32(c), at_sample = get_i32(c), started, i;
    int allowed = MT_INSTANTIATED | MT_INIT | MT_TERMINATED | (inst->co_simulation ? MT_STEP | MT_EVENT
                                                                                    : MT_EVENT | MT_CONTINUOUS);
    int64_t k;
    double t0, t, rtol, h, ts = 1.0;
    get(c, &k, sizeof k);
    t0 = get_f64(c);
    t = get_f64(c);
    rtol = get_f64(c);
    h = get_f64(c);
    if (!(mode & allowed) || (mode & (mode - 1)))
        return refuse(inst, fn, "mode", mode, "is no mode of this interface type");
    started = !(mode & (MT_INSTANTIATED | MT_INIT));
    if (at_sample != 0 && at_sample != 1) return refuse(inst, fn, "at-sample flag", at_sample, "is not 0 or 1");
    if (k < 0 || k > (int64_t)1 << 53) return refuse(inst, fn, "sample counter", (double)k, "is outside [0, 2^53]");
    if (!isfinite(t0)) return refuse(inst, fn, "start time", t0, "is not finite");
    if (!isfinite(t)) return refuse(inst, fn, "time", t, "is not finite");
    if (!(rtol > 0.0 && rtol < 1.0)) return refuse(inst, fn, "relative tolerance", rtol, "is not in (0, 1)");
    if (!(h >= 0.0) || !isfinite(h)) return refuse(inst, fn, "solver step size", h, "is not finite and >= 0");
    if (check_values(inst, c, m->nx, vr_x, "state", !started, 0, fn)) return MT_ERROR;
    for (i = 0; i < m->nx; i++) {
        double flag = get_f64(c);
        if (flag != 0.0 && flag != 1.0) return refuse(inst, fn, "start-value flag of a state", flag, "is not 0 or 1");
    }
    if (check_values(inst, c, m->nu, vr_u, "input", 0, 0, fn)) return MT_ERROR;
    if (mt_sampled(inst)) memcpy(&ts, c->q + (size_t)m->ts_index * sizeof(double), sizeof ts);
    if (check_values(inst, c, m->np, vr_p, "parameter", !started, started, fn)) return MT_ERROR;
    if (check_values(inst, c, m->nz, vr_z, "discrete state", 0, 0, fn)) return MT_ERROR;
    if (check_values(inst, c, m->nz, vr_z, "previous discrete state", 0, 0, fn)) return MT_ERROR;
    if (check_values(inst, c, m->nyd, vr_yd, "sampled output", 0, 0, fn)) return MT_ERROR;
    if (started && !(ts > 0.0)) return refuse(inst, fn, "sample period", ts, "is not > 0");
    return MT_OK;
}

int mt_snapshot_restore(mt_instance *inst, const unsigned char *data, size_t size, int apply, const char *fn)
{
    const mt_model *m = inst->m;
    cursor c, fields;
    int i;
    int64_t k;
    double d[4];
    if (check_header(inst, data, size, &c, fn) != MT_OK) return MT_ERROR;
    fields = c;
    if (check_fields(inst, &fields, fn) != MT_OK) return MT_ERROR;
    if (!apply) return MT_OK;
    inst->mode = get_i32(&c);
    inst->at_sample = get_i32(&c);
    get(&c, &k, sizeof k);
    inst->k_next = k;
    get(&c, d, sizeof d);
    inst->t0 = d[0];
    inst->t = d[1];
    inst->rtol = d[2];
    inst->solver.h = d[3];
    get(&c, inst->x, (size_t)m->nx * sizeof(double));
    for (i = 0; i < m->nx; i++) inst->x_set[i] = get_f64(&c) != 0.0;
    get(&c, inst->u, (size_t)m->nu * sizeof(double));
    get(&c, inst->p, (size_t)m->np * sizeof(double));
    inst->S_valid = 0;
    get(&c, inst->z, (size_t)m->nz * sizeof(double));
    get(&c, inst->z_pre, (size_t)m->nz * sizeof(double));
    get(&c, inst->yd, (size_t)m->nyd * sizeof(double));
    return MT_OK;
}

/* Compiled inner loop of the co-simulation master (harness/master.py), model-agnostic.
 *
 * Runs ticks k_start..k_end-1 of the same Gauss-Seidel plan as Master._loop_python: per tick,
 * copy the external input row, snapshot the "pre" log columns, then per FMU in stepping order
 * (when k % m == 0): gather its inputs (sum of gain * source, summed in source order, no fused
 * multiply-add), set them, doStep (last step shortened to the run end), get its outputs; then
 * snapshot the "post" log columns. All values live in one flat double buffer owned by Python.
 * FMI functions are the FMU's own, passed as pointers. Compiled with -ffp-contract=off so the
 * arithmetic is bit-identical to the numpy path. Times in seconds.
 */
#define _POSIX_C_SOURCE 199309L
#include <stddef.h>
#include <stdbool.h>
#include <time.h>

typedef int (*fmi2_get_set_t)(void *, const unsigned int *, size_t, double *);
typedef int (*fmi2_do_step_t)(void *, double, double, int);
typedef int (*fmi3_get_set_t)(void *, const unsigned int *, size_t, double *, size_t);
typedef int (*fmi3_do_step_t)(void *, double, double, bool, bool *, bool *, bool *, double *);

typedef struct {
    int fmi3;
    int m;                      /* communication step in base steps */
    void *component;
    void *get, *set, *do_step;  /* fmi2GetReal/SetReal/DoStep or fmi3GetFloat64/SetFloat64/DoStep */
    const unsigned int *read_vrs; size_t n_read_vrs; double *read_values; size_t n_read_values;
    const unsigned int *input_vrs; size_t n_inputs; double *input_values;
    const int *port_start;      /* n_inputs + 1 offsets into source_slots / source_gains */
    const int *source_slots;
    const double *source_gains; /* NULL: every input is a plain copy of its one source */
    int profile;                /* nonzero: add the wall time spent inside doStep to step_seconds */
    double step_seconds;
} mt_fmu;

typedef struct {
    int m;                      /* log every m base steps */
    double *data;               /* rows x n_columns, C order */
    int n_columns;
    int n_pre; const int *pre_slots; const int *pre_columns;
    int n_post; const int *post_slots; const int *post_columns;
} mt_log;

typedef struct {
    int fmu;                    /* index into the fmus array */
    int call;                   /* 0 get, 1 set, 2 doStep, 3 doStep asked to terminate */
    long tick;
    int status;
} mt_failure;

enum { MT_OK = 0, MT_FAILED = 1 };

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}
enum { CALL_GET = 0, CALL_SET = 1, CALL_STEP = 2, CALL_TERMINATE = 3 };
#define FMI_WARNING 1

static void gather(const mt_fmu *f, const double *values) {
    for (size_t i = 0; i < f->n_inputs; i++) {
        int lo = f->port_start[i], hi = f->port_start[i + 1];
        double acc;
        if (f->source_gains == NULL) {
            acc = values[f->source_slots[lo]];
        } else {
            acc = f->source_gains[lo] * values[f->source_slots[lo]];
            for (int j = lo + 1; j < hi; j++) {
                double term = f->source_gains[j] * values[f->source_slots[j]];
                acc = acc + term;
            }
        }
        f->input_values[i] = acc;
    }
}

static void snapshot(const mt_log *logs, int n_logs, const double *values, long k, int post) {
    for (int g = 0; g < n_logs; g++) {
        const mt_log *l = &logs[g];
        if (k % l->m) continue;
        double *row = l->data + (size_t)(k / l->m) * (size_t)l->n_columns;
        int n = post ? l->n_post : l->n_pre;
        const int *slots = post ? l->post_slots : l->pre_slots;
        const int *columns = post ? l->post_columns : l->pre_columns;
        for (int i = 0; i < n; i++) row[columns[i]] = values[slots[i]];
    }
}

/* Returns MT_OK, or MT_FAILED with *failure filled at the first call whose status is above
 * warning (fmpy raises for those) or the first fmi3DoStep that asks to terminate. */
int mt_run_ticks(mt_fmu *fmus, int n_fmus, const mt_log *logs, int n_logs, double *values,
                 const double *external, int external_offset, int n_external,
                 long k_start, long k_end, long n_steps, double start_time, double base_step,
                 mt_failure *failure) {
    for (long k = k_start; k < k_end; k++) {
        const double *row = external + (size_t)k * (size_t)n_external;
        for (int j = 0; j < n_external; j++) values[external_offset + j] = row[j];
        snapshot(logs, n_logs, values, k, 0);
        double t = start_time + (double)k * base_step;
        for (int i = 0; i < n_fmus; i++) {
            mt_fmu *f = &fmus[i];
            if (k % f->m) continue;
            double h = (double)(k + f->m <= n_steps ? f->m : n_steps - k) * base_step;
            int status, call;
            bool terminate = false;
            if (f->n_inputs) {
                gather(f, values);
                status = f->fmi3 ? ((fmi3_get_set_t)f->set)(f->component, f->input_vrs, f->n_inputs,
                                                             f->input_values, f->n_inputs)
                                 : ((fmi2_get_set_t)f->set)(f->component, f->input_vrs, f->n_inputs,
                                                             f->input_values);
                call = CALL_SET;
                if (status > FMI_WARNING) goto failed;
            }
            double started = f->profile ? now() : 0.0;
            if (f->fmi3) {
                bool event = false, early = false;
                double last = 0.0;
                status = ((fmi3_do_step_t)f->do_step)(f->component, t, h, false, &event, &terminate,
                                                      &early, &last);
            } else {
                status = ((fmi2_do_step_t)f->do_step)(f->component, t, h, 1);
            }
            if (f->profile) f->step_seconds += now() - started;
            call = CALL_STEP;
            if (status > FMI_WARNING) goto failed;
            if (terminate) { call = CALL_TERMINATE; status = 0; goto failed; }
            if (f->n_read_vrs) {
                status = f->fmi3 ? ((fmi3_get_set_t)f->get)(f->component, f->read_vrs, f->n_read_vrs,
                                                             f->read_values, f->n_read_values)
                                 : ((fmi2_get_set_t)f->get)(f->component, f->read_vrs, f->n_read_vrs,
                                                             f->read_values);
                call = CALL_GET;
                if (status > FMI_WARNING) goto failed;
            }
            continue;
        failed:
            failure->fmu = i;
            failure->call = call;
            failure->tick = k;
            failure->status = status;
            return MT_FAILED;
        }
        snapshot(logs, n_logs, values, k, 1);
    }
    return MT_OK;
}

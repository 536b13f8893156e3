/* mt_runtime.h: the model-agnostic part of the FMU shared by fmi2.c and fmi3.c.
 *
 * One mt_instance per FMU instance: the variables of the descriptor MT_MODEL (mt_model.h), the
 * FMI state machine, logging, Co-Simulation stepping with the Rosenbrock solver (mt_solver.h),
 * the sampled part, FMU state snapshots and directional derivatives. The FMI 2.0 and 3.0 layers
 * only translate their calling conventions to these functions. Units are those of the model.
 */
#ifndef MT_RUNTIME_H
#define MT_RUNTIME_H

#include <stddef.h>

#include "mt_model.h"
#include "mt_solver.h"

/* Status codes: the numeric values of fmi2Status and fmi3Status agree for these. */
enum { MT_OK = 0, MT_WARNING = 1, MT_DISCARD = 2, MT_ERROR = 3, MT_FATAL = 4 };

/* Modes of the FMI state machines (bit flags, so that a function can list where it is allowed). */
enum {
    MT_INSTANTIATED = 1 << 0,
    MT_INIT = 1 << 1,
    MT_EVENT = 1 << 2,        /* Model Exchange (and FMI 3.0 CS with eventModeUsed) event mode */
    MT_CONTINUOUS = 1 << 3,   /* Model Exchange continuous-time mode */
    MT_STEP = 1 << 4,         /* Co-Simulation step mode */
    MT_TERMINATED = 1 << 5,
    MT_FAILED = 1 << 6        /* after an error: only getters, set state, reset and free */
};
#define MT_ANY_MODE 0x7f

struct mt_instance;
/* Hands a finished message to the importer's logger (FMI-version specific). */
typedef void (*mt_emit_fn)(struct mt_instance *inst, int status, const char *category, const char *message);

typedef struct mt_instance {
    const mt_model *m;
    char *name;
    int co_simulation;        /* 1: Co-Simulation, 0: Model Exchange */
    int event_mode_used;      /* FMI 3.0 Co-Simulation: the importer uses Event Mode */
    int fmi_version;          /* 2 or 3 */
    int mode;
    /* logging */
    mt_emit_fn emit;
    void (*logger)(void);     /* the importer's callback (cast back by emit) */
    void *env;                /* its environment pointer */
    int logging_on, log_events, log_errors;
    /* experiment */
    double t0, t, rtol;
    /* variables */
    double *x, *u, *p, *z, *z_pre, *yd;
    unsigned char *x_set;     /* 1 where the user set a state's start value */
    /* sampled part */
    long long k_next;         /* index of the next sample instant t0 + k*Ts not yet executed */
    int at_sample;            /* 1 while the time equals the instant of the last executed sample */
    /* scratch */
    double *dx, *y, *J, *znext, *scratch;
    double *S, *zu;           /* sample_matrix(p) and [z; u] for a linear sampled part */
    int S_valid;              /* 0 when p changed since S was evaluated */
    const double **arg;
    double **res;
    mt_int *iw;
    double *w;
    mt_solver solver;
} mt_instance;

/* Lifecycle. mt_instantiate logs through emit and returns NULL on failure. */
mt_instance *mt_instantiate(const char *name, const char *token, int co_simulation, int fmi_version,
                            mt_emit_fn emit, void (*logger)(void), void *env, int logging_on);
void mt_free(mt_instance *inst);
void mt_reset(mt_instance *inst);

/* Registry of live instances (those mt_instantiate returned and no FreeInstance has released). The FMI
 * layers check every instance pointer against it before using it, so a second free of an instance or a
 * pointer that is no instance of this FMU is refused with a message on stderr (the importer's logger
 * belongs to an instance, which such a pointer is not) instead of reading freed memory. */
/* 1 when ptr is a live instance; else writes "fn: ..." to stderr and returns 0. NULL: 0, no message. */
int mt_live(const void *ptr, const char *fn);
/* FreeInstance: unregisters and frees a live instance; NULL does nothing; any other pointer is refused
 * with a message (a second free included). */
void mt_release(void *ptr, const char *fn);

/* printf-style message; warnings, discards and errors always reach the logger, MT_OK messages only
 * when their category is enabled. */
void mt_log(mt_instance *inst, int status, const char *category, const char *fmt, ...)
#ifdef __GNUC__
    __attribute__((format(printf, 4, 5)))
#endif
    ;
/* 1 when inst is in one of the modes of mask, else logs an illegal call of fn and returns 0. */
int mt_allowed(mt_instance *inst, int mask, const char *fn);
int mt_set_debug_logging(mt_instance *inst, int on, size_t n, const char *const *categories);
/* Enter the failed mode after a run-time error; returns MT_ERROR. */
int mt_fail(mt_instance *inst);

/* Variable access by value reference. */
int mt_get_float64(mt_instance *inst, const unsigned int *vr, size_t n, double *value, const char *fn);
int mt_set_float64(mt_instance *inst, const unsigned int *vr, size_t n, const double *value, const char *fn);
/* Error for a value reference of another type (the model has only Float64 variables). */
int mt_wrong_type(mt_instance *inst, const unsigned int *vr, size_t n, const char *type, const char *fn);

/* Initialisation. */
int mt_setup(mt_instance *inst, int tolerance_defined, double tolerance, double start_time);
int mt_exit_initialization(mt_instance *inst);

/* Enter Terminated; logs the solver statistics (category logEvents). */
int mt_terminate(mt_instance *inst);

/* Co-Simulation: integrate from t to t + h (h >= 0). */
int mt_do_step(mt_instance *inst, double t, double h, const char *fn);

/* Model Exchange. */
int mt_set_time(mt_instance *inst, double t);
int mt_set_states(mt_instance *inst, const double *x, size_t n, const char *fn);
int mt_get_states(mt_instance *inst, double *x, size_t n, const char *fn);
int mt_get_derivatives(mt_instance *inst, double *dx, size_t n, const char *fn);
int mt_get_nominals(mt_instance *inst, double *nominals, size_t n, const char *fn);
int mt_check_event_indicators(mt_instance *inst, size_t n, const char *fn);
/* Executes the samples due at the current time; reports the next time event. */
int mt_update_discrete(mt_instance *inst, int *next_defined, double *next_time);

/* Before exit of initialisation: the states follow x0(p) except where the user set a start value.
 * Returns -1 when x0 fails to evaluate. */
int mt_refresh_initial_states(mt_instance *inst);
/* 1 when the model has a sampled part. */
int mt_sampled(const mt_instance *inst);

/* FMU state snapshots (mt_snapshot.c): a byte blob, the serialised form is the snapshot itself. */
typedef struct {
    size_t size;
    unsigned char data[];
} mt_snapshot;
mt_snapshot *mt_snapshot_take(mt_instance *inst, mt_snapshot *reuse);
/* Validates data (magic, token, sizes, then every field: mode, counters, times, tolerance, step size, the
 * variables' finiteness and ranges) and, when apply is 1, restores the instance from it. A refused state is
 * named field by field in the log and leaves the instance unchanged. */
int mt_snapshot_restore(mt_instance *inst, const unsigned char *data, size_t size, int apply, const char *fn);

/* d unknowns / d knowns times seed (adjoint: transposed). Unknowns: states, derivatives, y;
 * knowns: states, inputs. */
int mt_derivatives(mt_instance *inst, const unsigned int *unknowns, size_t n_unknowns, const unsigned int *knowns,
                   size_t n_knowns, const double *seed, size_t n_seed, double *sensitivity,
                   size_t n_sensitivity, int adjoint, const char *fn);

#endif

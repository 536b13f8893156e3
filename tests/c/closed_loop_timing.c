/* Wall time per doStep of the 4-DOF closed loop in pure C (no Python): four controller instances of one
 * FMI 2.0 CS binary around one plant instance, replaying a reference profile, with the plant's solver
 * statistics (from the logEvents message of fmi2Terminate).
 *
 * Usage: closed_loop_timing PLANT.so PLANT_GUID CTRL.so CTRL_GUID INPUTS [Q_OUT [PLANT_RTOL]]
 * INPUTS (text): ncp; per controller ncp pairs "vr value"; 4 additive plant forces [N]; n; then n + 1 rows of
 * 16 numbers (per joint: position [m], velocity [m/s], acceleration [m/s^2], jerk [m/s^3]).
 * Fixed value references: controller r, q, r_dot, r_ddot, r_dddot = 1..5, u = 6; plant u1..u7 = 17..20,
 * q1..q7 = 21..24 (CheungManipulator / RobustJointController). Ts = 5e-4 s.
 * Prints per-doStep means of thread CPU time (the clock's own cost, measured, is subtracted), split into
 * ticks while the reference moves and ticks at rest, and the loop's wall time. Q_OUT receives
 * t, q1..q7, u1..u7 per tick (%.17g) for comparing two builds ("-": none). PLANT_RTOL: the tolerance passed
 * to the plant's fmi2SetupExperiment (default: none, the FMU's 1e-8). */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "fmi2Functions.h"

#define TS 5e-4
#define NJ 4

typedef struct {
    fmi2InstantiateTYPE *instantiate;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_init;
    fmi2SetRealTYPE *set;
    fmi2GetRealTYPE *get;
    fmi2DoStepTYPE *step;
    fmi2TerminateTYPE *terminate;
    fmi2FreeInstanceTYPE *free_instance;
} api;

static void logger(fmi2ComponentEnvironment env, fmi2String inst, fmi2Status st, fmi2String cat, fmi2String msg,
                   ...)
{
    (void)env;
    if (strstr(msg, "Terminate") || st != fmi2OK) printf("  [%s] %s\n", inst, msg);
}

static int load(const char *path, api *a)
{
    void *lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "%s\n", dlerror());
        return -1;
    }
    a->instantiate = (fmi2InstantiateTYPE *)dlsym(lib, "fmi2Instantiate");
    a->setup = (fmi2SetupExperimentTYPE *)dlsym(lib, "fmi2SetupExperiment");
    a->enter = (fmi2EnterInitializationModeTYPE *)dlsym(lib, "fmi2EnterInitializationMode");
    a->exit_init = (fmi2ExitInitializationModeTYPE *)dlsym(lib, "fmi2ExitInitializationMode");
    a->set = (fmi2SetRealTYPE *)dlsym(lib, "fmi2SetReal");
    a->get = (fmi2GetRealTYPE *)dlsym(lib, "fmi2GetReal");
    a->step = (fmi2DoStepTYPE *)dlsym(lib, "fmi2DoStep");
    a->terminate = (fmi2TerminateTYPE *)dlsym(lib, "fmi2Terminate");
    a->free_instance = (fmi2FreeInstanceTYPE *)dlsym(lib, "fmi2FreeInstance");
    return a->instantiate && a->step ? 0 : -1;
}

/* CPU time of this thread: on a loaded machine the wall time mostly measures the scheduler. */
static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double wall(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

int main(int argc, char **argv)
{
    api P, C;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    FILE *in, *out = NULL;
    int ncp, j, i;
    long n, k, n_move = 0;
    unsigned cp_vr[NJ][32], c_in[5] = {1, 2, 3, 4, 5}, c_out = 6, u_vr[NJ] = {17, 18, 19, 20},
                            q_vr[NJ] = {21, 22, 23, 24};
    double cp[NJ][32], hold[NJ], q[NJ], u[NJ], *ref;
    double t_plant_move = 0, t_plant_rest = 0, t_ctrl = 0, t_all, t_wall, clock_cost;
    fmi2Component plant, ctrl[NJ];
    if (argc < 6 || load(argv[1], &P) || load(argv[3], &C)) {
        fprintf(stderr, "usage: %s PLANT.so PLANT_GUID CTRL.so CTRL_GUID INPUTS [Q_OUT [PLANT_RTOL]]\n", argv[0]);
        return 2;
    }
    in = fopen(argv[5], "r");
    if (!in || fscanf(in, "%d", &ncp) != 1 || ncp > 32) return 2;
    for (j = 0; j < NJ; j++)
        for (i = 0; i < ncp; i++)
            if (fscanf(in, "%u %lf", &cp_vr[j][i], &cp[j][i]) != 2) return 2;
    for (j = 0; j < NJ; j++)
        if (fscanf(in, "%lf", &hold[j]) != 1) return 2;
    if (fscanf(in, "%ld", &n) != 1) return 2;
    ref = malloc(sizeof(double) * 16 * (size_t)(n + 1));
    for (k = 0; k < 16 * (n + 1); k++)
        if (fscanf(in, "%lf", &ref[k]) != 1) return 2;
    fclose(in);
    if (argc > 6 && strcmp(argv[6], "-") != 0) out = fopen(argv[6], "w");

    plant = P.instantiate("plant", fmi2CoSimulation, argv[2], "", &cb, 0, 1);
    if (!plant) return 3;
    P.setup(plant, argc > 7, argc > 7 ? atof(argv[7]) : 0.0, 0, 0, 0);
    P.enter(plant);
    P.exit_init(plant);
    for (j = 0; j < NJ; j++) {
        char name[8];
        snprintf(name, sizeof name, "c%d", 2 * j + 1);
        ctrl[j] = C.instantiate(name, fmi2CoSimulation, argv[4], "", &cb, 0, 0);
        if (!ctrl[j]) return 3;
        C.setup(ctrl[j], 0, 0, 0, 0, 0);
        C.enter(ctrl[j]);
        C.set(ctrl[j], cp_vr[j], (size_t)ncp, cp[j]);
        C.exit_init(ctrl[j]);
    }
    clock_cost = now();
    for (k = 0; k < 1000; k++) now();
    clock_cost = (now() - clock_cost) / 1001;
    P.get(plant, q_vr, NJ, q);
    t_wall = wall();
    t_all = now();
    for (k = 0; k < n; k++) {
        double t = k * TS, a, b, *r = ref + 16 * k;
        int moving = 0;
        a = now();
        for (j = 0; j < NJ; j++) {
            double v[5] = {r[4 * j], q[j], r[4 * j + 1], r[4 * j + 2], r[4 * j + 3]};
            moving |= v[2] != 0.0;
            C.set(ctrl[j], c_in, 5, v);
            if (C.step(ctrl[j], t, TS, 1) > fmi2Warning) return 4;
            C.get(ctrl[j], &c_out, 1, &u[j]);
            u[j] += hold[j];
        }
        b = now();
        t_ctrl += b - a;
        P.set(plant, u_vr, NJ, u);
        if (P.step(plant, t, TS, 1) > fmi2Warning) return 5;
        P.get(plant, q_vr, NJ, q);
        a = now();
        if (moving) {
            t_plant_move += a - b;
            n_move++;
        } else {
            t_plant_rest += a - b;
        }
        if (out)
            fprintf(out, "%.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", t + TS, q[0], q[1], q[2], q[3],
                    u[0], u[1], u[2], u[3]);
    }
    t_all = now() - t_all;
    t_wall = wall() - t_wall;
    t_ctrl -= n * clock_cost;
    t_plant_move -= n_move * clock_cost;
    t_plant_rest -= (n - n_move) * clock_cost;
    printf("%ld ticks of %g s (%ld moving): loop %.2f us/tick CPU (%.0fx real time), %.2f us/tick wall; "
           "clock %.3f us/call\n", n, TS, n_move, 1e6 * t_all / n, n * TS / t_all, 1e6 * t_wall / n, 1e6 * clock_cost);
    printf("  plant doStep+set/get: %.2f us moving, %.2f us at rest, %.2f us mean\n",
           n_move ? 1e6 * t_plant_move / n_move : 0.0, n > n_move ? 1e6 * t_plant_rest / (n - n_move) : 0.0,
           1e6 * (t_plant_move + t_plant_rest) / n);
    printf("  controller set/doStep/get: %.3f us each (4 per tick: %.2f us)\n", 1e6 * t_ctrl / n / NJ,
           1e6 * t_ctrl / n);
    printf("RATIO closed_loop_c.realtime_factor_cpu=%.6g baseline=simulated time / CPU time of the pure C loop\n",
           n * TS / t_all);
    fflush(stdout);
    P.terminate(plant);
    P.free_instance(plant);
    for (j = 0; j < NJ; j++) {
        C.terminate(ctrl[j]);
        C.free_instance(ctrl[j]);
    }
    if (out) fclose(out);
    free(ref);
    return 0;
}

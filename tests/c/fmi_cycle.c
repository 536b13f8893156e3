/* A full FMI life cycle on one FMU binary, for valgrind: instantiate, initialise, step, get/set/serialize
 * state, Model Exchange calls, free, then a second free and calls on invalid instance pointers; refused calls
 * too: a getter before initialisation, a serialised state with a NaN tolerance. Usage: fmi_cycle LIB.so 2|3 TOKEN NVR INPUT_VR NX
 * Exit code 0 when every call that should succeed did. */
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
#include "fmi3Functions.h"

static int failures = 0;
#define CHECK(call) do { int s_ = (int)(call); if (s_ != 0) { fprintf(stderr, "%s -> %d\n", #call, s_); failures++; } } while (0)
#define SYM(type, name) type name = (type)dlsym(lib, #name); if (!name) { fprintf(stderr, "missing %s\n", #name); return 2; }

static void logger2(fmi2ComponentEnvironment env, fmi2String inst, fmi2Status st, fmi2String cat, fmi2String msg, ...) {
    (void)env; (void)inst; (void)st; (void)cat; (void)msg;
}
static void logger3(fmi3InstanceEnvironment env, fmi3Status st, fmi3String cat, fmi3String msg) {
    (void)env; (void)st; (void)cat; (void)msg;
}

/* NaN into the relative tolerance of a serialised state (layout: fmus/runtime/mt_snapshot.c). */
static void corrupt_tolerance(void *blob, const char *token) {
    double nan_value = NAN;
    memcpy((char *)blob + 8 + 8 * 4 + strlen(token) + 32, &nan_value, sizeof nan_value);
}

static int run2(void *lib, const char *token, int nvr, unsigned input_vr, int nx) {
    SYM(fmi2InstantiateTYPE *, fmi2Instantiate) SYM(fmi2FreeInstanceTYPE *, fmi2FreeInstance)
    SYM(fmi2SetupExperimentTYPE *, fmi2SetupExperiment) SYM(fmi2EnterInitializationModeTYPE *, fmi2EnterInitializationMode)
    SYM(fmi2ExitInitializationModeTYPE *, fmi2ExitInitializationMode) SYM(fmi2DoStepTYPE *, fmi2DoStep)
    SYM(fmi2GetRealTYPE *, fmi2GetReal) SYM(fmi2SetRealTYPE *, fmi2SetReal) SYM(fmi2TerminateTYPE *, fmi2Terminate)
    SYM(fmi2GetFMUstateTYPE *, fmi2GetFMUstate) SYM(fmi2SetFMUstateTYPE *, fmi2SetFMUstate)
    SYM(fmi2FreeFMUstateTYPE *, fmi2FreeFMUstate) SYM(fmi2SerializedFMUstateSizeTYPE *, fmi2SerializedFMUstateSize)
    SYM(fmi2SerializeFMUstateTYPE *, fmi2SerializeFMUstate) SYM(fmi2DeSerializeFMUstateTYPE *, fmi2DeSerializeFMUstate)
    SYM(fmi2GetDerivativesTYPE *, fmi2GetDerivatives) SYM(fmi2SetTimeTYPE *, fmi2SetTime)
    SYM(fmi2SetContinuousStatesTYPE *, fmi2SetContinuousStates) SYM(fmi2GetContinuousStatesTYPE *, fmi2GetContinuousStates)
    SYM(fmi2EnterContinuousTimeModeTYPE *, fmi2EnterContinuousTimeMode) SYM(fmi2NewDiscreteStatesTYPE *, fmi2NewDiscreteStates)
    SYM(fmi2ResetTYPE *, fmi2Reset)
    fmi2CallbackFunctions cb = {logger2, calloc, free, NULL, NULL};
    unsigned vrs[4096]; double vals[4096];
    for (int i = 0; i < nvr - 1 && i < 4096; i++) vrs[i] = (unsigned)(i + 1);
    /* Co-Simulation */
    fmi2Component c = fmi2Instantiate("cs", fmi2CoSimulation, token, "", &cb, fmi2False, fmi2True);
    if (!c) return 3;
    if (fmi2GetReal(c, vrs, 1, vals) != fmi2Error) failures++;  /* not in Instantiated */
    CHECK(fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0));
    CHECK(fmi2EnterInitializationMode(c));
    double u = 3.0;
    CHECK(fmi2SetReal(c, &input_vr, 1, &u));
    CHECK(fmi2ExitInitializationMode(c));
    for (int k = 0; k < 50; k++) CHECK(fmi2DoStep(c, k * 1e-3, 1e-3, fmi2True));
    CHECK(fmi2GetReal(c, vrs, (size_t)(nvr - 1), vals));
    fmi2FMUstate s = NULL;
    CHECK(fmi2GetFMUstate(c, &s));
    CHECK(fmi2DoStep(c, 0.05, 1e-3, fmi2True));
    CHECK(fmi2SetFMUstate(c, s));
    size_t n = 0;
    CHECK(fmi2SerializedFMUstateSize(c, s, &n));
    char *blob = malloc(n);
    CHECK(fmi2SerializeFMUstate(c, s, blob, n));
    fmi2FMUstate s2 = NULL;
    CHECK(fmi2DeSerializeFMUstate(c, blob, n, &s2));
    CHECK(fmi2SetFMUstate(c, s2));
    corrupt_tolerance(blob, token);
    if (fmi2DeSerializeFMUstate(c, blob, n, &s2) != fmi2Error) failures++;
    free(blob);
    CHECK(fmi2FreeFMUstate(c, &s));
    CHECK(fmi2FreeFMUstate(c, &s2));
    if (fmi2DoStep(c, 0.0, -1.0, fmi2True) == fmi2OK) failures++;  /* must be refused */
    CHECK(fmi2Reset(c));
    CHECK(fmi2Terminate(c) == fmi2OK ? 0 : 0);
    fmi2FreeInstance(c);
    /* Model Exchange */
    c = fmi2Instantiate("me", fmi2ModelExchange, token, "", &cb, fmi2False, fmi2True);
    if (!c) return 4;
    CHECK(fmi2SetupExperiment(c, fmi2False, 0, 0, fmi2False, 0));
    CHECK(fmi2EnterInitializationMode(c));
    CHECK(fmi2ExitInitializationMode(c));
    fmi2EventInfo info; memset(&info, 0, sizeof info);
    CHECK(fmi2NewDiscreteStates(c, &info));
    CHECK(fmi2EnterContinuousTimeMode(c));
    double x[256], dx[256];
    if (nx > 0) {
        CHECK(fmi2GetContinuousStates(c, x, (size_t)nx));
        for (int k = 0; k < 10; k++) {
            CHECK(fmi2GetDerivatives(c, dx, (size_t)nx));
            for (int i = 0; i < nx; i++) x[i] += 1e-3 * dx[i];
            CHECK(fmi2SetTime(c, (k + 1) * 1e-3));
            CHECK(fmi2SetContinuousStates(c, x, (size_t)nx));
        }
    }
    CHECK(fmi2Terminate(c));
    fmi2FreeInstance(c);
    /* A second free, a call on the freed instance, calls on a pointer that is no instance: refused. */
    fmi2FreeInstance(c);
    if (fmi2Reset(c) != fmi2Error) failures++;
    static double not_an_instance[64];
    if (fmi2Terminate((fmi2Component)not_an_instance) != fmi2Error) failures++;
    fmi2FreeInstance((fmi2Component)not_an_instance);
    return 0;
}

static int run3(void *lib, const char *token, int nvr, unsigned input_vr, int nx) {
    SYM(fmi3InstantiateCoSimulationTYPE *, fmi3InstantiateCoSimulation)
    SYM(fmi3InstantiateModelExchangeTYPE *, fmi3InstantiateModelExchange)
    SYM(fmi3FreeInstanceTYPE *, fmi3FreeInstance) SYM(fmi3EnterInitializationModeTYPE *, fmi3EnterInitializationMode)
    SYM(fmi3ExitInitializationModeTYPE *, fmi3ExitInitializationMode) SYM(fmi3DoStepTYPE *, fmi3DoStep)
    SYM(fmi3GetFloat64TYPE *, fmi3GetFloat64) SYM(fmi3SetFloat64TYPE *, fmi3SetFloat64) SYM(fmi3TerminateTYPE *, fmi3Terminate)
    SYM(fmi3GetFMUStateTYPE *, fmi3GetFMUState) SYM(fmi3SetFMUStateTYPE *, fmi3SetFMUState)
    SYM(fmi3FreeFMUStateTYPE *, fmi3FreeFMUState) SYM(fmi3SerializedFMUStateSizeTYPE *, fmi3SerializedFMUStateSize)
    SYM(fmi3SerializeFMUStateTYPE *, fmi3SerializeFMUState) SYM(fmi3DeserializeFMUStateTYPE *, fmi3DeserializeFMUState)
    SYM(fmi3GetContinuousStateDerivativesTYPE *, fmi3GetContinuousStateDerivatives) SYM(fmi3SetTimeTYPE *, fmi3SetTime)
    SYM(fmi3SetContinuousStatesTYPE *, fmi3SetContinuousStates) SYM(fmi3GetContinuousStatesTYPE *, fmi3GetContinuousStates)
    SYM(fmi3EnterContinuousTimeModeTYPE *, fmi3EnterContinuousTimeMode) SYM(fmi3UpdateDiscreteStatesTYPE *, fmi3UpdateDiscreteStates)
    SYM(fmi3GetDirectionalDerivativeTYPE *, fmi3GetDirectionalDerivative) SYM(fmi3ResetTYPE *, fmi3Reset)
    unsigned vrs[4096]; double vals[4096];
    for (int i = 0; i < nvr && i < 4096; i++) vrs[i] = (unsigned)i;
    fmi3Instance c = fmi3InstantiateCoSimulation("cs", token, "", fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL, logger3, NULL);
    if (!c) return 3;
    if (fmi3GetFloat64(c, vrs, 1, vals, 1) != fmi3Error) failures++;  /* time has no start value */
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0));
    double u = 3.0;
    CHECK(fmi3SetFloat64(c, &input_vr, 1, &u, 1));
    CHECK(fmi3ExitInitializationMode(c));
    fmi3Boolean ev, term, early; fmi3Float64 last;
    for (int k = 0; k < 50; k++) CHECK(fmi3DoStep(c, k * 1e-3, 1e-3, fmi3True, &ev, &term, &early, &last));
    CHECK(fmi3GetFloat64(c, vrs, (size_t)nvr, vals, (size_t)nvr));
    fmi3FMUState s = NULL;
    CHECK(fmi3GetFMUState(c, &s));
    CHECK(fmi3DoStep(c, 0.05, 1e-3, fmi3True, &ev, &term, &early, &last));
    CHECK(fmi3SetFMUState(c, s));
    size_t n = 0;
    CHECK(fmi3SerializedFMUStateSize(c, s, &n));
    unsigned char *blob = malloc(n);
    CHECK(fmi3SerializeFMUState(c, s, blob, n));
    fmi3FMUState s2 = NULL;
    CHECK(fmi3DeserializeFMUState(c, blob, n, &s2));
    CHECK(fmi3SetFMUState(c, s2));
    corrupt_tolerance(blob, token);
    if (fmi3DeserializeFMUState(c, blob, n, &s2) != fmi3Error) failures++;
    free(blob);
    CHECK(fmi3FreeFMUState(c, &s));
    CHECK(fmi3FreeFMUState(c, &s2));
    if (fmi3DoStep(c, 0.0, -1.0, fmi3True, &ev, &term, &early, &last) == fmi3OK) failures++;
    CHECK(fmi3Reset(c));
    CHECK(fmi3Terminate(c) == fmi3OK ? 0 : 0);
    fmi3FreeInstance(c);
    c = fmi3InstantiateModelExchange("me", token, "", fmi3False, fmi3True, NULL, logger3);
    if (!c) return 4;
    CHECK(fmi3EnterInitializationMode(c, fmi3False, 0, 0, fmi3False, 0));
    CHECK(fmi3ExitInitializationMode(c));
    fmi3Boolean a, b, d, e, f; fmi3Float64 next;
    CHECK(fmi3UpdateDiscreteStates(c, &a, &b, &d, &e, &f, &next));
    CHECK(fmi3EnterContinuousTimeMode(c));
    double x[256], dx[256];
    if (nx > 0) {
        CHECK(fmi3GetContinuousStates(c, x, (size_t)nx));
        for (int k = 0; k < 10; k++) {
            CHECK(fmi3GetContinuousStateDerivatives(c, dx, (size_t)nx));
            for (int i = 0; i < nx; i++) x[i] += 1e-3 * dx[i];
            CHECK(fmi3SetTime(c, (k + 1) * 1e-3));
            CHECK(fmi3SetContinuousStates(c, x, (size_t)nx));
        }
        unsigned known = 1, unknown = (unsigned)(1 + nx);
        double seed = 1.0, sens = 0.0;
        CHECK(fmi3GetDirectionalDerivative(c, &unknown, 1, &known, 1, &seed, 1, &sens, 1));
    }
    CHECK(fmi3Terminate(c));
    fmi3FreeInstance(c);
    /* A second free, a call on the freed instance, calls on a pointer that is no instance: refused. */
    fmi3FreeInstance(c);
    if (fmi3Reset(c) != fmi3Error) failures++;
    static double not_an_instance[64];
    if (fmi3Terminate((fmi3Instance)not_an_instance) != fmi3Error) failures++;
    fmi3FreeInstance((fmi3Instance)not_an_instance);
    return 0;
}

int main(int argc, char **argv) {
    if (argc != 7) { fprintf(stderr, "usage: fmi_cycle LIB.so 2|3 TOKEN NVR INPUT_VR NX\n"); return 2; }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
    int nvr = atoi(argv[4]), nx = atoi(argv[6]);
    unsigned input_vr = (unsigned)atoi(argv[5]);
    int rc = argv[2][0] == '2' ? run2(lib, argv[3], nvr, input_vr, nx) : run3(lib, argv[3], nvr, input_vr, nx);
    dlclose(lib);
    if (rc) return rc;
    if (failures) { fprintf(stderr, "%d calls failed\n", failures); return 1; }
    return 0;
}

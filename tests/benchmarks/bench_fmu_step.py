"""Benchmark (not a test): cost of one doStep of the joint plant FMU at 0.5 ms steps, measured in C,
beside the cost of one fmpy set/doStep/get cycle on the same FMU, in one run.

Run: .venv/bin/python tests/benchmarks/bench_fmu_step.py [--smoke]   (--smoke: 1000 steps)
Ratio: the fmpy cycle over the C cycle (the baseline: the same calls from C).
"""
from __future__ import annotations

import subprocess
import tempfile
import time
import zipfile
from pathlib import Path

import fmpy
from fmpy.fmi2 import FMU2Slave

from motiontwin.fmus import build, package
from ratios import ratio, smoke

STEP = 5e-4
STEPS = 20000

C_LOOP = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
static void logger(fmi2ComponentEnvironment e, fmi2String i, fmi2Status s, fmi2String c, fmi2String m, ...) {}
int main(int argc, char **argv) {
    void *lib = dlopen(argv[1], RTLD_NOW);
    fmi2InstantiateTYPE *inst = (fmi2InstantiateTYPE *)dlsym(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE *setup = (fmi2SetupExperimentTYPE *)dlsym(lib, "fmi2SetupExperiment");
    fmi2EnterInitializationModeTYPE *enter = (fmi2EnterInitializationModeTYPE *)dlsym(lib, "fmi2EnterInitializationMode");
    fmi2ExitInitializationModeTYPE *exit_ = (fmi2ExitInitializationModeTYPE *)dlsym(lib, "fmi2ExitInitializationMode");
    fmi2DoStepTYPE *step = (fmi2DoStepTYPE *)dlsym(lib, "fmi2DoStep");
    fmi2SetRealTYPE *set = (fmi2SetRealTYPE *)dlsym(lib, "fmi2SetReal");
    fmi2GetRealTYPE *get = (fmi2GetRealTYPE *)dlsym(lib, "fmi2GetReal");
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = inst("bench", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    unsigned vu = (unsigned)atoi(argv[3]), vq = (unsigned)atoi(argv[4]);
    int n = atoi(argv[5]); double h = atof(argv[6]), q = 0, u;
    setup(c, fmi2False, 0, 0, fmi2False, 0); enter(c); exit_(c);
    struct timespec t0, t1; clock_gettime(CLOCK_MONOTONIC, &t0);
    for (int k = 0; k < n; k++) { u = 3.0 - 100.0 * q; set(c, &vu, 1, &u); step(c, k * h, h, fmi2True); get(c, &vq, 1, &q); }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    printf("%.9f\n", (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec));
    return 0;
}
"""


def main() -> None:
    steps = 1000 if smoke() else STEPS
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        fmu = build.build(["MotionTwin.Plants.LinearMotorJoint"],
                          out_dir=tmp_path, fmi_versions=("2.0",))[0]
        md = fmpy.read_model_description(str(fmu.path))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        unzip = tmp_path / "unzip"
        zipfile.ZipFile(fmu.path).extractall(unzip)
        lib = unzip / "binaries" / package.PLATFORM_DIR["2.0"] / f"{fmu.identifier}.so"
        src = tmp_path / "loop.c"
        src.write_text(C_LOOP)
        exe = tmp_path / "loop"
        headers = Path(fmpy.__file__).parent / "c-code"
        subprocess.run(["gcc", "-O2", f"-I{headers}", str(src), "-o", str(exe), "-ldl"], check=True)
        c_seconds = float(subprocess.run([str(exe), str(lib), md.guid, str(vr["u"]), str(vr["q"]), str(steps),
                                          str(STEP)], capture_output=True, text=True, check=True).stdout)

        slave = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip), modelIdentifier=fmu.identifier)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        q = 0.0
        start = time.perf_counter()
        for k in range(steps):
            slave.setReal([vr["u"]], [3.0 - 100.0 * q])
            slave.doStep(currentCommunicationPoint=k * STEP, communicationStepSize=STEP)
            q = slave.getReal([vr["q"]])[0]
        py_seconds = time.perf_counter() - start
        slave.terminate()
        slave.freeInstance()

    c_us = c_seconds / steps * 1e6
    py_us = py_seconds / steps * 1e6
    print(f"joint plant FMU, {steps} steps of {STEP * 1e3:g} ms under proportional feedback")
    print(f"  C set/doStep/get cycle:     {c_us:8.2f} us/step  (real-time factor {STEP * 1e6 / c_us:8.0f}x)")
    print(f"  fmpy set/doStep/get cycle:  {py_us:8.2f} us/step  (real-time factor {STEP * 1e6 / py_us:8.0f}x)")
    print(f"  fmpy overhead over C:       {py_us / c_us:8.2f}x")
    ratio("fmu_step.fmpy_over_c", py_us / c_us, "fmpy set/doStep/get cycle / the same cycle in C, per step")
    ratio("fmu_step.realtime_factor_c", STEP * 1e6 / c_us, "step size / wall time of one C cycle")


if __name__ == "__main__":
    main()

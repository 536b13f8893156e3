"""Benchmark (not a test): real-time factor of the 4-DOF closed loop at 2 kHz through the harness, beside a
raw fmpy set/doStep/get loop on the same FMUs, and where the time goes; the harness both with its
compiled inner loop (harness/native_loop.c, the default) and with its Python loop (``native=False``).

Loop: four ``RobustJointController`` channels (FMI 2.0, Ts = 5e-4 s, Table 2 designs rescaled as in
harness.comparison) around ``CheungManipulator`` (FMI 2.0, 5e-4 s steps), the paper's substrate move
repeated back and forth. Real-time factor = simulated time / wall time (target >= 50x on this 2-core machine).

Run: .venv/bin/python tests/benchmarks/bench_manipulator.py [SIMULATED_SECONDS] [--smoke]
(--smoke: 0.05 s simulated, one repetition.) Ratios: the raw fmpy set/doStep/get loop (the baseline), the
harness's Python loop and a direct ctypes loop, each over the harness's compiled loop.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import fmpy
import numpy as np
from fmpy.fmi2 import FMU2Slave

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from motiontwin import comparison  # noqa: E402
from motiontwin.harness.excitation import end_effector_point_to_point  # noqa: E402
from motiontwin.harness.kinematics import CHEUNG_END_POSE, CHEUNG_START_POSE  # noqa: E402
from motiontwin.harness.fmu_instance import extracted_fmu  # noqa: E402
from motiontwin.harness.master import Master  # noqa: E402
from ratios import ratio, smoke  # noqa: E402

TS = comparison.TS
TARGET = 50.0


def reference(n: int) -> np.ndarray:
    """(n + 1, 4, 4) array: per sample, [position, velocity, acceleration, jerk] x joint; moves every 0.25 s."""
    t = np.arange(n + 1) * TS
    period = 0.25
    phase = t % (2 * period)
    there = end_effector_point_to_point(phase, CHEUNG_START_POSE, CHEUNG_END_POSE, comparison.MOVE_TIME, 0.01)
    back = end_effector_point_to_point(phase - period, CHEUNG_END_POSE, CHEUNG_START_POSE, comparison.MOVE_TIME, 0.01)
    first = (phase < period)[:, None]
    fields = ("position", "velocity", "acceleration", "jerk")
    return np.stack([np.where(first, getattr(there, f), getattr(back, f)) for f in fields], axis=1)


def raw_loop(fmus: dict[str, Path], designs: list[dict[str, float]], holding: np.ndarray,
             ref: np.ndarray) -> tuple[float, np.ndarray]:
    """The same loop with fmpy's FMU2Slave setReal/doStep/getReal only."""
    def slave(path: Path, name: str) -> tuple[FMU2Slave, dict[str, int]]:
        md = fmpy.read_model_description(str(path))
        s = FMU2Slave(guid=md.guid, unzipDirectory=extracted_fmu(path),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        return s, {v.name: v.valueReference for v in md.modelVariables}

    plant, pv = slave(fmus["plant"], "plant")
    ctrls = [slave(fmus["robust"], f"c{p}") for p in comparison.PORTS]
    for (c, cv), design in zip(ctrls, designs):
        names = [k for k in design if k in cv and k != "Ts"]
        c.setReal([cv[k] for k in names], [design[k] for k in names])
    for s in [plant] + [c for c, _ in ctrls]:
        s.enterInitializationMode()
        s.exitInitializationMode()
    q_vr = [pv[f"q{p}"] for p in comparison.PORTS]
    u_vr = [pv[f"u{p}"] for p in comparison.PORTS]
    c_in = [[cv[k] for k in ("r", "q", "r_dot", "r_ddot", "r_dddot")] for _, cv in ctrls]
    c_out = [[cv["u"]] for _, cv in ctrls]
    n = ref.shape[0] - 1
    out = np.empty((n + 1, 4))
    q = plant.getReal(q_vr)
    clock = time.perf_counter
    t0 = clock()
    for k in range(n):
        t = k * TS
        out[k] = q
        u = [0.0] * 4
        for j, (c, _) in enumerate(ctrls):
            p, v, a, jerk = ref[k, :, j]
            c.setReal(c_in[j], [p, q[j], v, a, jerk])
            c.doStep(t, TS)
            u[j] = c.getReal(c_out[j])[0] + holding[j]
        plant.setReal(u_vr, u)
        plant.doStep(t, TS)
        q = plant.getReal(q_vr)
    elapsed = clock() - t0
    out[n] = q
    for s in [plant] + [c for c, _ in ctrls]:
        s.terminate()
        s.freeInstance()
    return elapsed, out


def direct_loop(fmus: dict[str, Path], designs: list[dict[str, float]], holding: np.ndarray,
                ref: np.ndarray) -> tuple[float, np.ndarray]:
    """Lower bound of a Python loop: the FMI C functions called through ctypes directly (fmpy's loaded
    function table, bypassing its per-call Python wrappers), status checked inline, buffers preallocated."""
    import ctypes

    def slave(path: Path, name: str) -> tuple[FMU2Slave, dict[str, int]]:
        md = fmpy.read_model_description(str(path))
        s = FMU2Slave(guid=md.guid, unzipDirectory=extracted_fmu(path),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        return s, {v.name: v.valueReference for v in md.modelVariables}

    plant, pv = slave(fmus["plant"], "plant")
    ctrls = [slave(fmus["robust"], f"c{p}") for p in comparison.PORTS]
    for (c, cv), design in zip(ctrls, designs):
        names = [k for k in design if k in cv and k != "Ts"]
        c.setReal([cv[k] for k in names], [design[k] for k in names])
    for s in [plant] + [c for c, _ in ctrls]:
        s.enterInitializationMode()
        s.exitInitializationMode()
    uint, dbl = ctypes.c_uint, ctypes.c_double
    q_vr = (uint * 4)(*[pv[f"q{p}"] for p in comparison.PORTS])
    u_vr = (uint * 4)(*[pv[f"u{p}"] for p in comparison.PORTS])
    q_buf, u_buf = (dbl * 4)(), (dbl * 4)()
    c_in = [(uint * 5)(*[cv[k] for k in ("r", "q", "r_dot", "r_ddot", "r_dddot")]) for _, cv in ctrls]
    c_out = [(uint * 1)(cv["u"]) for _, cv in ctrls]
    in_buf, out_buf = (dbl * 5)(), (dbl * 1)()
    def functions(s: FMU2Slave) -> tuple:
        """fmi2GetReal, fmi2SetReal, fmi2DoStep of the FMU binary ``s`` was instantiated from (an instance is
        only valid with its own binary's functions)."""
        return s._functions["fmi2GetReal"], s._functions["fmi2SetReal"], s._functions["fmi2DoStep"]

    get, put, step = functions(plant)
    c_get, c_put, c_step = zip(*[functions(c) for c, _ in ctrls])
    comps = [c.component for c, _ in ctrls]
    pc = plant.component
    n = ref.shape[0] - 1
    out = np.empty((n + 1, 4))
    get(pc, q_vr, 4, q_buf)
    t0 = time.perf_counter()
    for k in range(n):
        t = k * TS
        out[k] = q_buf
        for j in range(4):
            p, v, a, jerk = ref[k, :, j]
            in_buf[:] = (p, q_buf[j], v, a, jerk)
            status = (c_put[j](comps[j], c_in[j], 5, in_buf) | c_step[j](comps[j], t, TS, 1)
                      | c_get[j](comps[j], c_out[j], 1, out_buf))
            u_buf[j] = out_buf[0] + holding[j]
            if status > 1:
                raise RuntimeError(f"controller {j} failed at t = {t}")
        if put(pc, u_vr, 4, u_buf) | step(pc, t, TS, 1) | get(pc, q_vr, 4, q_buf) > 1:
            raise RuntimeError(f"plant failed at t = {t}")
    elapsed = time.perf_counter() - t0
    out[n] = q_buf
    for s in [plant] + [c for c, _ in ctrls]:
        s.terminate()
        s.freeInstance()
    return elapsed, out


def main() -> None:
    small = smoke()
    simulated = float(sys.argv[1]) if len(sys.argv) > 1 else (0.05 if small else 4.0)
    repeats = 1 if small else 3
    n = round(simulated / TS)
    with tempfile.TemporaryDirectory() as tmp:
        fmus = comparison.build_fmus(tmp)
        ref = reference(n)
        start = ref[0, 0]
        with comparison.PlantDynamics(fmus["plant"]) as dyn:
            masses = np.diag(dyn.mass_matrix(start)).copy()
            holding = dyn.inverse(start, np.zeros(4), np.zeros(4))
        designs = comparison.table2_designs(masses, 5.0)
        system = comparison.closed_loop_system(fmus, "robust")
        inputs = {}
        for j, p in enumerate(comparison.PORTS):
            for i, prefix in enumerate(("r", "rd", "rdd", "rddd")):
                inputs[f"{prefix}{p}"] = ref[:, i, j]
            inputs[f"ff{p}"] = np.full(n + 1, holding[j])
        overrides = {f"c{p}.{k}": v for p, d in zip(comparison.PORTS, designs) for k, v in d.items()
                     if k not in ("Ts", "table2_scale")}
        warm_time = min(0.1, n * TS)
        warm = round(warm_time / TS) + 1
        harness_s: dict[bool, list[float]] = {True: [], False: []}
        logs = {}
        raw_s, direct_s = [], []
        with Master(system, progress=False) as compiled, Master(system, progress=False, native=False) as python:
            assert compiled.uses_native, "no C compiler: the compiled loop is not available"
            for master in (compiled, python):
                master.run(inputs={k: v[:warm] for k, v in inputs.items()}, parameters=overrides, stop_time=warm_time)
            for _ in range(repeats):
                for master in (compiled, python):
                    t0 = time.perf_counter()
                    logs[master.native] = master.run(inputs=inputs, parameters=overrides, stop_time=n * TS)["log"]
                    harness_s[master.native].append(time.perf_counter() - t0)
                elapsed, raw = raw_loop(fmus, designs, holding, ref)
                raw_s.append(elapsed)
                elapsed, direct = direct_loop(fmus, designs, holding, ref)
                direct_s.append(elapsed)
            cpu = {}
            for master in (compiled, python):
                t0 = time.process_time()
                master.run(inputs=inputs, parameters=overrides, stop_time=n * TS)
                cpu[master.native] = time.process_time() - t0
        with Master(system, progress=False, profile=True) as profiled:
            profiled.run(inputs=inputs, parameters=overrides, stop_time=n * TS)
            inside = profiled.step_seconds
        c, py, r, d = min(harness_s[True]), min(harness_s[False]), min(raw_s), min(direct_s)
        q = {native: np.column_stack([log[f"plant.q{p}"] for p in comparison.PORTS]) for native, log in logs.items()}
        identical = all(logs[True][f].tobytes() == logs[False][f].tobytes() for f in logs[True].dtype.names)
        print(f"4-DOF closed loop: 4 x RobustJointController + CheungManipulator (FMI 2.0), 2 kHz, "
              f"{simulated:g} s simulated ({n} steps); load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")

        def line(label: str, wall: float, extra: str = "") -> None:
            print(f"  {label:<22}: {wall:7.3f} s wall  real-time factor {simulated / wall:6.1f}x  "
                  f"{wall / n * 1e6:6.1f} us/step{extra}")

        line("harness, compiled loop", c, f"  ({'meets' if simulated / c >= TARGET else 'MISSES'} the "
                                          f">= {TARGET:g}x target)")
        line("harness, Python loop", py)
        line("raw fmpy loop", r)
        line("direct ctypes loop", d, f"  (max |q - q_raw| = {np.max(np.abs(direct - raw)):.1e} m)")
        print(f"  ratios: Python loop / compiled = {py / c:.2f}, raw fmpy / compiled = {r / c:.2f}, "
              f"direct ctypes / compiled = {d / c:.2f}")
        ratio("manipulator.speedup_over_raw_fmpy", r / c, "raw fmpy set/doStep/get loop / harness compiled loop, "
              "wall")
        ratio("manipulator.speedup_over_python_loop", py / c, "harness Python loop / harness compiled loop, wall")
        ratio("manipulator.speedup_over_direct_ctypes", d / c, "direct ctypes loop / harness compiled loop, wall")
        ratio("manipulator.realtime_factor", simulated / c, f"simulated time / wall time (target >= {TARGET:g})")
        print(f"  compiled and Python loop logs bit-identical: {identical};  "
              f"max |q_harness - q_raw| = {float(np.max(np.abs(q[True] - raw))):.2e} m")
        print(f"  CPU time (less sensitive to the load): compiled loop {cpu[True]:.3f} s "
              f"= {simulated / cpu[True]:.1f}x real time, Python loop {cpu[False]:.3f} s "
              f"= {simulated / cpu[False]:.1f}x")
        plant_s = inside["plant"]
        ctrl_s = sum(v for k, v in inside.items() if k != "plant")
        total = plant_s + ctrl_s
        print(f"  time inside doStep (compiled loop, clock_gettime around each call): plant {plant_s / n * 1e6:.1f} "
              f"us/step, 4 controllers {ctrl_s / n * 1e6:.1f} us/step = {total / n * 1e6:.1f} us/step; "
              f"the FMUs alone allow at most {simulated / total:.1f}x real time under this load")

if __name__ == "__main__":
    main()

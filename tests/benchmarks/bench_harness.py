"""Benchmark (not a test): co-simulation harness overhead over a raw fmpy set/doStep/get loop on the
same FMUs, measured side by side in one run, and runs per second of a 100-seed sweep that reuses instances.

Two closed loops, plant force = controller output + u_ext(t), u_ext seeded noise:
1. third-party: a sampled P controller (OpenModelica ``add.fmu``, 1 ms) around a mass-spring-damper
   (OpenModelica ``Mass_Damper.fmu``, 0.1 ms);
2. the project's FMUs (built here with fmus.build into a temporary folder): ``SampledPI`` (FMI 3.0,
   Ts = 1 ms) around ``LinearMotorJoint`` (FMI 2.0, 0.5 ms, i.e. 2 kHz).

Run: .venv/bin/python tests/benchmarks/bench_harness.py [FOLDER_WITH_GEMSEO_FMUS] [--smoke]
(default: $MOTIONTWIN_TEST_FMUS, else the gemseo-fmu wheel's FMUs fetched once into
~/.cache/motiontwin/gemseo_fmus by tests.fmi_util.gemseo_fmu_folder; --smoke: 0.2 s and 0.5 s simulated,
one repetition, 4 sweep seeds). Ratios: harness over the raw fmpy loop (the baseline) for both loops.
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

from fmpy.fmi3 import FMU3Slave  # noqa: E402

from motiontwin.harness.executor import run_sweep  # noqa: E402
from motiontwin.harness.fmu_instance import extracted_fmu  # noqa: E402
from motiontwin.harness.master import Master  # noqa: E402
from ratios import ratio, smoke  # noqa: E402
from tests.fmi_util import gemseo_fmu_folder  # noqa: E402

BASE = 1e-4
STOP = 2.0
SUB = 10  # plant steps per controller step
REPEATS = 5
SEEDS = 100
PROJECT_STOP = 10.0
KP = 2000.0

SYSTEM = """
base_step = {base}
stop_time = {stop}
[fmus.ctrl]
path = "{fmus}/add.fmu"
step = {ts}
sampled = true
[fmus.ctrl.parameters]
"add.k1" = {kp}
"add.k2" = -{kp}
[fmus.plant]
path = "{fmus}/Mass_Damper.fmu"
[inputs.r]
[inputs.u_ext]
[[connections]]
from = "input.r"
to = "ctrl.u1"
[[connections]]
from = "plant.y"
to = "ctrl.u2"
[[connections]]
from = ["ctrl.y", "input.u_ext"]
to = "plant.f"
[[log]]
signals = ["plant.y", "ctrl.y", "plant.f"]
"""


def raw_loop(fmus: Path, r: float, u_ext: np.ndarray) -> np.ndarray:
    """The same closed loop with fmpy's FMU2Slave set/doStep/get and nothing else."""
    slaves = []
    for name in ("add", "Mass_Damper"):
        md = fmpy.read_model_description(str(fmus / f"{name}.fmu"))
        s = FMU2Slave(guid=md.guid, unzipDirectory=extracted_fmu(fmus / f"{name}.fmu"),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        slaves.append((s, {v.name: v.valueReference for v in md.modelVariables}))
    (ctrl, cv), (plant, pv) = slaves
    ctrl.setReal([cv["add.k1"], cv["add.k2"]], [KP, -KP])
    for s in (ctrl, plant):
        s.enterInitializationMode()
        s.exitInitializationMode()
    n = round(STOP / BASE)
    out = np.empty((n + 1, 3))
    y = plant.getReal([pv["y"]])[0]
    u = 0.0
    t0 = time.perf_counter()
    for k in range(n):
        if k % SUB == 0:
            ctrl.setReal([cv["u1"], cv["u2"]], [r, y])
            ctrl.doStep(k * BASE, SUB * BASE)
            u = ctrl.getReal([cv["y"]])[0]
        f = u + u_ext[k]
        plant.setReal([pv["f"]], [f])
        out[k] = (y, u, f)
        plant.doStep(k * BASE, BASE)
        y = plant.getReal([pv["y"]])[0]
    elapsed = time.perf_counter() - t0
    out[n] = (y, u, u + u_ext[n])
    for s, _ in slaves:
        s.terminate()
        s.freeInstance()
    return elapsed, out


PROJECT_SYSTEM = """
base_step = 5e-4
stop_time = {stop}
[fmus.pi]
path = "{pi}"
[fmus.pi.parameters]
Kp = 2000.0
Ki = 20000.0
Kd = 40.0
[fmus.plant]
path = "{plant}"
[inputs.r]
[inputs.u_ext]
[[connections]]
from = ["input.r", "plant.q"]
gains = [1.0, -1.0]
to = "pi.e"
[[connections]]
from = ["pi.y", "input.u_ext"]
to = "plant.u"
[[log]]
signals = ["plant.q", "pi.y", "plant.u"]
"""


def raw_project_loop(pi_path: Path, plant_path: Path, r: float, u_ext: np.ndarray, n: int) -> tuple[float, np.ndarray]:
    """The project loop with fmpy's FMU3Slave/FMU2Slave set/doStep/get and nothing else."""
    md_pi = fmpy.read_model_description(str(pi_path))
    md_pl = fmpy.read_model_description(str(plant_path))
    pi = FMU3Slave(guid=md_pi.guid, unzipDirectory=extracted_fmu(pi_path),
                   modelIdentifier=md_pi.coSimulation.modelIdentifier, instanceName="pi")
    plant = FMU2Slave(guid=md_pl.guid, unzipDirectory=extracted_fmu(plant_path),
                      modelIdentifier=md_pl.coSimulation.modelIdentifier, instanceName="plant")
    pv = {v.name: v.valueReference for v in md_pi.modelVariables}
    qv = {v.name: v.valueReference for v in md_pl.modelVariables}
    pi.instantiate()
    plant.instantiate()
    plant.setupExperiment(startTime=0.0)
    pi.enterInitializationMode()
    pi.setFloat64([pv["Kp"], pv["Ki"], pv["Kd"]], [2000.0, 20000.0, 40.0])
    plant.enterInitializationMode()
    pi.exitInitializationMode()
    plant.exitInitializationMode()
    out = np.empty((n + 1, 3))
    q = plant.getReal([qv["q"]])[0]
    h = 5e-4
    t0 = time.perf_counter()
    for k in range(n):
        if k % 2 == 0:
            pi.setFloat64([pv["e"]], [r - q])
            pi.doStep(k * h, 2 * h)
            u = pi.getFloat64([pv["y"]])[0]
        f = u + u_ext[k]
        plant.setReal([qv["u"]], [f])
        out[k] = (q, u, f)
        plant.doStep(k * h, h)
        q = plant.getReal([qv["q"]])[0]
    elapsed = time.perf_counter() - t0
    out[n] = (q, u, u + u_ext[n])
    return elapsed, out


def project_section(tmp: Path) -> None:
    from motiontwin.fmus import build

    pi = build.build_fmu(build.load_model("SampledPI", ROOT / "tests" / "models" / "SampledPI.mo"), tmp, "3.0").path
    plant = build.build_fmu(build.load_model("MotionTwin.Plants.LinearMotorJoint", build.MODELICA_DIR), tmp, "2.0").path
    stop = PROJECT_STOP
    n = round(stop / 5e-4)
    path = tmp / "project.toml"
    path.write_text(PROJECT_SYSTEM.format(stop=stop, pi=pi, plant=plant))
    u_ext = np.random.default_rng(1).normal(0.0, 1.0, n + 1)
    with Master(path, progress=False) as master:
        master.run(inputs={"r": 1e-3, "u_ext": u_ext})
        raw_times, harness_times = [], []
        for _ in range(REPEATS):
            raw_s, raw = raw_project_loop(pi, plant, 1e-3, u_ext, n)
            t0 = time.perf_counter()
            log = master.run(inputs={"r": 1e-3, "u_ext": u_ext})["log"]
            harness_times.append(time.perf_counter() - t0)
            raw_times.append(raw_s)
    same = np.array_equal(raw[:, 0], log["plant.q"]) and np.array_equal(raw[:-1, 2], log["plant.u"][:-1])
    raw_s, harness_s = min(raw_times), min(harness_times)
    print(f"project FMUs: SampledPI (FMI 3.0, 1 ms) + LinearMotorJoint (FMI 2.0, 2 kHz), {stop} s simulated")
    print(f"  raw fmpy loop : {raw_s * 1e3:8.1f} ms  ({raw_s / n * 1e6:.2f} us per base step)")
    print(f"  harness run   : {harness_s * 1e3:8.1f} ms  ({harness_s / n * 1e6:.2f} us per base step)")
    print(f"  overhead ratio harness/raw = {harness_s / raw_s:.2f} (target <= 1.5); identical results: {same}")
    print(f"  real-time factor (harness) = {stop / harness_s:.0f}x")
    ratio("harness.project_loop_over_raw_fmpy", harness_s / raw_s, "harness run / raw fmpy set/doStep/get loop on "
          "the project FMUs, wall (target <= 1.5)")


def main() -> None:
    global STOP, REPEATS, SEEDS, PROJECT_STOP
    if smoke():
        STOP, REPEATS, SEEDS, PROJECT_STOP = 0.2, 1, 4, 0.5
    given = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("MOTIONTWIN_TEST_FMUS")
    fmus = Path(given) if given else gemseo_fmu_folder(Path.home() / ".cache" / "motiontwin" / "gemseo_fmus")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "loop.toml"
        path.write_text(SYSTEM.format(base=BASE, stop=STOP, ts=SUB * BASE, kp=KP, fmus=fmus))
        n = round(STOP / BASE)
        u_ext = np.random.default_rng(0).normal(0.0, 10.0, n + 1)
        with Master(path, progress=False) as master:
            master.run(inputs={"r": -0.45, "u_ext": u_ext})  # warm-up
            raw_times, harness_times = [], []
            for _ in range(REPEATS):
                raw_s, raw = raw_loop(fmus, -0.45, u_ext)
                t0 = time.perf_counter()
                log = master.run(inputs={"r": -0.45, "u_ext": u_ext})["log"]
                harness_times.append(time.perf_counter() - t0)
                raw_times.append(raw_s)
            same = np.array_equal(raw[:, 0], log["plant.y"]) and np.array_equal(raw[:-1, 2], log["plant.f"][:-1])
            raw_s, harness_s = min(raw_times), min(harness_times)
            print(f"closed loop {n} plant steps + {n // SUB} controller steps, {STOP} s simulated")
            print(f"  raw fmpy loop : {raw_s * 1e3:8.1f} ms  ({raw_s / n * 1e6:.2f} us per base step)")
            print(f"  harness run   : {harness_s * 1e3:8.1f} ms  ({harness_s / n * 1e6:.2f} us per base step, "
                  f"incl. reset, init, logging 3 signals)")
            print(f"  overhead ratio harness/raw = {harness_s / raw_s:.2f} (target <= 1.5); identical results: {same}")
            print(f"  real-time factor (harness) = {STOP / harness_s:.0f}x")
            ratio("harness.gemseo_loop_over_raw_fmpy", harness_s / raw_s, "harness run / raw fmpy "
                  "set/doStep/get loop on the OpenModelica FMUs, wall (target <= 1.5)")

        short = path.with_name("short.toml")
        short.write_text(SYSTEM.format(base=BASE, stop=0.1, ts=SUB * BASE, kp=KP, fmus=fmus))
        cases = [{"inputs": {"r": -0.45, "u_ext": np.random.default_rng(seed).normal(0, 10, 1001)}}
                 for seed in range(SEEDS)]
        run_sweep(short, cases[:2])
        t0 = time.perf_counter()
        results = run_sweep(short, cases)
        elapsed = time.perf_counter() - t0
        print(f"sweep of {len(results)} seeds (0.1 s each, in-process, instances reused): "
              f"{len(results) / elapsed:.0f} runs/s")
        project_section(Path(tmp))


if __name__ == "__main__":
    main()

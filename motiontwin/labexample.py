"""A recording that looks like lab data, made by the project's harness on library FMUs (README "Worked example:
lab data").

The truth is a heavy prismatic axis, ``MotionTwin.Plants.PrismaticAxis`` with m = 95 kg, viscous d = 60 N.s/m,
Coulomb Fc = 20.6 N (tanh over 1 mm/s) and a constant force F0 = -3.2 N, in a sampled PID loop at 1 kHz
(``MotionTwin.Benchmarks.LoopController``) with an incremental encoder (``MotionTwin.Benchmarks.Encoder``, 0.1 um
counts, 50 nm noise), co-simulated by :class:`harness.master.Master` (ident.benchmarks.single_axis's loop). The
reference is a periodic Fourier trajectory (f0 = 0.25 Hz, 10 harmonics, within 232-248 mm, up to 0.08 m/s and
0.9 m/s2). What makes it lab-like:

* the loop is already moving at t = 0: the run starts at rest, moves to the trajectory, runs 1.3 periods, and the
  file starts there (mid-period, at speed);
* the time stamps jitter (uniform +-20 ns on a 1 ms clock) and the record has a few seconds beyond whole periods;
* the lab's names and units: ``t`` [s], ``pos_enc`` [mm], ``ref`` [mm] and ``cmd`` [V], the force command
  before an amplifier of gain 40 N/V, with 1 mV of noise;
* two recordings (``axis_a.mat`` for identification, ``axis_b.mat`` with other Fourier coefficients for
  validation), the loop's controller as ``controller.json`` (discrete state space, for identify oe and validate),
  and the truth in ``truth.json``.

    python -m motiontwin.labexample --out build/lab

Units: SI inside; the .mat files hold the lab's units stated above.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import scipy.io

from motiontwin.fmus.files import atomic_path, atomic_write_texts
from motiontwin.ident.controller import controller_document
from motiontwin.ident.benchmarks import single_axis as benchmark
from motiontwin.ident.controller import Controller
from motiontwin.harness.excitation import fourier_trajectory

PLANT = "MotionTwin.Plants.PrismaticAxis"
TRUTH = {"m": 95.0, "d": 60.0, "Fc": 20.6, "F0": -3.2, "v_eps": 1e-3}
TS = 1e-3
F0 = 0.25                     # fundamental [Hz]: a period of 4 s
HARMONICS = 10                # up to 2.5 Hz
STROKE = 0.008                # largest excursion from CENTRE [m]
GAIN = 40.0                   # amplifier gain [N/V]
CENTRE = 0.24                 # centre of the stroke [m]
RESOLUTION, NOISE = 1e-7, 5e-8          # encoder count and noise [m]
JITTER = 2e-8                 # clock jitter half-width [s]
VOLT_NOISE = 1e-3             # command noise [V]
RECORDINGS = {"axis_a": 1, "axis_b": 2}   # recording -> seed of its Fourier phases (and noise)


def coefficients(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fourier velocity coefficients a_k, b_k [m/s] (harness.excitation): amplitudes k^0.7 with seeded phases,
    scaled to a largest excursion of STROKE, so the higher harmonics excite the inertia."""
    phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, HARMONICS)
    amplitude = np.arange(1, HARMONICS + 1) ** 0.7
    a, b = amplitude * np.cos(phases), amplitude * np.sin(phases)
    q = fourier_trajectory(np.arange(int(round(1 / (F0 * TS)))) * TS, F0, a, b).position
    scale = STROKE / float(np.max(np.abs(q)))
    return scale * a, scale * b


def loop_controller() -> Controller:
    """The lab's PID (filtered derivative, Tustin) tuned for the 95 kg axis at 25 Hz."""
    return benchmark.pid_controller(ts=TS, mass=TRUTH["m"], bandwidth=25.0)


def lab_recording(seed: int, periods: int = 6, extra: float = 3.3,
                  fmu_dir: Path | None = None) -> dict[str, np.ndarray]:
    """Co-simulate one recording; returns the lab file's variables (t, pos_enc [mm], ref [mm], cmd [V]) and
    the true position ``q_true`` [m]."""
    a, b = coefficients(seed)
    rng = np.random.default_rng(seed)
    lead = 1.3 / F0                                   # the loop runs this long before the file starts
    n_lead, n_file = int(round(lead / TS)), int(round((periods / F0 + extra) / TS))
    t_traj = np.arange(n_lead + n_file) * TS
    r = fourier_trajectory(t_traj, F0, a, b, CENTRE).position
    rr, u_ext, pre = benchmark.with_preroll(r, np.zeros_like(r))
    noise = NOISE * rng.standard_normal(rr.size)
    plant = benchmark.TruthPlant(PLANT, dict(TRUTH))
    out = benchmark.cosimulate(plant, rr, u_ext, noise, RESOLUTION, ctrl=loop_controller(), fmu_dir=fmu_dir)
    start = pre + n_lead
    keep = slice(start, start + n_file)
    t = np.arange(n_file) * TS + rng.uniform(-JITTER, JITTER, n_file)
    t[0] = 0.0
    return {"t": t, "pos_enc": 1e3 * out["q"][keep], "ref": 1e3 * out["r"][keep],
            "cmd": out["u"][keep] / GAIN + VOLT_NOISE * rng.standard_normal(n_file), "q_true": out["q_true"][keep]}


def _write_mat(path: Path, variables: dict[str, np.ndarray]) -> None:
    """A .mat file as a lab PC would save it (column vectors), written atomically."""
    with atomic_path(path) as tmp:
        scipy.io.savemat(tmp, variables, oned_as="column")


def generate(out: Path, periods: int = 6, extra: float = 3.3, fmu_dir: Path | None = None) -> list[Path]:
    """Write axis_a.mat, axis_b.mat, controller.json and truth.json into ``out``; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, seed in RECORDINGS.items():
        data = lab_recording(seed, periods, extra, fmu_dir)
        path = out / f"{name}.mat"
        _write_mat(path, {k: v for k, v in data.items() if k != "q_true"})
        written.append(path)
    ctrl = loop_controller()
    truth = {"class": PLANT, "parameters": TRUTH, "gain_N_per_V": GAIN, "sample_time": TS, "f0": F0,
             "coefficients": {name: [c.tolist() for c in coefficients(seed)] for name, seed in RECORDINGS.items()},
             "periods": periods, "extra_seconds": extra, "encoder_resolution": RESOLUTION, "encoder_noise": NOISE,
             "clock_jitter": JITTER, "note": "asymmetric Coulomb levels of the same axis: "
                                             f"{TRUTH['Fc'] + TRUTH['F0']:.1f} N (v > 0), "
                                             f"{TRUTH['Fc'] - TRUTH['F0']:.1f} N (v < 0)"}
    texts = {out / "controller.json": json.dumps(controller_document(ctrl), indent=2) + "\n",
             out / "truth.json": json.dumps(truth, indent=2) + "\n"}
    atomic_write_texts(texts)
    return written + list(texts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m motiontwin.labexample", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the lab files")
    parser.add_argument("--periods", type=int, default=6, help="whole periods of 4 s (default 6)")
    parser.add_argument("--extra", type=float, default=3.3, help="seconds beyond the whole periods (default 3.3)")
    args = parser.parse_args(argv)
    if args.periods < 2 or not math.isfinite(args.extra) or args.extra < 0:
        parser.error("--periods must be >= 2 and --extra >= 0")
    for path in generate(args.out, args.periods, args.extra):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())

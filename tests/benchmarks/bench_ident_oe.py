"""Benchmark (issue 5): output-error refit of a joint model on 60 s at 2 kHz, CasADi (ident.outputerror:
single shooting, RK4, forward AD sensitivities) against the approach a user would write: scipy
least_squares whose residual runs an fmpy simulation of the FMU, finite-difference Jacobian. Same data,
same start, same bounds, both in one run; prints wall times, their ratio (target >= 10) and both optima.

Run: .venv/bin/python tests/benchmarks/bench_ident_oe.py [--seconds 60] [--model linear|cheung] [--casadi-chain]
[--smoke] (--smoke: 1 s of data). Ratios: the scipy + fmpy output-error refit (the baseline) over CasADi's.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import fmpy
import numpy as np
from scipy.optimize import least_squares

from motiontwin.fmus import build
from motiontwin.harness.recording import make_recording
from motiontwin.ident import outputerror as oe
from ratios import ratio

TS = 5e-4
MODELS = {
    "linear": ("MotionTwin.Plants.LinearMotorJoint", "x", {"m": 2.6, "d": 14.0}),
    "cheung": ("MotionTwin.Plants.CheungJoint", "x1", {"K": 1.1, "alpha": 8.0, "omega": 2600.0, "zeta": 0.04}),
}


def periodic_multisine(n: int, f_max: float, rms: float, seed: int) -> np.ndarray:
    """1 s periodic random-phase multisine, 1..f_max Hz, zero mean, repeated over n samples."""
    per = int(round(1 / TS))
    spec = np.zeros(per // 2 + 1, complex)
    spec[1:int(f_max) + 1] = np.exp(1j * np.random.default_rng(seed).uniform(0, 2 * np.pi, int(f_max)))
    one = np.fft.irfft(spec, per)
    return np.resize(one * rms / np.std(one), n)


def fmpy_q(fmu: str, u: np.ndarray, values: dict[str, float]) -> np.ndarray:
    t = np.arange(u.size) * TS
    sig = np.zeros(u.size, dtype=[("time", float), ("u", float)])
    sig["time"], sig["u"] = t, u
    return fmpy.simulate_fmu(fmu, stop_time=t[-1], step_size=TS, output_interval=TS, input=sig, output=["q"],
                             start_values=values)["q"]


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="bench-oe-") as scratch:
        measure(Path(scratch))


def measure(scratch: Path) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--model", choices=sorted(MODELS), default="linear")
    parser.add_argument("--casadi-chain", action="store_true",
                        help="chain the samples with CasADi mapaccum instead of compiled C (the fallback)")
    parser.add_argument("--noise", type=float, default=2e-6, help="encoder noise std [m]")
    parser.add_argument("--smoke", action="store_true", help="1 s of data: only proves the script runs")
    args = parser.parse_args()
    if args.smoke:
        args.seconds = 1.0
    class_name, state, truth = MODELS[args.model]
    model = build.load_model(class_name)
    fmu = str(build.build_fmu(model, scratch, "2.0").path)
    n = int(round(args.seconds / TS))
    u = periodic_multisine(n, 40 if args.model == "linear" else 500, 5.0, seed=0)
    q = fmpy_q(fmu, u, truth) + args.noise * np.random.default_rng(1).standard_normal(n)
    rec = make_recording(np.arange(n) * TS, {"u": u, "q": q})
    free = list(truth)
    start = {v.name: float(v.start) for v in model.parameters if v.name in truth}
    bounds = oe.default_bounds(model, free)
    lo = np.array([bounds[k][0] for k in free]) / np.array([start[k] for k in free])
    hi = np.array([bounds[k][1] for k in free]) / np.array([start[k] for k in free])

    def refit() -> tuple[float, float, oe.Loop, oe.Fit]:
        t0 = time.perf_counter()
        loop = oe.build_loop(model, None, state, free, start, n, ts=TS, substeps=4, native=not args.casadi_chain)
        t_build = time.perf_counter() - t0
        fit = oe.fit(loop, rec, oe.Weights(args.noise), initial={state: 0.0}, max_nfev=50)
        return time.perf_counter() - t0, t_build, loop, fit

    os.environ["XDG_CACHE_HOME"] = str(scratch / "cache")  # first refit compiles
    t_casadi, t_build, loop, fit = refit()
    t_cached, t_build_cached, _, fit_cached = refit()
    casadi_opt = np.array([fit.values[k] for k in free])
    std = oe.statistics(loop, fit).std

    scale = np.array([start[k] for k in free])
    count = [0]

    def residual(x: np.ndarray) -> np.ndarray:   # what a user writes: one FMU simulation per evaluation
        count[0] += 1
        return (q - fmpy_q(fmu, u, dict(zip(free, x * scale)))) / args.noise

    t0 = time.perf_counter()
    sol = least_squares(residual, np.ones(len(free)), bounds=(lo, hi), diff_step=1e-6, x_scale="jac", max_nfev=50)
    t_naive = time.perf_counter() - t0
    naive_opt = sol.x * scale

    print(f"{class_name}, {args.seconds:g} s at {1 / TS:g} Hz ({n} samples), free {free}")
    print(f"truth          {np.array([truth[k] for k in free])}")
    print(f"CasADi OE      {casadi_opt}  ({t_casadi:.2f} s incl. build {t_build:.2f} s with C compile, "
          f"{fit.nfev} free runs)")
    print(f"  cached .so   {np.array([fit_cached.values[k] for k in free])}  ({t_cached:.2f} s incl. build "
          f"{t_build_cached:.2f} s)")
    print(f"scipy + fmpy   {naive_opt}  ({t_naive:.2f} s, {count[0]} FMU simulations)")
    print(f"std (CasADi)   {std}")
    print(f"speed-up       {t_naive / t_casadi:.1f}x incl. compile, {t_naive / t_cached:.1f}x cached "
          f"(target >= 10x)")
    diff = np.abs(casadi_opt - naive_opt) / std
    print(f"|difference| / std: {diff} (agreement criterion: < 0.1 std each)")
    ratio("ident_oe.speedup_incl_compile", t_naive / t_casadi, "scipy least_squares over fmpy.simulate_fmu "
          "(finite differences) / CasADi refit incl. C compile, wall (target >= 10)")
    ratio("ident_oe.speedup_cached", t_naive / t_cached, "scipy least_squares over fmpy.simulate_fmu "
          "(finite differences) / CasADi refit with the cached .so, wall (target >= 10)")


if __name__ == "__main__":
    main()

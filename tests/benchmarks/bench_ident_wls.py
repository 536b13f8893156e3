"""Benchmark (not a test): inverse-dynamics Gauss-Markov least squares on 10^5 samples.

1. serial joint (7 parameters): 10^5 samples, frequency-domain filtering/differentiation + regressor +
   weighted least squares with statistics;
2. a 6-channel stacked problem (24 parameters, hexapod-sized as Abdellatif Table I) with a full 6x6
   channel covariance: 10^5 samples = 6*10^5 rows.
Each timing is the best of 3 runs. Target (issue 5): WLS on 10^5 samples under 1 s.

Run: .venv/bin/python tests/benchmarks/bench_ident_wls.py [--smoke]   (--smoke: 10^4 samples, one run each)
Ratios: each time over the 1 s target (the baseline).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from motiontwin.ident.joint import joint_regressor  # noqa: E402
from motiontwin.ident.leastsquares import gauss_markov  # noqa: E402
from motiontwin.ident.signals import lowpass_differentiate  # noqa: E402
from motiontwin.harness.excitation import fourier_trajectory  # noqa: E402
from ratios import ratio, smoke  # noqa: E402

N = 100_000
FS = 1000.0
REPEATS = 3


def best_of(fn, repeats=None):
    repeats = repeats or REPEATS
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    global N, REPEATS
    if smoke():
        N, REPEATS = 10_000, 1
    rng = np.random.default_rng(0)
    t = np.arange(N) / FS
    f0 = FS / N * 10  # 10 whole periods in the record
    q = fourier_trajectory(t, f0, 4 * np.array([1, -0.6, 0.4, 0.3, -0.2]), np.array([-2, 2.8, -1.2, 0.8, 1])).position
    theta = np.array([0.5, 2.9, 0.9, 1.5, 2.0, 1.95, 1.5])
    q_meas = q + 1e-4 * rng.standard_normal(N)

    def joint_pipeline():
        d = lowpass_differentiate(q_meas, FS, 50 * f0)
        phi, names = joint_regressor(d.position, d.velocity, d.acceleration)
        tau = phi @ theta + 0.5 * rng.standard_normal(N)
        return gauss_markov(phi, tau, names=names, noise_covariance=0.25)

    d = lowpass_differentiate(q_meas, FS, 50 * f0)
    phi, names = joint_regressor(d.position, d.velocity, d.acceleration)
    tau = phi @ theta + 0.5 * rng.standard_normal(N)
    t_wls, res = best_of(lambda: gauss_markov(phi, tau, names=names, noise_covariance=0.25))
    t_pipe, _ = best_of(joint_pipeline)

    n_ch, n_par = 6, 24
    psi = rng.standard_normal((N * n_ch, n_par)) * np.logspace(-1, 1, n_par)
    a = rng.standard_normal((n_ch, n_ch))
    cov = a @ a.T / n_ch + 0.1 * np.eye(n_ch)
    noise = (np.linalg.cholesky(cov) @ rng.standard_normal((n_ch, N))).T.reshape(-1)
    p_true = rng.standard_normal(n_par)
    y = psi @ p_true + noise
    t_multi, res_multi = best_of(lambda: gauss_markov(psi, y, channel_covariance=cov))
    z = np.abs(res_multi.estimate - p_true) / res_multi.std

    print(f"{'case':<52} {'time [s]':>9}")
    print(f"{f'joint WLS, {N:.0e} x 7 (statistics included)':<52} {t_wls:9.3f}")
    print(f"{'joint pipeline: FFT filter + regressor + WLS, 1e5':<52} {t_pipe:9.3f}")
    print(f"{'6-channel GM, 1e5 samples (6e5 x 24), full 6x6 cov':<52} {t_multi:9.3f}")
    print(f"joint max |error|/std = {np.max(np.abs(res.estimate - theta) / res.std):.2f}; "
          f"6-channel max |error|/std = {z.max():.2f}")
    print("target: < 1 s for 1e5 samples:", "PASS" if max(t_wls, t_pipe) < 1.0 else "FAIL")
    for name, seconds in (("joint_wls", t_wls), ("joint_pipeline", t_pipe), ("six_channel_gm", t_multi)):
        ratio(f"wls.{name}_over_target", seconds / 1.0, f"1 s target for 1e5 samples ({N} samples here)")


if __name__ == "__main__":
    main()

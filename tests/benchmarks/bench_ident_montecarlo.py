"""Benchmark (not a test): 100-seed Monte Carlo of the identification methods (Abdellatif's 100 trials).

1. Serial joint (truth: closed-loop ODE, tests/ident_truth.py; noise 1e-4 rad on position, 0.5 N m on
   torque; 10 periods of 2 s at 1 kHz; f_c = 10 Hz; samples slower than 0.2 rad/s dropped) for three
   excitations under the same limits (|q| <= 1.5 rad, |qd| <= 6 rad/s, |qdd| <= 40 rad/s^2): random
   Fourier coefficients, condition-number design and D-optimal design (CasADi/IPOPT). Table per design
   and parameter: mean error %, spread (std) %, coverage of the 95 % intervals. Figure like
   Abdellatif's Fig. 5: estimated normal densities per parameter and design.
2. Projection method vs direct output-error fit on closed-loop data: bias table (tests/test_ident_closedloop.py setup).

Run: .venv/bin/python tests/benchmarks/bench_ident_montecarlo.py [--seeds 100] [--figure out.png] [--smoke]
(--smoke: 2 seeds, one optimiser start per design). Ratios: the D-optimal design's spread over the random
excitation's (the baseline), and the projection method's gain bias over the direct output-error fit's.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from motiontwin.ident.closedloop import fit_output_error, project_on_reference  # noqa: E402
from motiontwin.ident.excitation_design import (  # noqa: E402
    ExcitationLimits,
    evaluate_design,
    optimize_excitation,
    random_design,
)
from motiontwin.ident.joint import identify_joint_periodic  # noqa: E402
from ratios import ratio  # noqa: E402
from tests import test_ident_closedloop as cl  # noqa: E402
from tests.ident_truth import JOINT_TRUTH, noisy_periods, simulate_joint_period  # noqa: E402

LIMITS = ExcitationLimits(q_center=0.0, q_range=1.5, v_max=6.0, a_max=40.0)
F0, FS, NH = 0.5, 1000.0, 5
NAMES = list(JOINT_TRUTH)
TRUTH = np.array([JOINT_TRUTH[n] for n in NAMES])


def joint_monte_carlo(seeds: int, starts: int = 3):
    designs = {
        "random": random_design(LIMITS, F0, NH, np.random.default_rng(3)),
        "condition": optimize_excitation(LIMITS, F0, NH, criterion="condition", n_starts=starts),
        "d_optimal": optimize_excitation(LIMITS, F0, NH, criterion="d_optimal", n_starts=starts),
    }
    results = {}
    for label, design in designs.items():
        metrics = evaluate_design(design, LIMITS)
        _, q, u = simulate_joint_period(a=design.a, b=design.b, q0=design.q0, f0=F0, fs=FS)
        estimates, covered = [], []
        for seed in range(seeds):
            qs, us = noisy_periods(q, u, 10, 1e-4, 0.5, np.random.default_rng(seed))
            fit = identify_joint_periodic(qs, us, FS, F0, 10.0, min_speed=0.2).fit
            estimates.append(fit.estimate)
            ci = fit.confidence_interval(0.95)
            covered.append((ci[:, 0] <= TRUTH) & (TRUTH <= ci[:, 1]))
        results[label] = (metrics, np.array(estimates), np.array(covered))
    return results


def print_joint_table(results) -> None:
    print("Serial joint, 3 excitations x", len(next(iter(results.values()))[1]), "seeds")
    for label, (metrics, est, cov) in results.items():
        print(f"\n[{label}] cond(Psi) = {metrics.condition_number:.1f}, log det(Psi^T Psi) = "
              f"{metrics.log_det_information:.2f}, max constraint use = {metrics.max_constraint_ratio:.3f}")
        print(f"{'parameter':>8} {'truth':>8} {'mean err %':>10} {'|err| %':>8} {'std %':>7} {'95% cover':>9}")
        rel = (est - TRUTH) / np.abs(TRUTH)
        for i, name in enumerate(NAMES):
            print(f"{name:>8} {TRUTH[i]:8.4f} {100 * rel[:, i].mean():10.3f} {100 * np.abs(rel[:, i]).mean():8.3f} "
                  f"{100 * rel[:, i].std():7.3f} {100 * cov[:, i].mean():8.0f}%")
    print("\nspread (std %) per parameter:")
    print(f"{'design':>10} " + " ".join(f"{n:>7}" for n in NAMES) + f" {'gen.var':>9}")
    for label, (_, est, _) in results.items():
        rel = (est - TRUTH) / np.abs(TRUTH)
        gv = np.linalg.slogdet(np.cov(rel.T))[1] / len(NAMES)
        print(f"{label:>10} " + " ".join(f"{100 * s:7.3f}" for s in rel.std(axis=0)) + f" {gv:9.3f}")
    print("(gen.var = log det of the empirical covariance of relative errors / n_par; smaller is better)")


def save_figure(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(14, 6))
    styles = {"random": ":", "condition": "--", "d_optimal": "-"}
    for i, name in enumerate(NAMES):
        ax = axes.flat[i]
        for label, (_, est, _) in results.items():
            mu, sd = est[:, i].mean(), est[:, i].std()
            x = np.linspace(mu - 4 * sd, mu + 4 * sd, 200)
            ax.plot(x, np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), styles[label], label=label)
        ax.axvline(TRUTH[i], color="k", lw=0.8)
        ax.set_title(name)
    axes.flat[-1].axis("off")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("Estimated normal distributions of the joint parameters (cf. Abdellatif Fig. 5)")
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(fd)
    fig.savefig(tmp, dpi=100)
    os.replace(tmp, path)
    print(f"figure written to {path}")


def closed_loop_table(seeds: int) -> float:
    """Prints the bias table; returns |gain bias| of the projection method / that of the direct fit."""
    truth = cl._features(cl.B, cl.A)
    naive, pm = [], []
    for seed in range(seeds):
        r, u, y = cl._closed_loop_data(seed)
        naive_fit = fit_output_error(u, y, 2, 2, skip=cl.M_CAUSAL)
        proj = project_on_reference(r, u, 0, cl.M_CAUSAL)
        pm_fit = fit_output_error(proj.projected, y, 2, 2, skip=cl.M_CAUSAL)
        naive.append(cl._features(naive_fit.b, naive_fit.f) / truth - 1)
        pm.append(cl._features(pm_fit.b, pm_fit.f) / truth - 1)
    naive, pm = 100 * np.array(naive), 100 * np.array(pm)
    print(f"\nClosed-loop identification, {seeds} seeds: relative error of the identified plant [%]")
    print(f"{'method':>22} {'gain bias':>10} {'gain std':>9} {'f_res bias':>11} {'f_res std':>10}")
    for label, e in (("direct output-error", naive), ("projection method", pm)):
        print(f"{label:>22} {e[:, 0].mean():10.2f} {e[:, 0].std():9.2f} {e[:, 1].mean():11.2f} {e[:, 1].std():10.2f}")
    return abs(pm[:, 0].mean()) / abs(naive[:, 0].mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--figure", type=Path, default=None,
                        help="also draw the errors per design (as the paper's Fig. 5) into this PNG file")
    parser.add_argument("--smoke", action="store_true", help="2 seeds, 1 optimiser start: only proves it runs")
    args = parser.parse_args()
    if args.smoke:
        args.seeds = 2
    t0 = time.perf_counter()
    results = joint_monte_carlo(args.seeds, 1 if args.smoke else 3)
    print_joint_table(results)
    if args.figure is not None:
        save_figure(results, args.figure)
    bias = closed_loop_table(args.seeds)
    print(f"\ntotal time {time.perf_counter() - t0:.1f} s")
    spread = {label: ((est - TRUTH) / np.abs(TRUTH)).std(axis=0) for label, (_, est, _) in results.items()}
    ratio("montecarlo.doptimal_over_random_spread", float(np.mean(spread["d_optimal"] / spread["random"])),
          "random Fourier excitation: spread of the relative errors, mean over the parameters")
    ratio("montecarlo.projection_over_direct_gain_bias", bias, "direct output-error fit on closed-loop data: "
          "|gain bias|")


if __name__ == "__main__":
    main()

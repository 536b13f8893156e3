"""Benchmark (not a test): 100-seed Monte Carlo of the hexapod base-parameter identification
(Abdellatif & Heimann's 100 trials), on synthetic data from the Modelica truth MotionTwin.Plants.Hexapod.

Truth: leg forces by inverse dynamics of the Modelica model along the prescribed pose trajectory
(perfect tracking, the closed-loop measurement of the paper), leg lengths from its outputs.
Experiment: random Fourier pose excitation, 5 harmonics, f0 = 0.5 Hz, 10 periods at 200 Hz; pose
within home +- (60, 60, 50 mm, 0.12, 0.12, 0.15 rad). Sensors: leg length white noise 2 um then
1 um quantisation; leg forces 0.5 N standard deviation, correlation 0.3 between legs. Processing:
direct kinematics per sample, period averaging with full force covariance, ideal low-pass at
f_c = 2.5 Hz, Gauss-Markov on the 18 base parameters.

Prints, per base parameter: truth, mean error %, mean |error| %, spread %, mean estimated std %,
coverage of the 95 % intervals; then the pass/fail of the targets (every mean |error| < 2 %, overall
coverage in 90-98 %). Optional figure: estimated normal densities per parameter (cf. Fig. 5).

With --design-seeds N (> 0): excitation design under leg limits (pose ranges as above, |dL/dt| <= 0.3 m/s,
|d2L/dt2| <= 3 m/s^2): random coefficients vs the condition-number design vs the D-optimal design
(ident.excitation_design.optimize_hexapod_excitation: CasADi/IPOPT on the Modelica model's symbolic
regressor, --design-starts random starts of --design-iterations iterations each), N seeds each; spread table
per parameter and design, and (--design-figure) a figure like Fig. 5 (dotted: random, dashed: condition
number, solid: D-optimal). The random baseline of the Monte Carlo is one draw (seed 3); the Gauss-Markov
prediction of the spread is also printed for --random-draws further draws, to show where that draw lies.

Run: .venv/bin/python tests/benchmarks/bench_ident_hexapod.py [--seeds 100] [--workers 2]
     [--figure out.png] [--design-seeds 100] [--design-starts 3] [--design-iterations 100]
     [--random-draws 20] [--design-figure fig5.png] [--smoke]
(--smoke: 2 seeds, 1 worker; the targets are not judged). Ratios: the largest mean |error| over the 2 %
target, the overall coverage over the nominal 95 %.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from motiontwin.ident.excitation_design import optimize_hexapod_excitation, predicted_relative_std  # noqa: E402
from ratios import ratio  # noqa: E402
from motiontwin.ident.hexapod import (  # noqa: E402
    HexapodLimits,
    MeasurementNoise,
    ModelicaHexapod,
    evaluate_pose_design,
    hexapod_base_parameters,
    identify_hexapod_periodic,
    measure_periods,
    random_limited_excitation,
    random_pose_excitation,
    simulate_period,
    stacked_regressor,
)

POSE_RANGE = np.array([0.06, 0.06, 0.05, 0.12, 0.12, 0.15])
F0, FS, NH, N_PERIODS = 0.5, 200.0, 5, 10
FC = NH * F0
NOISE = MeasurementNoise(sigma_length=2e-6, length_quantum=1e-6,
                         force_covariance=0.5**2 * (0.7 * np.eye(6) + 0.3 * np.ones((6, 6))))
LIMITS = HexapodLimits(POSE_RANGE, leg_speed=0.3, leg_acceleration=3.0)


def _trial(job):
    seed, lengths, forces, base, truth_base = job
    measured_lengths, measured_forces = measure_periods(lengths, forces, N_PERIODS, NOISE,
                                                        np.random.default_rng(seed))
    fit = identify_hexapod_periodic(measured_lengths, measured_forces, FS, F0, FC, base=base).fit
    ci = fit.confidence_interval(0.95)
    return fit.estimate, fit.std, (ci[:, 0] <= truth_base) & (truth_base <= ci[:, 1])


def monte_carlo(seeds: int, workers: int, excitation=None, truth=None, base=None):
    truth = ModelicaHexapod() if truth is None else truth
    base = hexapod_base_parameters() if base is None else base
    truth_base = base.from_full(truth.theta())
    if excitation is None:
        excitation = random_pose_excitation(POSE_RANGE, F0, NH, np.random.default_rng(1))
    _, lengths, forces = simulate_period(truth, excitation, FS)
    jobs = [(seed, lengths, forces, base, truth_base) for seed in range(seeds)]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        rows = list(pool.map(_trial, jobs))
    estimates, stds, covered = (np.array(r) for r in zip(*rows))
    return base.names, truth_base, estimates, stds, covered


def print_table(names, truth, estimates, stds, covered) -> bool:
    rel = (estimates - truth) / np.abs(truth)
    mean_abs = 100 * np.abs(rel).mean(axis=0)
    coverage = 100 * covered.mean(axis=0)
    print(f"Hexapod base parameters, {len(estimates)} seeds (Monte Carlo on the Modelica truth)")
    print(f"{'base parameter':>18} {'truth':>10} {'mean err %':>10} {'|err| %':>8} {'spread %':>8} "
          f"{'est.std %':>9} {'95% cover':>9}")
    for i, name in enumerate(names):
        print(f"{name:>18} {truth[i]:10.4f} {100 * rel[:, i].mean():10.3f} {mean_abs[i]:8.3f} "
              f"{100 * rel[:, i].std():8.3f} {100 * (stds[:, i] / np.abs(truth[i])).mean():9.3f} "
              f"{coverage[i]:8.0f}%")
    total_coverage = 100 * covered.mean()
    ratio("hexapod.max_mean_abs_error_over_target", float(mean_abs.max()) / 2.0, "2 % target on the mean |error| "
          "of every base parameter")
    ratio("hexapod.coverage", total_coverage / 95.0, "nominal 95 % coverage, all base parameters")
    ok_error = bool(np.all(mean_abs < 2.0))
    ok_cover = bool(90.0 <= total_coverage <= 98.0)
    print(f"\nmax mean |error| = {mean_abs.max():.3f} % (target < 2 %): {'PASS' if ok_error else 'FAIL'}")
    print(f"coverage of the 95 % intervals over all parameters = {total_coverage:.1f} % "
          f"(per parameter {coverage.min():.0f}-{coverage.max():.0f} %; target 90-98 %): "
          f"{'PASS' if ok_cover else 'FAIL'}")
    return ok_error and ok_cover


def save_figure(names, truth, estimates, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 6, figsize=(18, 8))
    for i, name in enumerate(names):
        ax = axes.flat[i]
        mu, sd = estimates[:, i].mean(), estimates[:, i].std()
        x = np.linspace(mu - 4 * sd, mu + 4 * sd, 200)
        ax.hist(estimates[:, i], bins=15, density=True, alpha=0.4)
        ax.plot(x, np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)))
        ax.axvline(truth[i], color="k", lw=0.8)
        ax.set_title(name, fontsize=8)
    fig.suptitle("Hexapod base parameters: estimated normal distributions over the seeds (cf. Abdellatif Fig. 5)")
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(fd)
    fig.savefig(tmp, dpi=90)
    os.replace(tmp, path)
    print(f"figure written to {path}")


def scaled_condition(design, base, truth_base, n_samples: int = 200) -> float:
    """cond of the whitened regressor with columns scaled by the a-priori parameters (relative parameters),
    the quantity the condition-number design minimises."""
    t = np.arange(n_samples) / (n_samples * design.fundamental_frequency)
    psi = base.reduce_regressor(stacked_regressor(*design.trajectory(t)))
    inv_chol = np.linalg.inv(np.linalg.cholesky(NOISE.force_covariance))
    whitened = np.einsum("ij,njp->nip", inv_chol, psi.reshape(n_samples, 6, -1)).reshape(psi.shape)
    return float(np.linalg.cond(whitened * np.abs(truth_base)))


def design_comparison(seeds: int, workers: int, starts: int, iterations: int, random_draws: int):
    truth, base = ModelicaHexapod(), hexapod_base_parameters()
    truth_base = base.from_full(truth.theta())
    designs = {"random": random_limited_excitation(LIMITS, F0, NH, np.random.default_rng(3))}
    for criterion in ("condition", "d_optimal"):
        t0 = time.perf_counter()
        result = optimize_hexapod_excitation(
            LIMITS, F0, NH, criterion=criterion, truth=truth, base=base,
            force_covariance=NOISE.force_covariance, n_starts=starts, max_iter=iterations)
        designs[criterion] = result.excitation
        print(f"{criterion} design: {starts} starts x {iterations} IPOPT iterations in "
              f"{time.perf_counter() - t0:.1f} s; objectives per start "
              f"{', '.join(f'{v:.4g}' for v in result.start_objectives)} (kept start {result.best_start})")
    rng = np.random.default_rng(100)
    draws = [random_limited_excitation(LIMITS, F0, NH, rng) for _ in range(random_draws)]
    predicted = np.array([predicted_relative_std(d, base, NOISE.force_covariance, truth_base, N_PERIODS, FS)
                          for d in draws])
    results = {}
    for label, design in designs.items():
        metrics = evaluate_pose_design(design, base, LIMITS, NOISE.force_covariance)
        extra = (scaled_condition(design, base, truth_base),
                 predicted_relative_std(design, base, NOISE.force_covariance, truth_base, N_PERIODS, FS))
        results[label] = (metrics, *monte_carlo(seeds, workers, design, truth, base), extra)
    return results, predicted


def _generalised_variance(relative_errors: np.ndarray) -> float:
    """log det of the empirical covariance of the relative errors / n_par (log of the geometric mean variance)."""
    return float(np.linalg.slogdet(np.cov(relative_errors.T))[1] / relative_errors.shape[1])


def print_design_table(results, predicted_random) -> bool:
    first = next(iter(results.values()))
    names, truth = first[1], first[2]
    print(f"\nExcitation designs under leg limits, {len(first[3])} seeds each")
    summary = {}
    for label, (metrics, _, _, est, _, cov, (cond_scaled, pred)) in results.items():
        rel = (est - truth) / np.abs(truth)
        spread = 100 * rel.std(axis=0)
        summary[label] = (spread.max(), np.exp(np.mean(np.log(spread))), _generalised_variance(rel))
        print(f"[{label:>9}] cond(Psi) = {metrics.condition_number:7.1f}  cond(scaled) = {cond_scaled:6.1f}  "
              f"log det(Psi^T S^-1 Psi) = {metrics.log_det_information:7.2f}  limit use = "
              f"{metrics.max_limit_ratio:.3f}  max |err| = {100 * np.abs(rel).mean(axis=0).max():.3f} %  "
              f"coverage = {100 * cov.mean():.1f} %")
        print(f"{'':12}spread: max {spread.max():.3f} %, geometric mean {summary[label][1]:.4f} %, "
              f"gen. variance {summary[label][2]:.3f}; Gauss-Markov prediction: max {100 * pred.max():.3f} %, "
              f"geometric mean {100 * np.exp(np.mean(np.log(pred))):.4f} %")
    if len(predicted_random):
        worst = 100 * predicted_random.max(axis=1)
        gmean = 100 * np.exp(np.mean(np.log(predicted_random), axis=1))
        print(f"{len(predicted_random)} other random draws, Gauss-Markov prediction: max spread median "
              f"{np.median(worst):.3f} % (best {worst.min():.3f} %), geometric mean median {np.median(gmean):.4f} % "
              f"(best {gmean.min():.4f} %)")
    print("\nspread (std of the relative error, %) per base parameter:")
    print(f"{'base parameter':>18} " + " ".join(f"{label:>10}" for label in results))
    spreads = {label: 100 * ((est - truth) / np.abs(truth)).std(axis=0)
               for label, (_, _, _, est, _, _, _) in results.items()}
    for i, name in enumerate(names):
        print(f"{name:>18} " + " ".join(f"{spreads[label][i]:10.3f}" for label in results))
    print(f"{'gen. variance':>18} " + " ".join(f"{summary[label][2]:10.3f}" for label in results))
    print("(gen. variance = log det of the empirical covariance of the relative errors / n_par; smaller is better)")
    checks = {
        "D-optimal spread < condition-number spread (gen. variance)":
            summary["d_optimal"][2] < summary["condition"][2],
        "condition-number design beats random (gen. variance and max spread)":
            summary["condition"][2] < summary["random"][2] and summary["condition"][0] < summary["random"][0],
        "D-optimal design beats random (gen. variance and max spread)":
            summary["d_optimal"][2] < summary["random"][2] and summary["d_optimal"][0] < summary["random"][0],
    }
    for text, ok in checks.items():
        print(f"{text}: {'PASS' if ok else 'FAIL'}")
    return all(checks.values())


def save_design_figure(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(results.values()))
    names, truth = first[1], first[2]
    fig, axes = plt.subplots(3, 6, figsize=(18, 8))
    styles = {"random": ":", "condition": "--", "d_optimal": "-"}
    for i, name in enumerate(names):
        ax = axes.flat[i]
        for label, (_, _, _, est, _, _, _) in results.items():
            mu, sd = est[:, i].mean(), est[:, i].std()
            x = np.linspace(mu - 4 * sd, mu + 4 * sd, 200)
            ax.plot(x, np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), styles[label], label=label)
        ax.axvline(truth[i], color="k", lw=0.8)
        ax.set_title(name, fontsize=8)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Hexapod: estimated normal distributions per excitation design (cf. Abdellatif Fig. 5)")
    fig.tight_layout()
    fd, tmp = tempfile.mkstemp(suffix=".png", dir=path.parent)
    os.close(fd)
    fig.savefig(tmp, dpi=90)
    os.replace(tmp, path)
    print(f"figure written to {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--figure", type=Path, default=None)
    parser.add_argument("--design-seeds", type=int, default=0)
    parser.add_argument("--design-starts", type=int, default=3)
    parser.add_argument("--design-iterations", type=int, default=100)
    parser.add_argument("--random-draws", type=int, default=20)
    parser.add_argument("--design-figure", type=Path, default=None)
    parser.add_argument("--smoke", action="store_true", help="2 seeds, 1 worker: only proves the script runs")
    args = parser.parse_args()
    if args.smoke:
        args.seeds, args.workers = 2, 1
    t0 = time.perf_counter()
    ok = True
    if args.seeds > 0:
        names, truth, estimates, stds, covered = monte_carlo(args.seeds, args.workers)
        ok = print_table(names, truth, estimates, stds, covered)
        if args.figure is not None:
            save_figure(names, truth, estimates, args.figure)
    if args.design_seeds > 0:
        results, predicted_random = design_comparison(args.design_seeds, args.workers, args.design_starts,
                                                      args.design_iterations, args.random_draws)
        ok = print_design_table(results, predicted_random) and ok
        if args.design_figure is not None:
            save_design_figure(results, args.design_figure)
    print(f"\ntotal time {time.perf_counter() - t0:.1f} s")
    sys.exit(0 if ok or args.smoke else 1)


if __name__ == "__main__":
    main()

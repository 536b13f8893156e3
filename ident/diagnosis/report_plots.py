"""The PNG plots of a diagnosis report (one axis: training residual, inverse-dynamics residual against
velocity and position, residual spectrum, validation fit; several axes: one panel per axis). Units: SI, shown
in the axis's scales (:class:`axis_units.AxisUnits`)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from motiontwin.ident.diagnosis import evidence  # noqa: E402
from motiontwin.ident.diagnosis.axis_units import bundle_units  # noqa: E402

CLIP_WIDEN = 0.5     # residual plots: the 1-99 % range widened by this share of its width; beyond: clipped, counted


def robust_limits(values: np.ndarray) -> tuple[float, float, int]:
    """Plot limits: the 1-99 % percentile range widened by half its width on each side, and how many points
    lie outside (clipped to the edge): a few filter end effects of +-1600 N no longer squash a +-20 N
    friction step, which stays whole however many samples it has."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return -1.0, 1.0, 0
    q_lo, q_hi = (float(v) for v in np.percentile(finite, [1, 99]))
    span = (q_hi - q_lo) or float(np.max(np.abs(finite))) or 1.0
    lo, hi = q_lo - CLIP_WIDEN * span, q_hi + CLIP_WIDEN * span
    return lo, hi, int(np.sum((finite < lo) | (finite > hi)))


def diagnosis_plots(result: dict, staging: Path) -> tuple[list[str], dict[str, int]]:
    """The PNG plots and, per plot, how many residual points were clipped to its robust limits."""
    bundle, nominal, final = result["bundle"], result["nominal"], result["final"]
    train, val = bundle.train, bundle.validation
    ts = bundle.controller.sample_time
    sigma = result["weights"].sigma_q
    res_nom = train["q"] - nominal.fit.q_sim
    res_aug = train["q"] - final.fit.q_sim
    names = []
    clipped: dict[str, int] = {}
    units = bundle_units(bundle)
    k_res, res_unit = units.shown_residual(float(np.max(np.abs(np.concatenate(
        [res_nom, res_aug, val["q"] - nominal.val_q, val["q"] - result["q_augmented"]])))))
    k_pos, pos_unit = units.shown_position
    k_vel, vel_unit = units.shown_velocity

    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(train.time, res_nom * k_res, lw=0.6, label="nominal (refitted)")
    ax.plot(train.time, res_aug * k_res, lw=0.6, label="augmented")
    for a, b in evidence.flagged_windows(res_nom, train.time, sigma, ts):
        ax.axvspan(a, b, color="red", alpha=0.12)
    ax.set_xlabel("time [s]"), ax.set_ylabel(f"q residual [{res_unit}]"), ax.legend(), ax.grid(alpha=0.3)
    ax.set_title("Training residual; red: windows above 3 noise levels")
    names.append(_save(fig, staging, "residual_time.png"))

    ctx = result["context"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    if ctx.force is not None:
        shown, v, x, label = ctx.force, ctx.v, ctx.x, f"force residual of the nominal model [{units.force}]"
    else:
        shown, v, x, label = res_nom * k_res, np.gradient(train["q"], ts), train["q"], f"q residual [{res_unit}]"
    lo, hi, count = robust_limits(shown)
    for a, axis in zip(axes, (v * k_vel, x * k_pos)):
        a.plot(axis, np.clip(shown, lo, hi), ".", ms=1)
        a.set_ylim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
        a.grid(alpha=0.3)
    axes[0].set_ylabel(label)
    axes[0].set_xlabel(f"velocity [{vel_unit}]"), axes[1].set_xlabel(f"position [{pos_unit}]")
    fig.suptitle(f"Inverse-dynamics residual against velocity and position; {count} of {shown.size} outliers "
                 f"clipped", fontsize=10)
    clipped["residual_velocity_position.png"] = count
    names.append(_save(fig, staging, "residual_velocity_position.png"))

    fig, ax = plt.subplots(figsize=(9, 3.5))
    for res, label in ((res_nom, "nominal"), (res_aug, "augmented")):
        f, asd = evidence.spectrum(res, ts)
        ax.loglog(f[1:], asd[1:], lw=0.8, label=label)
    ax.set_xlabel("frequency [Hz]"), ax.set_ylabel(f"residual ASD [{units.position}/sqrt(Hz)]"), ax.legend()
    ax.grid(alpha=0.3)
    names.append(_save(fig, staging, "residual_spectrum.png"))

    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    axes[0].plot(val.time, val["q"] * k_pos, lw=0.8, label="measured")
    axes[0].plot(val.time, nominal.val_q * k_pos, lw=0.8, label="nominal")
    axes[0].plot(val.time, result["q_augmented"] * k_pos, lw=0.8, ls="--", label="augmented")
    axes[0].set_ylabel(f"q [{pos_unit}]"), axes[0].legend()
    axes[1].plot(val.time, (val["q"] - nominal.val_q) * k_res, lw=0.6, label="nominal")
    axes[1].plot(val.time, (val["q"] - result["q_augmented"]) * k_res, lw=0.6, label="augmented")
    axes[1].set_ylabel(f"error [{res_unit}]"), axes[1].set_xlabel("time [s]"), axes[1].legend()
    for a in axes:
        a.grid(alpha=0.3)
    fig.suptitle("Validation: fit before and after")
    names.append(_save(fig, staging, "validation_fit.png"))
    return names, clipped


def _save(fig, staging: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(staging / name, dpi=90)
    plt.close(fig)
    return name


def axis_plots(result: dict, staging: Path) -> list[str]:
    """The PNG plots of a multi-axis diagnosis, one panel per axis: the training residual of the refitted
    nominal and of the augmented model, and the validation error of both."""
    bundle, nominal, final = result["bundle"], result["nominal"], result["final"]
    axes = [a.output for a in bundle.plant.axes]
    names = []
    for rec, (q_nominal, q_final), name, title in (
            (bundle.train, (nominal.fit.q_sim, final.fit.q_sim), "residual_time.png", "Training residual"),
            (bundle.validation, (nominal.val_q, final.val_q), "validation_fit.png", "Validation error")):
        fig, panels = plt.subplots(len(axes), 1, figsize=(9, 1.8 * len(axes) + 1.2), sharex=True, squeeze=False)
        for k, (axis, ax) in enumerate(zip(axes, panels[:, 0])):
            scale, unit = bundle_units(bundle, axis).shown_residual(float(np.max(np.abs(np.concatenate(
                [rec[axis] - q_nominal[k], rec[axis] - q_final[k]])))))
            ax.plot(rec.time, (rec[axis] - q_nominal[k]) * scale, lw=0.6, label="nominal (refitted)")
            ax.plot(rec.time, (rec[axis] - q_final[k]) * scale, lw=0.6, label="augmented")
            ax.set_ylabel(f"{axis} [{unit}]"), ax.grid(alpha=0.3)
        panels[0, 0].legend(), panels[-1, 0].set_xlabel("time [s]")
        fig.suptitle(f"{title} per axis: nominal and augmented model")
        names.append(_save(fig, staging, name))
    return names

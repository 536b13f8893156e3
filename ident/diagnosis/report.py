"""Outputs of a diagnosis: diagnosis.json (the issue-7 contract), validation_prediction.csv, the augmented
FMU and report.md with PNG plots. Units: SI (s, m, N, Hz)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from motiontwin.fmus.build import build_fmu  # noqa: E402
from motiontwin.ident.diagnosis import evidence as ev  # noqa: E402
from motiontwin.ident.diagnosis.pipeline import AUGMENTED_CLASS  # noqa: E402


def _strip(values: dict[str, float]) -> dict[str, float]:
    return {k[len("plant."):] if k.startswith("plant.") else k: float(v) for k, v in values.items()}


def _location(result: dict, name: str) -> dict:
    """Where the effect acts: its contribution to the simulated position on the training recording."""
    final = result["final"]
    bundle = result["bundle"]
    info = final.evidence[name]
    previous = info["previous"]
    contribution = final.fit.q_sim - previous.fit.q_sim
    ctx = result["context"]
    ts = bundle.controller.Ts
    v = ctx.v if ctx.v is not None else np.gradient(bundle.train["q"], ts)
    loc = ev.locate(contribution, v, bundle.train["q"], ts)
    sigma = max(result["weights"].sigma_q, 1e-15)
    windows = ev.flagged_windows(bundle.train["q"] - previous.fit.q_sim, bundle.train.time, sigma, ts)
    loc["time_windows"] = windows[:10]
    return loc


def diagnosis_document(result: dict, out: Path, fmu_path: Path | None) -> dict:
    final, nominal = result["final"], result["nominal"]
    ctx = result["context"]
    effects = []
    order = sorted(final.effects, key=lambda e: -final.evidence[e.name]["cost_reduction"])
    for effect in order:
        info = final.evidence[effect.name]
        params = effect.contract(final.fit.values, ctx)
        ratio = info["cost_reduction"] / info["null_threshold"]
        text = (f"{effect.explanation} Evidence: adding it lowers the noise-weighted output-error cost by "
                f"{info['cost_reduction']:.4g}, {ratio:.1f} times the 99.9 % level that a correct model leaves "
                f"on the same excitation (parametric bootstrap), and the validation RMS falls from "
                f"{info['validation_rms_before']:.3g} m to {info['validation_rms_after']:.3g} m.")
        effects.append({"name": effect.name, "parameters": {k: float(v) for k, v in params.items()},
                        "location": _location(result, effect.name), "explanation": text,
                        "evidence": {"cost_reduction": info["cost_reduction"],
                                     "null_threshold": info["null_threshold"],
                                     "validation_rms_before": info["validation_rms_before"],
                                     "validation_rms_after": info["validation_rms_after"]}})
    q_meas = result["bundle"].validation["q"]
    aug_rms = float(np.sqrt(np.mean((q_meas - result["q_augmented"]) ** 2)))
    return {
        "effects": effects,
        "validation": {"nominal_rms": float(nominal.val_rms), "augmented_rms": aug_rms,
                       **_above_floor(float(nominal.val_rms), aug_rms, result["validation_floor"])},
        "nominal_parameters": _strip(nominal.fit.values),
        "augmented_parameters": _strip({k: v for k, v in result["augmented_values"].items()}),
        "augmented_model": str(out / "augmented_model" / f"{AUGMENTED_CLASS}.mo"),
        "augmented_fmu": str(out / fmu_path) if fmu_path else None,
        "noise": {"sigma_q": result["weights"].sigma_q, "sigma_u": result["weights"].sigma_u},
        "candidates": [{k: v for k, v in entry.items()} for entry in result["log"]],
        "runtime_s": round(result["seconds"], 2),
        "plant_roles": result["bundle"].plant.roles.as_dict(),
    }


def _above_floor(nominal_rms: float, augmented_rms: float, floor: float) -> dict[str, float]:
    """The validation RMS split into the noise floor and the model error above it [m]: the error of a
    model is sqrt(rms^2 - floor^2) (independent noise adds in power), and ``excess_ratio`` compares the
    augmented with the nominal model without the floor that neither can go below."""
    nominal_excess = math.sqrt(max(nominal_rms ** 2 - floor ** 2, 0.0))
    augmented_excess = math.sqrt(max(augmented_rms ** 2 - floor ** 2, 0.0))
    ratio = augmented_excess / nominal_excess if nominal_excess > 0 else math.nan
    return {"noise_floor_rms": floor, "nominal_excess_rms": nominal_excess,
            "augmented_excess_rms": augmented_excess, "excess_ratio": ratio}


def _plots(result: dict, staging: Path) -> list[str]:
    bundle, nominal, final = result["bundle"], result["nominal"], result["final"]
    train, val = bundle.train, bundle.validation
    ts = bundle.controller.Ts
    sigma = result["weights"].sigma_q
    res_nom = train["q"] - nominal.fit.q_sim
    res_aug = train["q"] - final.fit.q_sim
    names = []

    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(train.time, res_nom * 1e6, lw=0.6, label="nominal (refitted)")
    ax.plot(train.time, res_aug * 1e6, lw=0.6, label="augmented")
    for a, b in ev.flagged_windows(res_nom, train.time, sigma, ts):
        ax.axvspan(a, b, color="red", alpha=0.12)
    ax.set_xlabel("time [s]"), ax.set_ylabel("q residual [um]"), ax.legend(), ax.grid(alpha=0.3)
    ax.set_title("Training residual; red: windows above 3 noise levels")
    names.append(_save(fig, staging, "residual_time.png"))

    ctx = result["context"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    if ctx.force is not None:
        axes[0].plot(ctx.v, ctx.force, ".", ms=1)
        axes[1].plot(ctx.x * 1e3, ctx.force, ".", ms=1)
        axes[0].set_ylabel("force residual of the nominal model [N]")
    else:
        axes[0].plot(np.gradient(train["q"], ts), res_nom * 1e6, ".", ms=1)
        axes[1].plot(train["q"] * 1e3, res_nom * 1e6, ".", ms=1)
        axes[0].set_ylabel("q residual [um]")
    axes[0].set_xlabel("velocity [m/s]"), axes[1].set_xlabel("position [mm]")
    for a in axes:
        a.grid(alpha=0.3)
    fig.suptitle("Inverse-dynamics residual against velocity and position")
    names.append(_save(fig, staging, "residual_velocity_position.png"))

    fig, ax = plt.subplots(figsize=(9, 3.5))
    for res, label in ((res_nom, "nominal"), (res_aug, "augmented")):
        f, asd = ev.spectrum(res, ts)
        ax.loglog(f[1:], asd[1:], lw=0.8, label=label)
    ax.set_xlabel("frequency [Hz]"), ax.set_ylabel("residual ASD [m/sqrt(Hz)]"), ax.legend(), ax.grid(alpha=0.3)
    names.append(_save(fig, staging, "residual_spectrum.png"))

    fig, axes = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    axes[0].plot(val.time, val["q"] * 1e3, lw=0.8, label="measured")
    axes[0].plot(val.time, nominal.val_q * 1e3, lw=0.8, label="nominal")
    axes[0].plot(val.time, result["q_augmented"] * 1e3, lw=0.8, ls="--", label="augmented")
    axes[0].set_ylabel("q [mm]"), axes[0].legend()
    axes[1].plot(val.time, (val["q"] - nominal.val_q) * 1e6, lw=0.6, label="nominal")
    axes[1].plot(val.time, (val["q"] - result["q_augmented"]) * 1e6, lw=0.6, label="augmented")
    axes[1].set_ylabel("error [um]"), axes[1].set_xlabel("time [s]"), axes[1].legend()
    for a in axes:
        a.grid(alpha=0.3)
    fig.suptitle("Validation: fit before and after")
    names.append(_save(fig, staging, "validation_fit.png"))
    return names


def _save(fig, staging: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(staging / name, dpi=90)
    plt.close(fig)
    return name


def _markdown(doc: dict, plots: list[str], result: dict) -> str:
    val = doc["validation"]
    lines = ["# Mismatch diagnosis", "", f"Bundle: `{result['bundle'].directory}`", ""]
    if doc["effects"]:
        lines += ["## Missing physics found", ""]
        for e in doc["effects"]:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in e["parameters"].items())
            lines += [f"### {e['name']} ({params})", "", e["explanation"], "",
                      f"Location: {json.dumps(e['location'])}", ""]
    else:
        lines += ["## No missing physics", "", "After refitting the nominal parameters, no candidate effect "
                  "improved the fit beyond what a correct model leaves on the same excitation, or none improved "
                  "the validation fit: the nominal structure is kept, only its parameters were off.", ""]
    lines += ["## Fit", "", "| model | validation RMS [m] |", "|---|---|",
              f"| nominal, refitted | {val['nominal_rms']:.4g} |", f"| augmented | {val['augmented_rms']:.4g} |", "",
              f"Noise floor (RMS that the fitted model leaves when re-simulated with the estimated encoder noise "
              f"fed back): {val['noise_floor_rms']:.4g} m. Model error above it: {val['nominal_excess_rms']:.4g} m "
              f"(nominal) -> {val['augmented_excess_rms']:.4g} m (augmented).", "",
              "Nominal parameters (refitted): " + ", ".join(f"{k} = {v:.5g}" for k, v in
                                                          doc["nominal_parameters"].items()), "",
              "## Candidates tested", "", "| round | effect | cost reduction | null 99.9 % | ratio | seconds |",
              "|---|---|---|---|---|---|"]
    for c in doc["candidates"]:
        lines.append(f"| {c['round']} | {c['effect']} | {c['cost_reduction']:.4g} | {c['null_threshold']:.4g} | "
                     f"{c['evidence_ratio']:.2f} | {c['seconds']} |")
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots] + [""]
    lines += [f"Augmented model: `{doc['augmented_model']}`; FMU: `{doc['augmented_fmu']}`.", ""]
    return "\n".join(lines)


def write_all(result: dict, staging: Path, out: Path) -> dict:
    """Write every output into ``staging`` (paths in the document point into ``out``)."""
    staging.mkdir(parents=True, exist_ok=True)
    values = result["augmented_values"]
    model = result["augmented_model"]
    known = {v.name for v in model.parameters}
    built = build_fmu(model, staging / "fmu", "2.0", start_values={k: v for k, v in values.items() if k in known})
    fmu_rel = built.path.relative_to(staging)
    doc = diagnosis_document(result, out, fmu_rel)
    val = result["bundle"].validation
    table = np.column_stack([val.time, val["q"], result["nominal"].val_q, result["q_augmented"]])
    np.savetxt(staging / "validation_prediction.csv", table, delimiter=",", fmt="%.17g",
               header="time,q_measured,q_nominal,q_augmented", comments="")
    (staging / "diagnosis.json").write_text(json.dumps(_jsonable(doc), indent=2), encoding="utf-8")
    plots = _plots(result, staging)
    (staging / "report.md").write_text(_markdown(doc, plots, result), encoding="utf-8")
    return _jsonable(doc)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items() if k != "previous"}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj

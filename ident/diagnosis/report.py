"""Outputs of a diagnosis: diagnosis.json (the issue-7 contract), validation_prediction.csv, the augmented
FMU and report.md with PNG plots. Units: SI (s, m, N, Hz)."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.build import MODELICA_DIR, build_fmu
from motiontwin.ident.diagnosis.axis_units import AxisUnits, bundle_units
from motiontwin.ident.diagnosis.bounds import at_bound_markdown, bounds_widened, structure_at_bound
from motiontwin.ident.diagnosis import evidence
from motiontwin.ident.diagnosis.report_plots import CLIP_WIDEN, diagnosis_plots
from motiontwin.ident.diagnosis.bundle import Bundle, PlantInfo
from motiontwin.ident.diagnosis.empirical import POWER_SHARE
from motiontwin.ident.diagnosis.augmented import AUGMENTED_CLASS, write_axes_structure
from motiontwin.ident.diagnosis.effects import VOCABULARY, Effect
from motiontwin.ident.diagnosis.empirical import EMPIRICAL as EMPIRICAL_EFFECT
from motiontwin.ident.diagnosis.evidence import VALIDATION_GAIN
from motiontwin.ident.diagnosis.structure import ModelFit


#: units of the effects' parameters as the report states them (the contract's names)
CONTRACT_UNITS = {"F0": "N", "Fc": "N", "Fs": "N", "vs": "m/s", "Fc_pos": "N", "Fc_neg": "N", "amplitude": "N",
                  "period": "m", "delay": "s", "frequency": "Hz", "damping": "1", "mass_min": "kg", "mass_max": "kg",
                  "Fc_equivalent": "N", "offset_while_moving": "N", "A1": "N", "A2": "N", "n": "1", "b": "m",
                  "gap": "m", "z0": "m", "sigma0": "N/m", "sigma1": "N.s/m", "Fmax": "N", "Fc0": "N", "mu": "1",
                  "Fc_start": "N", "dFc": "N", "tau": "s", "error_amplitude": "m", "error_amplitude_2": "m"}


def _unit(name: str, units: dict[str, str]) -> str:
    return units.get(name, CONTRACT_UNITS.get(name, ""))


def _with_unit(value: float, unit: str) -> str:
    return f"{value:.4g} {unit}".rstrip() if unit not in ("", "1") else f"{value:.4g}"


def plant_units(result: dict) -> dict[str, str]:
    """Units of the plant parameters (their Modelica ``unit``) and of the effect parameters (written for a linear
    axis, in the axis's kind)."""
    units = {v.name: v.unit or "" for v in result["bundle"].plant.model.parameters}
    axis = bundle_units(result["bundle"])
    for effect in result["final"].effects:
        units.update({p.name: axis.si(p.unit) for p in effect.params})
    return units


def location_text(loc: dict, axis: str | None = None, units: AxisUnits = AxisUnits()) -> str:
    """The location of an effect in words and physical units (mm, mm/s or deg, deg/s; s, Hz); ``axis``: the
    output of the axis it acts on (several axes: the sentence names it and its direction), None for the one
    axis (x, or q when it turns)."""
    parts = [] if axis is None else [f"on axis {axis}"]
    v_lo, v_hi = loc["velocity_range"]
    direction = axis or ("q" if units.rotary else "x")
    moving = "turning" if units.rotary else "moving"
    k, speed = units.shown_velocity
    if v_lo >= 0:
        parts.append(f"while {moving} in +{direction} at {v_lo * k:.3g} to {v_hi * k:.3g} {speed}")
    elif v_hi <= 0:
        parts.append(f"while {moving} in -{direction} at {-v_hi * k:.3g} to {-v_lo * k:.3g} {speed}")
    else:
        parts.append(f"around standstill ({v_lo * k:.3g} to {v_hi * k:.3g} {speed})")
    x_lo, x_hi = loc["position_range"]
    k, length = units.shown_position
    parts.append(f"between {x_lo * k:.4g} and {x_hi * k:.4g} {length}")
    text = "Strongest " + " ".join(parts) + f"; residual power peaks at {loc['frequency_peak_hz']:.3g} Hz"
    windows = loc.get("time_windows") or []
    if windows:
        shown = ", ".join(f"{a:.3g}-{b:.3g} s" for a, b in windows[:5])
        text += f"; the nominal model's error exceeds 3 noise levels in {len(windows)} window(s): {shown}"
    return text + "."


def equivalent_forms(name: str, params: dict[str, float]) -> dict[str, float]:
    """Other parametrisations that predict the same forces while moving: asymmetric Coulomb friction
    Fc_pos (v > 0), Fc_neg (v < 0) equals Coulomb Fc = (Fc_pos + Fc_neg)/2 plus a constant force
    (Fc_pos - Fc_neg)/2 (they differ only at rest, where the asymmetric law gives zero)."""
    if name == "asymmetric_friction":
        return {"Fc_equivalent": 0.5 * (params["Fc_pos"] + params["Fc_neg"]),
                "offset_while_moving": 0.5 * (params["Fc_pos"] - params["Fc_neg"])}
    return {}


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
    ts = bundle.controller.sample_time
    v = ctx.v if ctx.v is not None else np.gradient(bundle.train["q"], ts)
    loc = evidence.locate(contribution, v, bundle.train["q"], ts)
    sigma = max(result["weights"].sigma_q, 1e-15)
    windows = evidence.flagged_windows(bundle.train["q"] - previous.fit.q_sim, bundle.train.time, sigma, ts)
    loc["time_windows"] = windows[:10]
    return loc


def evidence_level(info: dict) -> str:
    """What an effect's cost reduction was measured against: the rounds' parametric bootstrap, or (an effect
    the final prediction-error refit added, ``null_kind`` "chi-square") the chi-square quantile over the
    innovations' variance."""
    if info.get("null_kind") == "chi-square":
        return ("the 99.9 % chi-square quantile of its parameters over the innovations' variance (prediction-error "
                "weighting; the cost in those weights)")
    return "the 99.9 % level that a correct model leaves on the same excitation (parametric bootstrap)"


#: what a change to a kept effect's nested form after the rounds adds to its evidence (:mod:`nested`, :mod:`polish`)
NESTED_EVIDENCE = ("upgraded_from", "upgrade_cost_reduction", "upgrade_null_threshold", "upgrade_likelihood_ratio",
                   "upgrade_chi2_threshold", "demoted_from", "demotion_likelihood_ratio", "demotion_chi2_threshold",
                   "null_kind")


def diagnosis_document(result: dict, out: Path, fmu_path: Path | None) -> dict:
    final, nominal = result["final"], result["nominal"]
    ctx = result["context"]
    units = bundle_units(result["bundle"])
    effects = []
    named = [e for e in final.effects if e.family != EMPIRICAL_EFFECT]   # the empirical term: "unexplained"
    order = sorted(named, key=lambda e: -final.evidence[e.name]["cost_reduction"])
    for effect in order:
        info = final.evidence[effect.name]
        params = effect.contract(final.fit.values, ctx)
        ratio = info["cost_reduction"] / info["null_threshold"]
        text = (f"{effect.explanation} Evidence: adding it lowers the noise-weighted output-error cost by "
                f"{info['cost_reduction']:.4g}, {ratio:.1f} times {evidence_level(info)}, and "
                f"{evidence.validation_text(info, units)}.")
        location = _location(result, effect.name)
        equivalents = [{**e, "parameters": effect_contract(e, ctx, final)} for e in info.get("equivalents", [])]
        effects.append({"name": effect.name, "parameters": {k: float(v) for k, v in params.items()},
                        "units": {k: units.si(CONTRACT_UNITS.get(k, "")) for k in params},
                        "equivalent_forms": equivalent_forms(effect.name, params),
                        "equivalent_explanations": equivalents, "selection_rule": info.get("rule", ""),
                        "location": location, "location_text": location_text(location, units=units),
                        "explanation": text,
                        "evidence": {"cost_reduction": info["cost_reduction"],
                                     "null_threshold": info["null_threshold"],
                                     **{k: info[k] for k in (*evidence.VALIDATION_FIELDS, *NESTED_EVIDENCE)
                                        if k in info}}})
    q_meas = result["bundle"].validation["q"]
    aug_rms = float(np.sqrt(np.mean((q_meas - result["q_augmented"]) ** 2)))
    remainder = result.get("remainder") or {}
    return {
        "effects": effects,
        "unexplained": unexplained_entry(remainder),
        "not_confirmed": not_confirmed(result["log"], {(e.name, None) for e in final.effects}, result["bundle"]),
        "residual_check": {k: remainder[k] for k in ("status", "reason") if k in remainder},
        "validation": {"nominal_rms": float(nominal.val_rms), "augmented_rms": aug_rms,
                       **_above_floor(float(nominal.val_rms), aug_rms, result["validation_floor"]),
                       **({"estimation_rms": result["estimation_rms"], "estimation_from": result["estimation_from"]}
                          if result.get("estimation_rms") is not None else {}),
                       **({"force_rms": result["force"].rms, "force_floor_rms": result["force"].floor,
                           "force_estimation_rms": None if result.get("estimation_unknown") else result["force"].spread}
                          if result.get("force") is not None else {})},
        "nominal_parameters": _strip(nominal.fit.values),
        "augmented_parameters": _strip({k: v for k, v in result["augmented_values"].items()}),
        "augmented_model": str(out / "augmented_model" / f"{AUGMENTED_CLASS}.mo"),
        "augmented_fmu": str(out / fmu_path) if fmu_path else None,
        "noise": {"sigma_q": result["weights"].sigma_q, "sigma_u": result["weights"].sigma_u,
                  "final_fit_weighting": ("innovations" if result["weights"].whiten_q is not None
                                          or result["weights"].whiten_u is not None else "white"),
                  "process": (result["process_noise"].as_dict() if result.get("process_noise") is not None
                              else None)},
        "candidates": [{k: v for k, v in entry.items()} for entry in result["log"]],
        "location": result["located"],      # each round after the first: force residual / noise reference
        "runtime_s": round(result["seconds"], 2),
        "plant_roles": result["bundle"].plant.roles.as_dict(),
        "at_bound": structure_at_bound(final), "bounds_widened": bounds_widened(final),
        "plant_physics": result.get("plant_physics", {}),
        "units": units.as_dict(),
        "controller": (result["bundle"].observer.as_dict() if result["bundle"].observer is not None
                       else {"kind": "given", "Ts": result["bundle"].controller.Ts,
                             "updates_per_sample": result["bundle"].controller.ticks,
                             "rate": result["bundle"].controller.describe_rate()}),
    }


def not_confirmed(log: list[dict], named: set[tuple[str, str | None]], bundle: Bundle) -> list[dict]:
    """diagnosis.json's ``not_confirmed``: the significant candidates the validation rejected but does not
    exercise (``not_exercised_by_validation`` in their candidate entry, :func:`select._unexercised`), judged by
    the latest round's entry per effect and axis, and not in the final model (``named``: its (effect, axis)
    pairs, axis None for one axis). They are not in the model: nothing confirms them. Their parameters' units
    are those of their axis in ``bundle``."""
    latest = {(c["effect"], c.get("axis")): c for c in log if "validation_rms_after" in c}
    keys = ("effect", "axis", "round", "cost_reduction", "null_threshold", "evidence_ratio", "parameters",
            "not_exercised_by_validation")
    entries = [{k: c[k] for k in keys if k in c} for key, c in latest.items()
               if "not_exercised_by_validation" in c and key not in named]
    for entry in entries:
        units = bundle_units(bundle, entry.get("axis"))
        entry["units"] = {k: units.si(CONTRACT_UNITS.get(k, "")) for k in entry.get("parameters", {})}
    return entries


def not_confirmed_markdown(doc: dict) -> list[str]:
    """report.md's section on the significant effects that the validation recording cannot judge."""
    if not doc.get("not_confirmed"):
        return []
    lines = ["## Not confirmed", "", "Significant on the training recording but not exercised by the validation "
             "recording, which can therefore neither confirm nor refute them; they are not in the model. A "
             "validation run that reaches them (the same moves and forces) would decide.", ""]
    for c in doc["not_confirmed"]:
        on = f" on axis {c['axis']}" if "axis" in c else ""
        params = ", ".join(f"{k} = {_with_unit(v, c.get('units', {}).get(k, ''))}"
                           for k, v in c.get("parameters", {}).items())
        lines += [f"- {c['effect']}{on} ({params}): {c['evidence_ratio']:.3g} times the 99.9 % null level; "
                  f"{evidence.silent_text(c['not_exercised_by_validation'])}.", ""]
    return lines


def unexplained_entry(remainder: dict) -> dict | None:
    """diagnosis.json's ``unexplained``: where the structure no catalogue effect explains sits and the
    empirical term (or the rejected one); None when nothing significant remains or it was not tested."""
    if not remainder.get("status", "").startswith("unexplained"):
        return None
    has_term = "empirical_term" in remainder or "rejected_term" in remainder
    return {k: v for k, v in remainder.items() if k != "reason" or not has_term}


def unexplained_text(entry: dict) -> str:
    """The unexplained verdict in one line: status, axis, the empirical law and its validation gain."""
    term = entry.get("empirical_term") or entry.get("rejected_term")
    if term is None:
        return (f"{entry['status']} (on axis {entry['axis']}: validation RMS {entry['validation_rms']:.3g}, "
                f"{entry['validation_rms'] / math.hypot(entry['floor_rms'], entry.get('estimation_rms') or 0.0):.3g} "
                f"times what a correct model reaches on this data)")
    law = " + ".join(f"{c:.4g}*{name}" for name, c in term.get("coefficients", {}).items())
    label = "empirical term" if "empirical_term" in entry else "rejected term"
    gain = term.get("validation_gain")
    outcome = (f"validation RMS x{gain:.3g}" if gain is not None and math.isfinite(gain)
               else "its validation free run diverged")
    return f"{entry['status']} ({label} F = {law} on axis {entry['axis']}, {outcome})"


def _validation_change(term: dict, unit: str) -> str:
    """How an empirical term changes the validation RMS; a diverged free run (inf, null in JSON) says so."""
    after, gain = term.get("validation_rms_after"), term.get("validation_gain")
    if after is None or gain is None or not math.isfinite(after):
        return (f"the validation free run with the term diverges (RMS {term['validation_rms_before']:.3g} {unit} "
                "without it)")
    return (f"the validation RMS goes {term['validation_rms_before']:.3g} {unit} -> {after:.3g} {unit} "
            f"(x{gain:.3g})")


def effect_contract(entry: dict, ctx, final) -> dict[str, float]:
    """An equivalent structure's effect parameters in the contract's terms (as for the chosen effect)."""
    effect = VOCABULARY[entry["name"]](ctx)
    values = {**final.fit.values, **entry["parameters"]}
    return {k: float(v) for k, v in effect.contract(values, ctx).items()}


def _above_floor(nominal_rms: float, augmented_rms: float, floor: float) -> dict[str, float]:
    """The validation RMS split into the noise floor and the model error above it [m]: the error of a
    model is sqrt(rms^2 - floor^2) (independent noise adds in power), and ``excess_ratio`` compares the
    augmented with the nominal model without the floor that neither can go below."""
    nominal_excess = math.sqrt(max(nominal_rms ** 2 - floor ** 2, 0.0))
    augmented_excess = math.sqrt(max(augmented_rms ** 2 - floor ** 2, 0.0))
    ratio = augmented_excess / nominal_excess if nominal_excess > 0 else math.nan
    return {"noise_floor_rms": floor, "nominal_excess_rms": nominal_excess,
            "augmented_excess_rms": augmented_excess, "excess_ratio": ratio}


def _markdown(doc: dict, plots: list[str], result: dict, clipped: dict[str, int]) -> str:
    val = doc["validation"]
    units = plant_units(result)
    axis = bundle_units(result["bundle"])
    lines = ["# Mismatch diagnosis", "", f"Bundle: `{result['bundle'].directory}`", ""]
    if result["bundle"].observer is not None:
        lines += [f"Controller unknown: {result['bundle'].observer.describe()}. Validation RMS values are the "
                  "predictor's free run (a prediction error, not a simulation error).", ""]
    if doc["effects"]:
        lines += ["## Missing physics found", ""]
        for e in doc["effects"]:
            params = ", ".join(f"{k} = {_with_unit(v, e['units'].get(k, ''))}" for k, v in e["parameters"].items())
            lines += [f"### {e['name']} ({params})", "", e["explanation"], "", f"Location: {e['location_text']}", ""]
            if e["equivalent_forms"]:
                f = e["equivalent_forms"]
                lines += [f"Equivalent while moving: Coulomb friction Fc = {_with_unit(f['Fc_equivalent'], axis.force)} "
                          f"plus a constant force {_with_unit(f['offset_while_moving'], axis.force)} (the two differ only at "
                          f"rest, where asymmetric friction vanishes and a constant force does not).", ""]
            if e["equivalent_explanations"]:
                lines += ["#### Equivalent explanations", "",
                          "These structures fit within noise on the training and the validation recording:", "",
                          f"| structure | parameters | training cost [-] | validation RMS [{axis.position}] | fitted parameters | "
                          "AIC = cost + 2k [-] |", "|---|---|---|---|---|---|"]
                first = e["equivalent_explanations"][0]
                lines.append(f"| **{e['name']}** (chosen) | {params} | {first['chosen_train_cost']:.6g} | "
                             f"{first['chosen_validation_rms']:.4g} | {first['chosen_fitted_parameters']} | "
                             f"{first['chosen_aic']:.6g} |")
                for q in e["equivalent_explanations"]:
                    text = ", ".join(f"{k} = {_with_unit(v, axis.si(CONTRACT_UNITS.get(k, '')))}"
                                     for k, v in q["parameters"].items())
                    lines.append(f"| {q['name']} | {text} | {q['train_cost']:.6g} | {q['validation_rms']:.4g} | "
                                 f"{q['fitted_parameters']} | {q['aic']:.6g} |")
                lines += ["", f"Rule that picked {e['name']}: {e['selection_rule']}.", ""]
    else:
        lines += no_effect_lines(doc, "improved the fit beyond what a correct model leaves on the same excitation, "
                                      "or none improved the validation fit")
    lines += not_confirmed_markdown(doc) + _unexplained_markdown(doc, axis)
    lines += at_bound_markdown(doc["at_bound"], doc.get("bounds_widened"))
    m = axis.position
    lines += ["## Fit", "", f"| model | validation RMS [{m}] |", "|---|---|",
              f"| nominal, refitted | {val['nominal_rms']:.4g} |", f"| augmented | {val['augmented_rms']:.4g} |", "",
              f"Noise floor (RMS that the fitted model leaves when re-simulated with the estimated encoder noise "
              f"fed back): {val['noise_floor_rms']:.4g} {m}. Model error above it: {val['nominal_excess_rms']:.4g} "
              f"{m} (nominal) -> {val['augmented_excess_rms']:.4g} {m} (augmented).{_estimation_text(doc, m)}", "",
              "## Parameters", "", "| parameter | unit | start | nominal, refitted | augmented, refitted |",
              "|---|---|---|---|---|"]
    start = result["bundle"].start
    for name, value in doc["augmented_parameters"].items():
        nominal = doc["nominal_parameters"].get(name)
        lines.append(f"| {name} | {_unit(name, units) or '-'} | "
                     f"{'' if name not in start else f'{start[name]:.6g}'} | "
                     f"{'' if nominal is None else f'{nominal:.6g}'} | {value:.6g} |")
    lines += ["", "## Candidates tested", "",
              "| round | effect | cost reduction [-] | null 99.9 % [-] | ratio [-] | validation RMS, after/before [-] "
              "| force, after/before [-] | worst quarter, force [-] | seconds [s] |",
              "|---|---|---|---|---|---|---|---|---|"]
    for c in doc["candidates"]:
        lines.append(f"| {c['round']} | {c['effect']} | {c['cost_reduction']:.4g} | {c['null_threshold']:.4g} | "
                     f"{c['evidence_ratio']:.2f} | {_ratio_cell(c, 'validation_rms')} | "
                     f"{_ratio_cell(c, 'validation_force_rms')} | "
                     f"{_number_cell((c.get('stroke_force_ratio') or {}).get('ratio'))} | {c['seconds']} |")
    lines += ["", "Costs are noise-weighted sums of squares (dimensionless); an effect is kept when its cost "
              "reduction exceeds the 99.9 % null level, it lowers the validation RMS of the position or of the "
              "recorded force by at least 10 % without raising the other's by more, and it does not raise the "
              f"recorded force's mean square more than {evidence.STROKE_RATIO:g}x in any quarter of the validation "
              "recording by position (worst quarter). Blank: not validated (not significant, or a simpler form "
              "decided).", "",
              "## Plots", ""]
    for p in plots:
        note = (f" ({clipped[p]} outliers beyond the 1-99 % range widened by {CLIP_WIDEN:g} of its width on each "
                f"side, drawn at the edge)" if p in clipped else "")
        lines += [f"![{p}]({p})", f"{p}{note}", ""]
    lines += [f"Augmented model: `{doc['augmented_model']}`; FMU: `{doc['augmented_fmu']}`.", ""]
    return "\n".join(lines)


def _number_cell(value: float | None) -> str:
    return "" if value is None else f"{value:.3g}"


def _ratio_cell(candidate: dict, field: str) -> str:
    """A candidate's validation figure after over before ("" when it was not validated or has no such channel)."""
    before, after = candidate.get(f"{field}_before"), candidate.get(f"{field}_after")
    if before is None or after is None or not before > 0 or math.isnan(after / before):
        return ""
    return "inf (diverged)" if math.isinf(after) else _number_cell(after / before)


def _estimation_text(doc: dict, m: str) -> str:
    """Where the parameters' estimation error takes up the model error above the floor, say so: the training
    run determines some parameter weakly, which a richer excitation would pin (no missing physics)."""
    val = doc["validation"]
    spread = val.get("estimation_rms")
    if not spread or doc.get("unexplained") or val["augmented_excess_rms"] < val["noise_floor_rms"]:
        return ""
    return (f" The parameters' estimation error on this training recording ({val['estimation_from']}) moves "
            f"the validation run by {spread:.4g} {m} RMS, which takes up that error: the training run determines "
            f"some parameter weakly (see the Parameters table); a training run that excites it more would pin it.")


def no_effect_lines(doc: dict, why: str) -> list[str]:
    """The report section of a diagnosis that named no catalogue effect: "only the nominal parameters were off"
    only when nothing is unexplained; otherwise the nominal structure is kept and the unexplained section says
    what it leaves (never both)."""
    if doc.get("unexplained"):
        return ["## No catalogue effect", "", f"After refitting the nominal parameters, no candidate effect {why}: "
                "the nominal structure is kept, but what it leaves is more than noise (below).", ""]
    if doc.get("not_confirmed"):
        return ["## No confirmed effect", "", f"After refitting the nominal parameters, no candidate effect {why}: "
                "the nominal structure is kept, but a significant effect that the validation recording does not "
                "exercise is not confirmed either way (below).", ""]
    return ["## No missing physics", "", f"After refitting the nominal parameters, no candidate effect {why}: the "
            "nominal structure is kept, only its parameters were off.", ""]


def _unexplained_markdown(doc: dict, units: AxisUnits = AxisUnits()) -> list[str]:
    """The report section of the unexplained verdict, clearly labelled empirical (no lines when absent)."""
    entry = doc.get("unexplained")
    if not entry:
        check = doc.get("residual_check") or {}
        return [f"Remaining structure after the catalogue: {check['status']} ({check.get('reason', '')}).", ""] \
            if check else []
    validated = "empirical_term" in entry
    term = entry.get("empirical_term") or entry.get("rejected_term")
    heading = ["## Unexplained: structure no catalogue effect explains (EMPIRICAL term, not a physical law)", ""]
    if term is None:      # above the floor with no term at all (pipeline.above_floor)
        return heading + [f"Status: **{entry['status']}** on axis `{entry['axis']}`: {entry['reason']}.", ""] \
            + _where_lines(entry, units, "where the validation residual is largest")
    lines = heading + [
             f"Status: **{entry['status']}** on axis `{entry['axis']}`. After the catalogue effects, the force "
             f"residual still holds significant structure: the sparse regression (PySINDy STLSQ over functions of "
             f"position, velocity, acceleration and force) found the terms below; refitted by output error with "
             f"every parameter, they lower the noise-weighted cost by {term['cost_reduction']:.4g}, "
             f"{term['cost_reduction'] / term['null_threshold']:.1f} times the 99.9 % null level, and "
             f"{_validation_change(term, units.position)} (a term is kept below x{VALIDATION_GAIN:g}).", ""]
    lines += ["| term | coefficient | unit |", "|---|---|---|"]
    lines += [f"| {name} | {value:.6g} | {term['units'].get(name, '')} |"
              for name, value in term["coefficients"].items()]
    lines += [""] + _where_lines(entry, units, "the bins where the term acts most" if validated
                                 else "the bins where the force residual the term was fitted to is largest")
    if term.get("absorbed_effects"):
        lines += [f"Catalogue effects the empirical term carries, dropped: {', '.join(term['absorbed_effects'])} "
                  f"(without them the training cost rises by less than their own null threshold and the validation "
                  f"RMS stays within 10 %).", ""]
    if validated:
        lines += [f"Written into the augmented model as `{term['modelica']}` (parameters `empirical_c<k>` in the "
                  f"plant's state coordinates); it reproduces the residual on the recorded range and should not "
                  f"be extrapolated.", ""]
    else:
        lines += ["The term is significant on the training recording but does not improve the validation fit by "
                  "10 %: it is not added to the augmented model (unexplained, no term validated).", ""]
    return lines


def _where_lines(entry: dict, units: AxisUnits, what: str) -> list[str]:
    """One paragraph: the velocity, position and frequency ranges and the time windows of an unexplained
    verdict, in the axis's units."""
    windows = ", ".join(f"{a:.3g}-{b:.3g} s" for a, b in entry["time_windows"][:5]) or "none above 3 noise levels"
    v_lo, v_hi = entry["velocity_range"]
    x_lo, x_hi = entry["position_range"]
    f_lo, f_hi = entry["frequency_band_hz"]
    k_v, speed = units.shown_velocity
    k_x, length = units.shown_position
    return [f"Where: velocity {v_lo * k_v:.3g} to {v_hi * k_v:.3g} {speed}, position {x_lo * k_x:.4g} to "
            f"{x_hi * k_x:.4g} {length} ({what}), {f_lo:.3g}-{f_hi:.3g} Hz "
            f"({100 * POWER_SHARE:.0f} % of its power), time windows {windows}.", ""]


def html_from_markdown(text: str, title: str = "Mismatch diagnosis") -> str:
    """The report's Markdown (headings, paragraphs, pipe tables, images, `code`, **bold**) as one HTML page."""
    import html
    import re

    def inline(s: str) -> str:
        s = html.escape(s)
        s = re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", r'<img src="\2" alt="\1">', s)
        s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
        return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", s)

    out = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:70em;margin:auto}table{border-collapse:collapse}"
           "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}img{max-width:100%}</style></head><body>"]
    rows: list[list[str]] = []

    def flush() -> None:
        if rows:
            head, body = rows[0], [r for r in rows[1:] if not all(set(c) <= set("-: ") for c in r)]
            out.append("<table><tr>" + "".join(f"<th>{inline(c)}</th>" for c in head) + "</tr>"
                       + "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>" for r in body)
                       + "</table>")
            rows.clear()

    for line in text.splitlines():
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
            continue
        flush()
        heading = re.match(r"^(#{1,6}) (.*)", line)
        if heading:
            level = len(heading.group(1))
            out.append(f"<h{level}>{inline(heading.group(2))}</h{level}>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    flush()
    out.append("</body></html>")
    return "\n".join(out) + "\n"


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
    plots, clipped = diagnosis_plots(result, staging)
    doc["plots_clipped_points"] = clipped
    (staging / "diagnosis.json").write_text(json.dumps(_jsonable(doc), indent=2), encoding="utf-8")
    markdown = _markdown(doc, plots, result, clipped)
    (staging / "report.md").write_text(markdown, encoding="utf-8")
    (staging / "report.html").write_text(html_from_markdown(markdown), encoding="utf-8")
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


def write_product(plant: PlantInfo, final: "ModelFit", staging: Path) -> Path:
    """Write the final augmented model into ``staging/augmented_model`` with the MotionTwin library copied
    beside it (self-contained: it loads without the project's library path), and its FMI 2.0 FMU (ME + CS)
    with the fitted start values into ``staging/fmu``; returns the FMU's path relative to ``staging``."""
    folder = staging / "augmented_model"
    write_axes_structure(plant, final.placed, final.fit.values, folder)
    shutil.copytree(MODELICA_DIR / "MotionTwin", folder / "MotionTwin", ignore=shutil.ignore_patterns("__pycache__"))
    model = symbolic.build(frontend.load(folder, AUGMENTED_CLASS))
    known = {v.name for v in model.parameters}
    built = build_fmu(model, staging / "fmu", "2.0",
                      start_values={k: v for k, v in final.fit.values.items() if k in known})
    return built.path.relative_to(staging)


def _effect_entry(bundle: Bundle, final: ModelFit, axis: str, effect: Effect) -> dict:
    info = final.evidence[f"{effect.name}@{axis}"]
    ctx = info["context"]
    params = effect.contract(final.fit.values, ctx)
    k = [a.output for a in bundle.plant.axes].index(axis)
    ts = bundle.controller.sample_time
    location = evidence.locate(info["force_residual"], ctx.v, ctx.x * ctx.position_gain, ts)
    sigma = max(float(np.atleast_1d(info["sigma_q"])[k]), 1e-15)
    previous = info["previous_q"][k]
    location["time_windows"] = evidence.flagged_windows(bundle.train[axis] - previous, bundle.train.time,
                                                        sigma, ts)[:10]
    ratio = info["cost_reduction"] / info["null_threshold"]
    units = bundle_units(bundle, axis)
    text = (f"{effect.explanation} Located on axis {axis}: its inverse-dynamics force residual is "
            f"{info['score']:.3g} times what a correct model leaves with the same encoder noise. Adding the effect "
            f"there lowers the noise-weighted output-error cost by {info['cost_reduction']:.4g}, {ratio:.1f} times "
            f"the 99.9 % bootstrap level, and {evidence.validation_text(info, units, axis)}.")
    return {"name": effect.name, "axis": axis, "parameters": {n: float(v) for n, v in params.items()},
            "units": {n: units.si(CONTRACT_UNITS.get(n, "")) for n in params},
            "location": location, "location_text": location_text(location, axis, units), "explanation": text,
            "equivalent_explanations": info.get("equivalents", []), "selection_rule": info.get("rule", ""),
            "evidence": {n: info[n] for n in ("cost_reduction", "null_threshold", "score", *evidence.VALIDATION_FIELDS,
                                              *NESTED_EVIDENCE) if n in info}}


def report_markdown(doc: dict, bundle: Bundle, plots: list[str] = ()) -> str:
    """report.md of a multi-axis diagnosis: effects by axis, per-axis validation, where it was located."""
    lines = [f"# Mismatch diagnosis: {bundle.plant.class_name}, {len(bundle.plant.axes)} axes", ""]
    if doc["effects"]:
        lines.append("## Effects found")
        for e in doc["effects"]:
            params = ", ".join(f"{k} = {v:.4g} {e['units'].get(k, '')}".rstrip() for k, v in e["parameters"].items())
            lines += ["", f"### {e['name']} on axis {e['axis']}", "", f"Parameters: {params}.", "",
                      e["explanation"], "", e["location_text"]]
    else:
        lines += no_effect_lines(doc, "on the located axes beat the bootstrap null reference and improved "
                                      "validation")
    lines += not_confirmed_markdown(doc) + _unexplained_markdown(doc)
    lines += at_bound_markdown(doc["at_bound"], doc.get("bounds_widened"))
    lines += ["## Validation RMS per axis", "", "| axis | nominal | augmented | noise floor | unit |",
              "|---|---|---|---|---|"]
    for axis, v in doc["validation"]["per_axis"].items():
        unit = bundle_units(bundle, axis).position
        lines.append(f"| {axis} | {v['nominal_rms']:.3g} | {v['augmented_rms']:.3g} | {v['noise_floor_rms']:.3g} | "
                     f"{unit} |")
    lines += ["", "## Location (force residual / noise reference per axis, each round)", ""]
    for entry in doc["location"]:
        lines.append(f"- round {entry['round']}: " + ", ".join(f"{k} {v:.3g}" for k, v in entry["scores"].items()))
    lines += ["", "## Parameters", "", "| parameter | nominal refit | augmented refit |", "|---|---|---|"]
    for name, value in doc["augmented_parameters"].items():
        nominal = doc["nominal_parameters"].get(name)
        lines.append(f"| {name} | {'' if nominal is None else f'{nominal:.6g}'} | {value:.6g} |")
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    lines += ["", f"Augmented Modelica model: `{doc['augmented_model']}` (self-contained: the MotionTwin library "
              f"is copied beside it); its FMU (FMI 2.0, ME + CS, the fitted start values): `{doc['augmented_fmu']}`. "
              f"Runtime {doc['runtime_s']} s.", ""]
    return "\n".join(lines)

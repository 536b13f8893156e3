"""``diagnose``'s stages run in order on one bundle: the plant form and the nominal refit (:mod:`nominal`), where
the data disagrees (:mod:`locate`), the candidate effects screened (:mod:`screen`) and selected against the
bootstrap null and the validation rule (:mod:`select`), what remains unexplained (:mod:`remainder`); then
the augmented model, its FMU and the report are written (:mod:`report`). Units: SI (s, m, N)."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import stats

from motiontwin.fmus.files import move_file
from motiontwin.harness.interrupt import raise_if_terminated, uninterrupted
from motiontwin.ident import outputerror, startvalues
from motiontwin.ident.diagnosis import empirical, locate, noise, report, report_plots
from motiontwin.ident.diagnosis.augmented import AUGMENTED_CLASS, write_structure
from motiontwin.ident.diagnosis.bounds import bounds_widened, structure_at_bound
from motiontwin.ident.diagnosis.axis_units import bundle_units
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.locate import context, force_residual
from motiontwin.ident.diagnosis.nominal import (_divergence_hint, check_plant_form, fit_nominal, fit_nominal_axes,
                                                fit_observer, nominal_free, nominal_start, plant_physics)
from motiontwin.ident.diagnosis.polish import polished
from motiontwin.ident.diagnosis.remainder import EMPIRICAL_EFFECT, explain_remainder, explain_remainder_axes
from motiontwin.ident.diagnosis.nested import simplify_nested, upgrade_nested
from motiontwin.ident.diagnosis.prune import prune
from motiontwin.ident.diagnosis.select import VALIDATION_GAIN, select, widen_search_bounds
from motiontwin.ident.diagnosis.structure import (FLOOR_REPLICATES, LoopCache, ModelFit, _log,
                                                  _nominal_bounds, build_axes, build_structure, estimation_rms,
                                                  floor_rms, floors, sandwich_rms, validate, validate_axes,
                                                  validation_floor, validation_shift)

#: the final validation RMS may exceed the estimated noise floor by this factor before the verdict is "unexplained"
FLOOR_MARGIN = 1.5
#: where the parameters' estimation error is from (diagnosis.json's ``validation.estimation_from``)
REPLICATES, SANDWICH = "its noise replicates refitted", "the fit's HAC sandwich"
#: the parameters' estimation error of one fit is one draw, whose RMS ``FLOOR_REPLICATES`` refits estimate; where
#: one direction dominates (a weakly excited mass) the draw over that estimate follows Student's t with as many
#: degrees of freedom, and the verdict allows its 97.5 % quantile (2.57)
ESTIMATION_QUANTILE = float(stats.t.ppf(0.975, FLOOR_REPLICATES))

#: names of the stages that tests and scripts read from here
__all__ = ["AUGMENTED_CLASS", "VALIDATION_GAIN", "Diagnosis", "_nominal_bounds", "check_plant_form", "run"]


def run(bundle: Bundle, work: Path, progress=None) -> dict:
    """The whole diagnosis in ``work``; returns what the report needs."""
    t0 = time.perf_counter()
    bundle.cache = LoopCache()
    _log(progress, bundle.plant.roles.describe())
    check_plant_form(bundle, work / "check")
    _log(progress, f"every candidate effect's augmented model builds ({time.perf_counter() - t0:.1f} s)")
    bundle.start = nominal_start(bundle, progress)
    nominal, weights = fit_observer(bundle, *fit_nominal(bundle, progress), progress)
    bundle.process_noise = noise.of_bundle(bundle, nominal.fit.values, weights.sigma_q)
    _log(progress, f"process force noise (not predictable from the motion): {bundle.process_noise.describe()}")
    validate(bundle, nominal, work / "v_nominal")
    startvalues.check_free_run(nominal.val_q, bundle.validation["q"], bundle.validation.time,
                               f"the refitted nominal closed loop on {bundle.recording_path('validation')}",
                               {k: v for k, v in nominal.fit.values.items() if k in nominal.loop.free},
                               _divergence_hint(bundle))
    ctx = context(bundle, nominal)
    owned = plant_physics(bundle, nominal, ctx)
    for effect, name in owned.items():
        _log(progress, f"{effect}: not offered, the plant's own {name} carries this force and is refitted")
    final, log, located = select(bundle, nominal, weights, ctx, work / "trials", progress, owned)
    final = prune(bundle, final, weights, work / "prune", progress)
    final = simplify_nested(bundle, final, weights, ctx, work / "simplify", progress)
    final = upgrade_nested(bundle, final, weights, ctx, work / "upgrade", progress)
    final = widen_search_bounds(bundle, final, weights, work / "widen", progress)
    final, remainder = explain_remainder(bundle, final, weights, ctx, work / "remainder", progress)
    final, weights = polished(bundle, final, weights, ctx, work / "polish", progress)
    bundle.process_noise = final_process_noise(bundle, final, weights, progress)
    model_dir = work / "final_model"
    values = dict(final.fit.values)
    if not final.effects:
        values = {"plant." + k: v for k, v in values.items()}
    names = tuple(e.name for e in final.effects)
    bundle.cache.models.pop(names, None)   # the final model at the fitted values (Diagnosis.write writes it again)
    loop, _ = build_structure(bundle, final.effects, values, model_dir, bundle.validation.time.size,
                              with_jacobian=False, min_substeps=final.loop.substeps)
    written = bundle.cache.models[names]
    q_aug, u_aug = outputerror.simulate(loop, bundle.validation, values,
                                        shift=validation_shift(bundle, loop, final.fit))
    bundle.process_noise = noise.within_residual(
        bundle.process_noise, floor_rms(final.loop, bundle.train, final.fit.values, weights.sigma_q),
        floor_rms(final.loop, bundle.train, final.fit.values, weights.sigma_q, bundle.process_noise),
        float(final.fit.rms_q))
    _log(progress, f"process force noise within the final model's training residual: "
                   f"{bundle.process_noise.describe()}")
    floor, force = validation_floors(bundle, final, loop, values, u_aug, weights.sigma_q, progress)
    spread = None      # the parameters' estimation error matters only above the noise floor's margin
    estimation_from = REPLICATES
    unknown_spread = False
    if (np.sqrt(np.mean((bundle.validation["q"] - q_aug) ** 2)) > FLOOR_MARGIN * floor
            or (force is not None and force.rms > FLOOR_MARGIN * force.floor)):
        spread, force_spread = estimation_rms(final.loop, bundle.train, final.fit, final.bounds, loop,
                                              bundle.validation, values, weights, bundle.process_noise)
        if bundle.observer is not None:     # the predictor's replicates miss the real loop's scatter
            spread, force_spread, estimation_from = _with_sandwich(bundle, final, loop, values, spread, force_spread,
                                                                   progress)
        if math.isnan(spread):
            _log(progress, f"validation floor {floor:.4g} from the noise; the parameters' estimation error is not "
                           f"known: the refits of the noise replicates did not move from the fitted values (the "
                           f"cost is too rough there) or most diverged, so the bound counts the noise alone")
            spread, force_spread = 0.0, 0.0
            unknown_spread = True
        else:
            _log(progress, f"validation floor {floor:.4g} from the noise, {spread:.4g} from the parameters' "
                           f"estimation error; force {force_spread:.4g} from it")
        if force is not None:
            force = ForceCheck(force.rms, force.floor, force_spread)
    remainder = above_floor(bundle, remainder, q_aug, floor, weights.sigma_q, progress, spread or 0.0, force,
                            unknown_spread)
    _log(progress, f"diagnosis done in {time.perf_counter() - t0:.1f} s")
    return {"bundle": bundle, "nominal": nominal, "final": final, "weights": weights, "context": ctx,
            "log": log, "augmented_values": values, "q_augmented": q_aug, "u_augmented": u_aug,
            "remainder": remainder, "located": located,
            "augmented_model": written, "validation_floor": floor,
            "estimation_rms": None if unknown_spread else spread, "estimation_unknown": unknown_spread, "force": force,
            "estimation_from": estimation_from,
            "seconds": time.perf_counter() - t0,
            "plant_physics": owned, "process_noise": bundle.process_noise}


def final_process_noise(bundle: Bundle, final: ModelFit, weights: outputerror.Weights,
                        progress=None) -> noise.ProcessNoise:
    """The process noise read again from the final model's force residual, with the effects found in it
    (:func:`noise.estimate` resolved: a slow noise at its level), for the floor the verdict is judged against;
    the nominal model's estimate when that residual has no force gain. Why: the nominal model's residual holds
    the force of the effects not yet found, so its estimate, which drives the selection's nulls and the
    prediction-error refit, stays blind to the slow end of the spectrum, where a slow process noise lies too (on
    the fresh set's parameters-only control it read 0.093 N at 20 ms for 0.064 N white + 0.18 N at 58 ms, the
    floor came out 27 % low and the control was called "unexplained"). Read so before the selection or the
    refit, the slow force a missing effect leaves passed for noise and changed their answers (a real servo's
    load-dependent friction; the audit set's Coulomb + cogging)."""
    inv, gain, input_gain = force_residual(bundle, final)
    if inv is None:
        return bundle.process_noise
    ts = bundle.controller.sample_time
    found = noise.estimate(noise.held_force(inv, input_gain, ts), inv.x, inv.v, inv.a, input_gain,
                           weights.sigma_q / abs(gain), ts, inv.cutoff, resolved=True)
    _log(progress, f"process force noise under the final model ({', '.join(final.names) or 'nominal'}): "
                   f"{found.describe()}")
    return found


def above_floor(bundle: Bundle, remainder: dict, q_final: np.ndarray, floor: float, sigma_q: float,
                progress=None, spread: float = 0.0, force: ForceCheck | None = None,
                unknown_spread: bool = False) -> dict:
    """The last word of a single-axis diagnosis: when neither a catalogue effect nor the empirical stage
    left the final model's validation RMS within what a correct model fitted on this training recording
    leaves (:func:`floor_bound` of the floor from encoder and process noise, :mod:`noise`, and ``spread``, the
    validation RMS of its parameters' estimation error, :func:`structure.estimation_rms`), in the position or, with
    ``force``, in the recorded force (which a loop with integral action leaves where it holds the position),
    the answer is "unexplained, no term validated" with where the validation residual sits, never "only
    parameters were off". ``unknown_spread``: the estimation error could not be estimated (counted as 0, said so)."""
    rec = bundle.validation
    residual = rec["q"] - q_final
    rms = float(np.sqrt(np.mean(residual ** 2)))
    reach = float(np.hypot(floor, spread))
    above = rms > floor_bound(floor, spread)
    force_above = force is not None and force.rms > floor_bound(force.floor, force.spread)
    if remainder.get("status", "").startswith("unexplained") or not (above or force_above):
        return remainder
    ts = bundle.controller.sample_time
    _, v, _ = startvalues.mirror_derivatives(rec["q"], 1 / ts, startvalues.derivative_cutoff(1 / ts))
    where = empirical.locate_remainder(residual, residual, rec.time, v, rec["q"], sigma_q, ts)
    reason = (f"the validation RMS {rms:.4g} is {rms / reach:.3g} times what a correct model fitted on this training "
              f"recording reaches ({reach:.4g}: {floor:.4g} from the encoder and process noise estimated from the "
              + (f"recording; its parameters' estimation error not known (its noise replicates' refits did not move "
                 f"or diverged), the bound allows {FLOOR_MARGIN} times the noise)" if unknown_spread else
                 f"recording, {spread:.4g} from its parameters' estimation error; the bound allows {FLOOR_MARGIN} "
                 f"times the first and {ESTIMATION_QUANTILE:.3g} times the second)"))
    if force is not None:
        reason += (f", that of the recorded force {force.rms:.4g} is {force.rms / force.reach:.3g} times what a "
                   f"correct model reaches there ({force.reach:.4g}: floor {force.floor:.4g}, estimation error "
                   f"{'not known' if unknown_spread else format(force.spread, '.4g')})")
    reason += f"; {remainder.get('reason', 'no catalogue effect or empirical term took it up')}"
    _log(progress, f"unexplained, no term validated: {reason}")
    return {"status": empirical.NOT_VALIDATED, "axis": bundle.plant.output_name, **where,
            "reason": reason, "validation_rms": rms, "floor_rms": floor,
            "estimation_rms": None if unknown_spread else spread,
            **({"validation_force_rms": force.rms, "force_floor_rms": force.floor,
                "force_estimation_rms": None if unknown_spread else force.spread} if force is not None else {})}


def _with_sandwich(bundle: Bundle, final: ModelFit, loop: outputerror.Loop, values: dict[str, float], spread: float,
                   force_spread: float, progress=None) -> tuple[float, float, str]:
    """An unknown controller's estimation error: the larger of the replicates' (``spread``, ``force_spread``) and
    the fit's HAC sandwich's (:func:`structure.sandwich_rms`), in each channel, and where the position's is from.
    On the held-out Coulomb bundle without its controller the replicates gave 1.3e-5 rad where the fitted mass (5 %
    light, as the known controller's fit) costs 7.5e-5 on the validation run, and the verdict called the right
    structure "unexplained"; the sandwich gives 9.8e-5."""
    position, force = sandwich_rms(final.loop, final.fit, final.bounds, loop, bundle.validation, values)
    if math.isnan(position):
        return spread, force_spread, REPLICATES
    _log(progress, f"the parameters' estimation error from the fit's HAC sandwich: {position:.4g} (replicates: "
                   f"{spread:.4g}), force {force:.4g} ({force_spread:.4g}); the predictor's replicates can miss the "
                   f"scatter of the real, unknown loop, so the larger counts")
    return (max(position, spread) if not math.isnan(spread) else position,
            max(force, force_spread) if not math.isnan(force_spread) else force,
            SANDWICH if math.isnan(spread) or position > spread else REPLICATES)


def floor_bound(floor: float, spread: float) -> float:
    """The largest validation RMS a correct model fitted on the training recording leaves, in the channel's
    unit: ``FLOOR_MARGIN`` times the noise floor and ``ESTIMATION_QUANTILE`` times the RMS of the parameters'
    estimation error, in power. Why not a margin on their sum: the noise floor is an average over the whole
    run, the estimation error one draw; on the held-out Coulomb case (inertia weakly excited) the fitted mass
    is 26 % off and leaves 2.0x the estimated RMS of that error, which 1.5x the sum called "unexplained"."""
    return float(np.hypot(FLOOR_MARGIN * floor, ESTIMATION_QUANTILE * spread))


@dataclass(frozen=True)
class ForceCheck:
    """The final model's validation RMS of the recorded force and the floor a correct model leaves there [N]."""

    rms: float
    floor: float
    spread: float = 0.0     # the parameters' estimation error in the force (:func:`structure.estimation_rms`)

    @property
    def reach(self) -> float:
        """What a correct model fitted on the training recording reaches: the floor and the spread in power."""
        return float(np.hypot(self.floor, self.spread))


def validation_floors(bundle: Bundle, final: ModelFit, loop: outputerror.Loop, values: dict[str, float],
                      u_final: np.ndarray, sigma_q: float, progress=None) -> tuple[float, ForceCheck | None]:
    """The validation floor of the position [m] and the force check of the final model (``loop`` at ``values``
    on the validation recording, whose force it simulated as ``u_final``): the floor of the recorded force from
    the same replicates (:func:`structure.floors`, with the force's own measurement noise), bounded as the
    process noise is (:func:`noise.within_residual`): noise cannot leave more force residual than the final model
    leaves on its training recording, so the force floor is scaled by that residual over the training force
    floor when it is below 1. None for an unknown controller (its observer does not simulate the force)."""
    if bundle.observer is not None:
        return validation_floor(loop, bundle, values, sigma_q, process=bundle.process_noise), None
    process = bundle.process_noise
    floor, force_floor = floors(loop, bundle.validation, values, sigma_q, process,
                                force_noise=noise.force_measurement(loop, bundle.validation))
    train_noise = noise.force_measurement(final.loop, bundle.train)
    _, train_floor = floors(final.loop, bundle.train, final.fit.values, sigma_q, process, force_noise=train_noise)
    train_force = outputerror.measured(final.loop, bundle.train, "input")
    train_rms = float(np.sqrt(np.mean((train_force - final.fit.u_sim) ** 2)))
    force_floor *= min(1.0, train_rms / train_floor) if train_floor > 0 else 1.0
    measured = outputerror.measured(loop, bundle.validation, "input")
    force = ForceCheck(float(np.sqrt(np.mean((measured - u_final) ** 2))), force_floor)
    _log(progress, f"validation force RMS {force.rms:.4g}, {force.rms / force.floor:.3g} times its floor "
                   f"{force.floor:.4g} (training: {train_rms:.4g} over {train_floor:.4g})")
    return floor, force


@dataclass
class Diagnosis:
    """The outcome of a diagnosis: the effects found, the refitted parameters and the validation fit.

    ``effects``: names of the catalogue effects added to the nominal model (empty: only its parameters were
    off, or what is missing is unexplained); ``parameters``: every parameter of the augmented model (plant
    ones without the ``plant.`` prefix) [SI]; ``nominal_parameters``: the refitted nominal plant;
    ``validation``: validation RMS of both [m] and the noise floor [m]; ``unexplained``: None, or where a
    significant residual structure no catalogue effect explains sits and the empirical term that explains it
    (``status`` "unexplained", ``empirical_term``) or the one that failed validation ("unexplained, no term
    validated", ``rejected_term``), as in diagnosis.json; ``result``: everything the report uses.
    :meth:`write` writes the report and the FMU."""

    effects: list[str]
    parameters: dict[str, float]
    nominal_parameters: dict[str, float]
    validation: dict[str, float]
    result: dict = field(repr=False)
    unexplained: dict | None = None

    @classmethod
    def from_result(cls, result: dict) -> "Diagnosis":
        strip = {k[len("plant."):] if k.startswith("plant.") else k: float(v)
                 for k, v in result["augmented_values"].items()}
        val_q = result["bundle"].validation["q"]
        augmented = float(np.sqrt(np.mean((val_q - result["q_augmented"]) ** 2)))
        remainder = result.get("remainder") or {}
        unexplained = remainder if remainder.get("status", "").startswith("unexplained") else None
        return cls([e.name for e in result["final"].effects if e.family != EMPIRICAL_EFFECT], strip,
                   {k: float(v) for k, v in result["nominal"].fit.values.items()},
                   {"nominal_rms": float(result["nominal"].val_rms), "augmented_rms": augmented,
                    "noise_floor_rms": float(result["validation_floor"])}, result, unexplained)

    def write(self, folder: str | os.PathLike) -> dict:
        """Write diagnosis.json, validation_prediction.csv, report.md (+ PNGs), the augmented Modelica model
        and its FMU into ``folder`` (staged beside it, then moved in); returns the diagnosis.json document."""
        out = Path(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
        result = self.result
        with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}.work-") as tmp:
            staging = Path(tmp) / "out"
            write_structure(result["bundle"].plant, result["final"].effects, result["augmented_values"],
                            staging / "augmented_model")
            document = report.write_all(result, staging, out)
            _publish(staging, out)
        return document


def _publish(staging: Path, out: Path) -> None:
    """Move every staged file into ``out`` (created if needed), atomically per file (fmus.files.move_file), with
    SIGTERM and Ctrl-C held back until all are in; nothing is moved when a SIGTERM arrived during the analysis
    and a library swallowed its exception (:func:`interrupt.raise_if_terminated`)."""
    raise_if_terminated()
    with uninterrupted():
        out.mkdir(parents=True, exist_ok=True)
        for src in sorted(staging.rglob("*")):
            if src.is_dir():
                continue
            target = out / src.relative_to(staging)
            target.parent.mkdir(parents=True, exist_ok=True)
            move_file(src, target)
    shutil.rmtree(staging, ignore_errors=True)


def run_axes(bundle: Bundle, work: Path, progress=None) -> dict:
    """The whole multi-axis diagnosis in ``work``; returns what the report needs."""
    t0 = time.perf_counter()
    bundle.cache = LoopCache()
    for roles in bundle.plant.axes:
        _log(progress, roles.describe())
    bundle.start = {v.name: float(v.start) for v in bundle.plant.model.parameters} | bundle.plant.parameters
    bundle.nominal_free = nominal_free(bundle)
    nominal, weights = fit_nominal_axes(bundle, work / "nominal", progress)
    bundle.process_noise = locate.process_noise(bundle, nominal.fit.values, weights.sigma_q)
    _log(progress, "process force noise (not predictable from the motion): " + "; ".join(
        f"{a.output} {p.describe()}" for a, p in zip(bundle.plant.axes, bundle.process_noise)))
    validate_axes(bundle, nominal, work / "v_nominal")
    for a in bundle.plant.axes:
        k = [x.output for x in bundle.plant.axes].index(a.output)
        startvalues.check_free_run(nominal.val_q[k], bundle.validation[a.output], bundle.validation.time,
                                   f"the refitted nominal closed loop on {bundle.recording_path('validation')}, "
                                   f"axis {a.output}", {n: nominal.fit.values[n] for n in nominal.loop.free},
                                   _divergence_hint(bundle))
    final, log, located = select(bundle, nominal, weights, None, work / "trials", progress)
    final = prune(bundle, final, weights, work / "prune", progress)
    final = simplify_nested(bundle, final, weights, None, work / "simplify", progress)
    final = upgrade_nested(bundle, final, weights, None, work / "upgrade", progress)
    final = widen_search_bounds(bundle, final, weights, work / "widen", progress)
    final, remainder = explain_remainder_axes(bundle, final, weights, work / "remainder", progress)
    final = with_final_start(bundle, final, weights, work / "v_start", progress)
    if not final.val_axes:
        validate_axes(bundle, final, work / "v_final")
    loop, _ = build_axes(bundle, final.placed, final.fit.values, work / "final", bundle.validation.time.size,
                         with_jacobian=False, min_substeps=final.loop.substeps)
    bundle.process_noise = within_residual_axes(bundle, final, weights, progress)
    floor = validation_floor(loop, bundle, final.fit.values, weights.sigma_q, process=bundle.process_noise)
    remainder = above_floor_axes(bundle, final, loop, remainder, floor, weights, progress)
    _log(progress, f"diagnosis done in {time.perf_counter() - t0:.1f} s")
    return {"bundle": bundle, "nominal": nominal, "final": final, "weights": weights, "log": log,
            "located": located, "remainder": remainder, "validation_floor": floor,
            "process_noise": bundle.process_noise, "seconds": time.perf_counter() - t0}


def within_residual_axes(bundle: Bundle, final: ModelFit, weights: outputerror.Weights,
                         progress=None) -> tuple[noise.ProcessNoise, ...]:
    """Each axis's process noise bounded by the final model's training residual on that axis
    (:func:`noise.within_residual`, both floors from the same replicates of all axes)."""
    process = bundle.process_noise
    if not noise.present(process):
        return process
    encoder = np.atleast_1d(floor_rms(final.loop, bundle.train, final.fit.values, weights.sigma_q))
    with_process = np.atleast_1d(floor_rms(final.loop, bundle.train, final.fit.values, weights.sigma_q, process))
    residual = [float(np.sqrt(np.mean((bundle.train[a.output] - final.fit.q_sim[k]) ** 2)))
                for k, a in enumerate(bundle.plant.axes)]
    bounded = tuple(noise.within_residual(p, e, w, r) for p, e, w, r in zip(process, encoder, with_process, residual))
    _log(progress, "process force noise within the final model's training residual: " + "; ".join(
        f"{a.output} {p.describe()}" for a, p in zip(bundle.plant.axes, bounded)))
    return bounded


def with_final_start(bundle: Bundle, final: ModelFit, weights: outputerror.Weights, folder: Path,
                     progress=None) -> ModelFit:
    """Several axes: the final structure refitted from the controller start that the final plant and the
    training run put (:func:`outputerror.start_shift` from the relation's start every fit held, the
    plant then refitted with it), kept when the training cost falls. The relation alone fixes an integrator's
    start only to the force noise over the run; in a velocity loop that is a constant position offset (on the
    two-axis bundle of ``tests/test_diagnosis_start_state.py``, q1 1.6x its floor before, 1.12x after)."""
    if bundle.observer is not None or final.fit.shift is None:
        return final
    shift = outputerror.start_shift(final.loop, bundle.train, final.fit.values, weights, start=final.fit.shift)
    if shift is None:
        return final
    result = outputerror.fit(final.loop, bundle.train, weights, final.bounds, start=final.fit.values, max_nfev=15,
                             shift=shift)
    if not result.cost < final.fit.cost:
        return final
    _log(progress, f"controller start re-estimated with the final plant: training cost {final.fit.cost:.4g} -> "
                   f"{result.cost:.4g}")
    refitted = dataclasses.replace(final, loop=final.loop.with_values(result.values), fit=result)
    validate_axes(bundle, refitted, folder)
    return refitted


def above_floor_axes(bundle: Bundle, final: ModelFit, loop: outputerror.Loop, remainder: dict,
                     floor: np.ndarray, weights: outputerror.Weights, progress=None) -> dict:
    """:func:`above_floor` for several axes, on each axis's position: when an axis's final validation RMS is
    above what a correct model fitted on this training recording leaves there (:func:`floor_bound` of its
    noise floor, encoder noise fed back, and its parameters' estimation error, :func:`structure.estimation_rms`,
    computed only when some axis is above ``FLOOR_MARGIN`` times its floor), the answer is "unexplained, no term
    validated" on the axis farthest above, with where its residual sits, never "none"."""
    if remainder.get("status", "").startswith("unexplained"):
        return remainder
    axes = [a.output for a in bundle.plant.axes]
    floor = np.broadcast_to(np.asarray(floor, float), (len(axes),))
    rms = np.array([final.val_axes[a] for a in axes])
    if not np.any(rms > FLOOR_MARGIN * floor):
        return remainder
    spread, _ = estimation_rms(final.loop, bundle.train, final.fit, final.bounds, loop, bundle.validation,
                               final.fit.values, weights, bundle.process_noise)
    unknown = bool(np.any(np.isnan(spread)))
    spread = np.where(np.isnan(spread), 0.0, spread)
    bound = np.array([floor_bound(f, e) for f, e in zip(floor, spread)])
    _log(progress, "validation floors per axis: " + ", ".join(
        f"{a} {r:.4g} over noise {f:.4g} and estimation {'not known' if unknown else format(e, '.4g')}"
        for a, r, f, e in zip(axes, rms, floor, spread)))
    if not np.any(rms > bound):
        return remainder
    k = int(np.argmax(np.where(rms > bound, rms / np.hypot(floor, spread), -np.inf)))   # the farthest of those above
    axis, rec, ts = axes[k], bundle.validation, bundle.controller.sample_time
    residual = rec[axis] - final.val_q[k]
    _, v, _ = startvalues.mirror_derivatives(rec[axis], 1 / ts, startvalues.derivative_cutoff(1 / ts))
    sigma = float(np.broadcast_to(np.asarray(weights.sigma_q, float), (len(axes),))[k])
    where = empirical.locate_remainder(residual, residual, rec.time, v, rec[axis], sigma, ts)
    reach = float(np.hypot(floor[k], spread[k]))
    reason = (f"the validation RMS of {axis} {rms[k]:.4g} is {rms[k] / reach:.3g} times what a correct model fitted "
              f"on this training recording reaches there ({reach:.4g}: {floor[k]:.4g} from the "
              f"{'encoder and process noise' if noise.present(bundle.process_noise) else 'encoder noise'}, "
              + (f"its parameters' estimation error not known; the bound allows {FLOOR_MARGIN} times the noise)"
                 if unknown else f"{spread[k]:.4g} from its parameters' estimation error; the bound allows "
                 f"{FLOOR_MARGIN} times the first and {ESTIMATION_QUANTILE:.3g} times the second)")
              + f"; {remainder.get('reason', 'no catalogue effect or empirical term took it up')}")
    _log(progress, f"unexplained, no term validated: {reason}")
    return {"status": empirical.NOT_VALIDATED, "axis": axis, **where, "reason": reason,
            "validation_rms": float(rms[k]), "floor_rms": float(floor[k]),
            "estimation_rms": None if unknown else float(spread[k])}


@dataclass
class MultiAxisDiagnosis:
    """The outcome of a multi-axis diagnosis (the fields of :class:`Diagnosis`, plus ``axes``:
    the axis of each effect, and ``validation["per_axis"]``)."""

    effects: list[str]
    axes: list[str]
    parameters: dict[str, float]
    nominal_parameters: dict[str, float]
    validation: dict
    result: dict = field(repr=False)

    @classmethod
    def from_result(cls, result: dict) -> "MultiAxisDiagnosis":
        bundle, nominal, final = result["bundle"], result["nominal"], result["final"]
        floor = np.atleast_1d(result["validation_floor"])
        per_axis = {a.output: {"nominal_rms": nominal.val_axes[a.output], "augmented_rms": final.val_axes[a.output],
                               "noise_floor_rms": float(floor[k] if floor.size > 1 else floor[0])}
                    for k, a in enumerate(bundle.plant.axes)}
        rec = bundle.validation

        def overall(q: np.ndarray) -> float:
            err = np.array([rec[a.output] - q[k] for k, a in enumerate(bundle.plant.axes)])
            return float(np.sqrt(np.mean(err ** 2)))

        validation = {"nominal_rms": overall(nominal.val_q), "augmented_rms": overall(final.val_q),
                      "noise_floor_rms": float(np.sqrt(np.mean(floor ** 2))), "per_axis": per_axis}
        named = [(axis, e) for axis, e in final.placed if e.family != EMPIRICAL_EFFECT]
        return cls([e.name for _, e in named], [axis for axis, _ in named],
                   report._strip(final.fit.values), report._strip(nominal.fit.values), validation, result)

    def document(self, out: Path) -> dict:
        """diagnosis.json's content."""
        result = self.result
        bundle, final = result["bundle"], result["final"]
        entries = [report._effect_entry(bundle, final, axis, e) for axis, e in final.placed
                   if e.family != EMPIRICAL_EFFECT]
        remainder = result["remainder"]
        return report._jsonable({
            "effects": entries, "unexplained": report.unexplained_entry(remainder),
            "not_confirmed": report.not_confirmed(result["log"], {(e.name, a) for a, e in final.placed}, bundle),
            "residual_check": {k: remainder[k] for k in ("status", "reason") if k in remainder},
            "validation": self.validation, "nominal_parameters": self.nominal_parameters,
            "augmented_parameters": self.parameters,
            "augmented_model": str(out / "augmented_model" / f"{AUGMENTED_CLASS}.mo"), "augmented_fmu": None,
            "noise": {"sigma_q": dict(zip([a.output for a in bundle.plant.axes],
                                          np.atleast_1d(result["weights"].sigma_q).tolist())),
                      "sigma_u": dict(zip([a.output for a in bundle.plant.axes],
                                          np.atleast_1d(result["weights"].sigma_u).tolist())),
                      "process": ({a.output: p.as_dict() for a, p in zip(bundle.plant.axes, result["process_noise"])}
                                  if result.get("process_noise") is not None else None)},
            "location": result["located"], "candidates": result["log"],
            "nominal_free": list(bundle.nominal_free[0]), "runtime_s": round(result["seconds"], 2),
            "at_bound": structure_at_bound(final), "bounds_widened": bounds_widened(final),
            "plant_roles": {a.output: a.as_dict() for a in bundle.plant.axes},
            "units": {a.output: bundle_units(bundle, a.output).as_dict() for a in bundle.plant.axes}})

    def write(self, folder: str | os.PathLike) -> dict:
        """Write diagnosis.json, validation_prediction.csv, report.md/html and the augmented Modelica model
        into ``folder`` (staged beside it, then moved in); returns the diagnosis.json document."""
        out = Path(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
        result = self.result
        bundle = result["bundle"]
        doc = self.document(out)
        with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}.work-") as tmp:
            staging = Path(tmp) / "out"
            doc["augmented_fmu"] = str(out / report.write_product(bundle.plant, result["final"], staging))
            rec = bundle.validation
            names = [a.output for a in bundle.plant.axes]
            table = np.column_stack([rec.time] + [np.column_stack([rec[n], result["nominal"].val_q[k],
                                                                   result["final"].val_q[k]])
                                                  for k, n in enumerate(names)])
            header = ",".join(["time"] + [f"{n}_{kind}" for n in names for kind in ("measured", "nominal",
                                                                                    "augmented")])
            np.savetxt(staging / "validation_prediction.csv", table, delimiter=",", fmt="%.17g", header=header,
                       comments="")
            (staging / "diagnosis.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")
            markdown = report.report_markdown(doc, bundle, report_plots.axis_plots(result, staging))
            (staging / "report.md").write_text(markdown, encoding="utf-8")
            (staging / "report.html").write_text(report.html_from_markdown(markdown), encoding="utf-8")
            _publish(staging, out)
        return doc

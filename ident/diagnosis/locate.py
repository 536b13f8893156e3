"""Where the data disagrees with the refitted nominal model: the recorded ranges and the inverse-dynamics
force residual in the plant's state coordinates (:class:`effects.Context`) that the candidates start from.
Units: SI (s, m, N)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from motiontwin.fmus import symbolic
from motiontwin.harness.recording import Recording
from motiontwin.ident import outputerror, startvalues
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import axis_kinematics, evidence, noise
from motiontwin.ident.diagnosis.bundle import Bundle
from motiontwin.ident.diagnosis.plant_roles import output_map
from motiontwin.ident.diagnosis.structure import ModelFit


def _in_state_coordinates(rec: Recording, gain: float, offset: float) -> Recording:
    """``rec`` with the measured q replaced by the plant's position state (q - offset)/gain."""
    return Recording(rec.time, {**rec.columns, "q": (rec["q"] - offset) / gain}, rec.units, rec.meta)


def context(bundle: Bundle, nominal: ModelFit) -> effect_models.Context:
    """Recorded ranges and inverse-dynamics signals in the plant's state coordinates."""
    ts = bundle.controller.sample_time
    plant = bundle.plant
    gain, offset = output_map(plant.model, plant.roles, nominal.fit.values)
    rec = _in_state_coordinates(bundle.train, gain, offset)
    inv = evidence.inverse_dynamics(rec, plant.model, nominal.fit.values, plant.position_state, plant.velocity_state,
                                    ts, _input_index(bundle))
    q = np.concatenate([rec["q"], _in_state_coordinates(bundle.validation, gain, offset)["q"]])
    v = inv.v if inv else np.gradient(rec["q"], ts)
    mass = _mass_equivalent(bundle, nominal.fit.values)
    ctx = effect_models.Context(ts, float(q.min()), float(q.max()), float(np.max(np.abs(v))) or 1e-3, mass,
                     position_gain=gain, u=bundle.train["u"],
                     duration=float(bundle.train.time[-1] - bundle.train.time[0]),
                     pole_pitch=_pitch_in_state_coordinates(plant.pole_pitch, gain))
    if inv is not None:
        ctx.x, ctx.v, ctx.a, ctx.force, ctx.udot = inv.x, inv.v, inv.a, inv.force, inv.udot
    ctx.resonance_guess = evidence.resonance_guesses(bundle.train["q"] - nominal.fit.q_sim, ts)
    ctx.q_residual = (bundle.train["q"] - nominal.fit.q_sim) / gain
    return ctx


def _pitch_in_state_coordinates(pole_pitch: float | None, gain: float) -> float | None:
    """``plant.pole_pitch`` [m of the measured output] in units of the plant's position state."""
    return None if pole_pitch is None else pole_pitch / gain


def _mass_equivalent(bundle: Bundle, values: dict[str, float]) -> float:
    return evidence.mass_equivalent(bundle.plant.model, values, bundle.plant.velocity_state, _input_index(bundle))


def _input_index(bundle: Bundle) -> int:
    return [v.name for v in bundle.plant.model.inputs].index(bundle.plant.input_name)


LOCATE_REPLICATES = 2       # noise re-simulations for each axis's reference force-residual level


def _acceleration_map(model: symbolic.SymbolicModel, bundle: Bundle) -> ca.Function:
    """(x, u, p) -> (the axes' accelerations: velocity-state derivatives, or the second time derivative of an
    expression axis's output; their Jacobian w.r.t. the axes' inputs)."""
    inputs = [v.name for v in model.inputs]
    k_u = [inputs.index(a.input) for a in bundle.plant.axes]
    acc = ca.vertcat(*[axis_kinematics.axis_acceleration(model, a) for a in bundle.plant.axes])
    u_axes = ca.vertcat(*[model.u[k] for k in k_u])
    return ca.Function("acc", [model.x, model.u, model.p], [acc, ca.jacobian(acc, model.u)[:, k_u]
                                                               if u_axes.numel() else acc])


def _axis_motion(bundle: Bundle, rec: Recording, values: dict[str, float],
                 fc: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Filtered position, velocity, acceleration (in axis coordinates: the state's, or an expression axis's
    output) and force of every axis (each axes x samples)."""
    fs = 1 / bundle.controller.sample_time
    fc = fc or startvalues.derivative_cutoff(fs)
    motion, forces = [], []
    for a in bundle.plant.axes:
        gain, offset = output_map(bundle.plant.model, a, values)
        motion.append(startvalues.mirror_derivatives((rec[a.output] - offset) / gain, fs, fc))
        forces.append(startvalues.mirror_derivatives(rec[a.input], fs, fc)[0])
    pos, vel, acc = (np.array([m[i] for m in motion]) for i in range(3))
    return pos, vel, acc, np.array(forces)


def _states_from(bundle: Bundle, rec: Recording, values: dict[str, float],
                 fc: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plant state trajectory (positions and velocities from the filtered outputs, other states at their
    start; with expression axes the states whose outputs and rates those are, :mod:`axis_kinematics`),
    accelerations and filtered forces of every axis, in axis coordinates."""
    model = bundle.plant.model
    names = [s.name for s in model.states]
    p = np.array([values[v.name] for v in model.parameters])
    pos, vel, acc, forces = _axis_motion(bundle, rec, values, fc)
    axes = bundle.plant.axes
    if any(a.expression for a in axes):
        maps = np.array([output_map(model, a, values) for a in axes])
        x = axis_kinematics.states_from_outputs(model, axes, p, pos * maps[:, :1] + maps[:, 1:], vel * maps[:, :1])
        return x, acc, forces
    x0 = np.array(ca.Function("x0", [model.p], [model.x0()])(p)).ravel()
    x = np.tile(x0[:, None], (1, rec.time.size))
    for k, a in enumerate(axes):
        x[names.index(a.position)], x[names.index(a.velocity)] = pos[k], vel[k]
    return x, acc, forces


def _needed_force(model: symbolic.SymbolicModel, bundle: Bundle, values: dict[str, float], x: np.ndarray,
                  acc: np.ndarray) -> np.ndarray:
    """Force each axis needs for the motion (x, acc) under the model at ``values`` (axes x samples)."""
    fn = _acceleration_map(model, bundle)
    p = np.array([values[v.name] for v in model.parameters])
    u = np.zeros((model.u.numel(), x.shape[1]))
    a0, gain = fn.map(x.shape[1])(x, u, p)
    n = len(bundle.plant.axes)
    a0 = np.array(a0)
    gain = np.array(gain).reshape(n, x.shape[1], n).transpose(1, 0, 2)   # map: blocks side by side
    return np.linalg.solve(gain, (acc - a0).T[:, :, None])[:, :, 0].T


def _plant_values(bundle: Bundle, values: dict[str, float]) -> dict[str, float]:
    """Every plant parameter by its own name: from ``values`` (plain or ``plant.``-prefixed), else its start."""
    plain = {k[len("plant."):] if k.startswith("plant.") else k: v for k, v in values.items()}
    return {v.name: plain.get(v.name, float(v.start)) for v in bundle.plant.model.parameters}


def process_noise(bundle: Bundle, values: dict[str, float], sigma_q: np.ndarray) -> tuple[noise.ProcessNoise, ...]:
    """The process force noise of every axis of a multi-axis bundle's training recording under the refitted
    nominal plant (``values``): :func:`noise.estimate` of each axis's inverse-dynamics force residual, in its axis
    coordinates, with the force held over each sample (each axis's recorded force averaged over the sample and
    the one before it, :func:`evidence.held_mean`, the acceleration the central second difference of the filtered
    position, :func:`evidence.central_acceleration`, as :func:`noise.held_force` does); ``sigma_q``: each axis's
    encoder noise in its measured unit."""
    model = bundle.plant.model
    plain = _plant_values(bundle, values)
    held = {a.input: evidence.held_mean(bundle.train[a.input]) for a in bundle.plant.axes}
    columns = {**bundle.train.columns, **held}
    rec = Recording(bundle.train.time, columns, bundle.train.units, bundle.train.meta)
    ts = bundle.controller.sample_time
    fc = startvalues.derivative_cutoff(1 / ts)
    x, acc, forces = _states_from(bundle, rec, plain, fc)
    pos, vel, _, _ = _axis_motion(bundle, rec, plain, fc)
    residual = forces - _needed_force(model, bundle, plain, x, evidence.central_acceleration(pos, acc, ts))
    p = np.array([plain[v.name] for v in model.parameters])
    _, g = _acceleration_map(model, bundle)(x[:, 0], np.zeros(model.u.numel()), p)
    masses = np.diag(np.linalg.inv(np.array(g)))
    sigma = np.broadcast_to(np.asarray(sigma_q, float), (len(bundle.plant.axes),))
    out = []
    for k, a in enumerate(bundle.plant.axes):
        gain, _ = output_map(model, a, plain)
        out.append(noise.estimate(residual[k], pos[k], vel[k], acc[k], 1 / masses[k], sigma[k] / abs(gain), ts, fc))
    return tuple(out)


def force_residual(bundle: Bundle, final: ModelFit, rec: Recording | None = None,
                   states: np.ndarray | None = None) -> tuple[evidence.InverseDynamics | None, float, float]:
    """One axis: the force residual of ``final`` on ``rec`` (default: the training recording; inverse dynamics of
    the augmented model itself, on the measured motion, the force held over each sample), the plant's output gain
    (position = gain * state + offset) and the model's input gain d(acceleration)/d(force) [1/kg]. The states a
    measurement does not give (delay, load, bristle, drift states) are ``states`` (default: the model's free run on
    the training recording, :func:`free_run_states`). None for the residual when the acceleration does not respond
    to the input."""
    plant = bundle.plant
    if final.effects:
        model, prefix = bundle.cache.models[tuple(final.names)], "plant."
    else:
        model, prefix = plant.model, ""
    values = {v.name: float(v.start) for v in model.parameters} | final.fit.values
    gain, offset = output_map(plant.model, plant.roles, {k[len(prefix):]: v for k, v in values.items()
                                                          if k.startswith(prefix)})
    driven = [v.name for v in model.inputs].index("u" if final.effects else plant.input_name)
    inv = evidence.inverse_dynamics(_in_state_coordinates(bundle.train if rec is None else rec, gain, offset), model,
                                    values, prefix + plant.position_state, prefix + plant.velocity_state,
                                    bundle.controller.sample_time, driven, held_input=True,
                                    states=free_run_states(bundle, final, model) if states is None else states)
    if inv is None:
        return None, gain, math.nan
    return inv, gain, 1 / evidence.mass_equivalent(model, values, prefix + plant.velocity_state, driven)


def free_run_states(bundle: Bundle, final: ModelFit, model: symbolic.SymbolicModel) -> np.ndarray | None:
    """The state trajectory of the final model's free run on the training recording, rows in ``model.states``
    order; None for a two-state model (the measured position and velocity are all its states)."""
    if model.x.numel() == 2:
        return None
    run = outputerror.simulate_states(final.loop, bundle.train, final.fit.values, final.fit.initial)
    rows = {s.name: row for s, row in zip(final.loop.model.states, run)}
    return np.array([rows[s.name] for s in model.states])


def axis_score(bundle: Bundle, current: ModelFit, weights: outputerror.Weights, seed: int) -> float:
    """One axis, as :func:`locate` scores each of several: the RMS of the force residual of ``current`` on the
    training recording beyond the one its own noise-free free run leaves through the same filters, over the level
    its free runs with white encoder noise of the estimated level leave (``LOCATE_REPLICATES``); infinite when the
    model's acceleration does not respond to its force (no residual to score)."""
    rec, sig = bundle.train, current.loop.signals
    model = bundle.cache.models[tuple(current.names)] if current.effects else bundle.plant.model
    states = free_run_states(bundle, current, model)

    def residual(encoder: np.ndarray | None) -> np.ndarray | None:
        q, u = outputerror.simulate(current.loop, rec, current.fit.values, noise=encoder, shift=current.fit.shift)
        columns = {**rec.columns, sig.output: q + (0.0 if encoder is None else encoder), sig.input: u}
        inv = force_residual(bundle, current, Recording(rec.time, columns, rec.units, rec.meta), states)[0]
        return None if inv is None else inv.force

    own, data = residual(None), force_residual(bundle, current, rec, states)[0]
    if own is None or data is None:
        return math.inf
    rng = np.random.default_rng(seed)
    reference = np.mean([np.mean((residual(rng.normal(0.0, weights.sigma_q, rec.time.size)) - own) ** 2)
                         for _ in range(LOCATE_REPLICATES)])
    return float(np.sqrt(np.mean((data.force - own) ** 2) / reference))


@dataclass
class AxisEvidence:
    """The located residual of one axis: the force residual [N] and its reference level from noise."""

    axis: str
    force: np.ndarray
    score: float          # RMS of the force residual / RMS a correct model leaves with the same noise
    context: effect_models.Context


def force_residuals(bundle: Bundle, rec: Recording, values: dict[str, float]) -> np.ndarray:
    """Per-axis inverse-dynamics force residual u_k - (force the nominal model needs) [N], axes x samples."""
    plain = _plant_values(bundle, values)
    x, acc, forces = _states_from(bundle, rec, plain)
    return forces - _needed_force(bundle.plant.model, bundle, plain, x, acc)


def locate(bundle: Bundle, current: ModelFit, weights: outputerror.Weights, seed: int) -> list[AxisEvidence]:
    """Every axis's force residual beyond the one the fitted model's own noise-free free run leaves through the
    same filters (the derivative filter's error on a fast excitation, common to model and data), and its
    ratio to the level that the fitted model re-simulated with white encoder noise leaves (same filters,
    same noise level per axis), best first."""
    rec = bundle.train

    def simulated(noise: np.ndarray | None) -> np.ndarray:
        q, u = outputerror.simulate(current.loop, rec, current.fit.values, noise=noise, shift=current.fit.shift)
        columns = dict(rec.columns)
        for k, a in enumerate(bundle.plant.axes):
            columns[a.output], columns[a.input] = q[k] + (0.0 if noise is None else noise[k]), u[k]
        return force_residuals(bundle, Recording(rec.time, columns, rec.units, rec.meta), current.fit.values)

    model_own = simulated(None)
    residual = force_residuals(bundle, rec, current.fit.values) - model_own
    rng = np.random.default_rng(seed)
    reference = np.zeros(len(bundle.plant.axes))
    sigma = np.reshape(np.asarray(weights.sigma_q, float), (-1, 1))
    for _ in range(LOCATE_REPLICATES):
        noise = rng.normal(0.0, 1.0, residual.shape) * sigma
        reference += np.mean((simulated(noise) - model_own) ** 2, axis=1)
    reference = np.sqrt(reference / LOCATE_REPLICATES)
    found = []
    for k, a in enumerate(bundle.plant.axes):
        score = float(np.sqrt(np.mean(residual[k] ** 2)) / max(reference[k], 1e-300))
        found.append(AxisEvidence(a.output, residual[k], score, axis_context(bundle, current, k, residual[k])))
    return sorted(found, key=lambda e: -e.score)


def axis_context(bundle: Bundle, current: ModelFit, k: int, force: np.ndarray) -> effect_models.Context:
    """Recorded ranges and inverse-dynamics signals of axis ``k`` in its state coordinates."""
    ts = bundle.controller.sample_time
    roles = bundle.plant.axes[k]
    model = bundle.plant.model
    plain = {v.name: current.fit.values.get("plant." + v.name, float(v.start)) for v in model.parameters}
    gain, offset = output_map(model, roles, plain)
    x, acc, forces = _states_from(bundle, bundle.train, plain)
    pos, vel = (m[k] for m in _axis_motion(bundle, bundle.train, plain)[:2])
    q_all = (np.concatenate([bundle.train[roles.output], bundle.validation[roles.output]]) - offset) / gain
    fn = _acceleration_map(model, bundle)
    p = np.array([plain[v.name] for v in model.parameters])
    _, g = fn(x[:, 0], np.zeros(model.u.numel()), p)
    mass = float(np.linalg.inv(np.array(g))[k, k])
    ctx = effect_models.Context(ts, float(q_all.min()), float(q_all.max()), float(np.max(np.abs(vel))) or 1e-3,
                                mass, position_gain=gain, u=bundle.train[roles.input],
                                duration=float(bundle.train.time[-1] - bundle.train.time[0]),
                                pole_pitch=_pitch_in_state_coordinates(bundle.plant.pitch_of(roles.output), gain))
    ctx.x, ctx.v, ctx.a, ctx.force = pos, vel, acc[k], force
    ctx.udot = np.gradient(forces[k], ts)
    q_sim = current.fit.q_sim[k]
    ctx.resonance_guess = evidence.resonance_guesses(bundle.train[roles.output] - q_sim, ts)
    return ctx

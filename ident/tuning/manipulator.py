"""Per-actuator tuning of the coupled Cheung & Hung 4-DOF manipulator from its FMU linearised at several poses.

Why: the paper designs each actuator's controller on the worst-case frequency response over actuator
positions. Here the CheungManipulator FMU (rigid coupled dynamics, Table 1) is linearised through its
directional derivatives (``harness.linearize``) at poses along the workspace diagonal; the diagonal channel
u_i -> q_i (the other actuator forces held) is the low-frequency model L_i(s) of eq. (7) at that pose, and it
is multiplied by the flexible-mode factor H(s) of eq. (8) (the CheungJoint resonance pair, which the rigid
FMU lacks) unless ``rigid``. Each actuator's controller is tuned on all its poses at once
(``ident.tuning.tune``: the worst case over poses is what the constraints bind), and the four designs together
are checked on the coupled MIMO linearisation (decentralised control, all interactions kept), with and
without gravity: the closed-loop spectral radius must stay below 1 at every pose.

Gravity: at rest the rigid model's gravity term gives a small negative stiffness (open-loop poles near
+0.5 rad/s), which eq. (7) does not model and the margins of eqs. (14)-(17) do not admit; the per-actuator
channels are therefore linearised with g = 0 and gravity enters only the MIMO closed-loop check.

Units: SI (m, N, s, rad); frequencies in Hz.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import control
import numpy as np

from motiontwin.harness.kinematics import CHEUNG, CHEUNG_START_POSE, cheung_in_range, cheung_inverse
from motiontwin.ident.frf import JointModel
from motiontwin.ident.tuning import TuningError, TuningResult, TuningSpec, controller_system, tune

__all__ = ["MANIPULATOR_CLASS", "ACTUATORS", "POSE_SEGMENT", "workspace_poses", "linearize_poses", "actuator_channel",
           "flexible_mode", "decentralised_radius", "plant_document", "ManipulatorDesign", "tune_manipulator"]

MANIPULATOR_CLASS = "MotionTwin.Plants.CheungManipulator"
ACTUATORS = ("d1", "d3", "d5", "d7")
_INPUTS = ("u1", "u3", "u5", "u7")
_OUTPUTS = ("q1", "q3", "q5", "q7")


#: Ends of the pose segment, offsets from the paper's start pose [m, m, m, rad]: d1, d7 run from 60 to 99 mm
#: of their 59.5..99.5 mm range and d3, d5 from 151 to 125 mm (the workspace is asymmetric about the start).
POSE_SEGMENT = ((-0.007, -0.007, -0.001, 0.0), (0.004, 0.004, 0.0005, 0.0))


def workspace_poses(count: int, segment: Sequence[Sequence[float]] = POSE_SEGMENT,
                    centre: Sequence[float] = tuple(CHEUNG_START_POSE)) -> np.ndarray:
    """``count`` poses [x, y, z, theta] evenly on the segment centre + segment[0] .. centre + segment[1];
    raises TuningError naming the pose whose actuators leave the Table 1 ranges."""
    if count < 1:
        raise TuningError(f"--poses {count}: give at least one pose")
    lo, hi = (np.asarray(centre, dtype=float) + np.asarray(e, dtype=float) for e in segment)
    poses = lo + np.outer(np.linspace(0, 1, count) if count > 1 else [0.5], hi - lo)
    for k, pose in enumerate(poses):
        with np.errstate(invalid="ignore"):
            d = cheung_inverse(pose)
        if not np.all(np.isfinite(d)) or not cheung_in_range(d):
            raise TuningError(f"pose {k} {np.round(pose, 5).tolist()}: actuator positions {np.round(d, 5).tolist()} m "
                              f"outside the Table 1 ranges {CHEUNG.d_min} .. {CHEUNG.d_max}")
    return poses


def linearize_poses(fmu: str | Path, poses: np.ndarray, gravity: bool = False) -> list[control.StateSpace]:
    """The FMU's 4x4 linearisation u -> q (8 states) at rest at each pose; g = 0 unless ``gravity``."""
    from motiontwin.harness.linearize import linearize

    out = []
    for pose in poses:
        start = dict(zip(ACTUATORS, (float(d) for d in cheung_inverse(pose))))
        if not gravity:
            start["g"] = 0.0
        out.append(linearize(fmu, list(_INPUTS), list(_OUTPUTS), start))
    return out


def actuator_channel(mimo: control.StateSpace, index: int, where: str) -> control.TransferFunction:
    """Minimal diagonal channel u_i -> q_i: the other joints' position integrators, uncontrollable or
    unobservable from this channel, are cancelled (python-control ``minreal`` on the transfer function)."""
    tf = control.minreal(control.tf(mimo[index, index]), tol=1e-7, verbose=False)
    num, den = (np.asarray(c, dtype=float) for c in (tf.num[0][0], tf.den[0][0]))
    num = np.trim_zeros(np.where(np.abs(num) < 1e-9 * np.max(np.abs(num)), 0.0, num), "f")
    if num.size == 0:
        raise TuningError(f"{where}: zero gain from u to q (not identifiable)")
    return control.tf(num, den)


def flexible_mode(model: JointModel) -> control.TransferFunction:
    """H(s) of eq. (8) (unit DC gain) from the resonance/antiresonance pairs of ``model``."""
    s = control.tf("s")
    h = control.tf(1, 1)
    for (w, z), (wb, zb) in zip(model.resonances, model.antiresonances):
        h = h * (w ** 2 / wb ** 2) * (s ** 2 + 2 * zb * wb * s + wb ** 2) / (s ** 2 + 2 * z * w * s + w ** 2)
    return h


def decentralised_radius(parameters: Sequence[dict[str, float]], mimo: control.StateSpace,
                         delay_samples: int = 1, flexible: control.TransferFunction | None = None) -> float:
    """Spectral radius of the coupled discrete closed loop: four controllers (block diagonal), the computation
    delay and the ZOH-sampled 4x4 plant (times ``flexible`` on every channel), unit negative feedback."""
    controllers = [controller_system(p) for p in parameters]
    ts = controllers[0].dt
    plant = mimo
    if flexible is not None:
        plant = control.append(*[control.ss(flexible)] * len(controllers)) * mimo
    sampled = control.sample_system(control.ss(plant), ts, method="zoh")
    if delay_samples:
        delay = control.ss(control.tf([1.0], [1.0] + [0.0] * delay_samples, dt=ts))
        sampled = control.append(*[delay] * len(controllers)) * sampled
    loop = control.append(*controllers) * sampled
    closed = control.feedback(loop, np.eye(len(controllers)))
    return float(np.max(np.abs(np.linalg.eigvals(np.asarray(closed.A)))))


def plant_document(plant: control.TransferFunction) -> dict[str, list[float]]:
    """JSON form of a SISO channel: numerator and denominator coefficients, highest power first (control.tf)."""
    return {"num": [float(c) for c in plant.num[0][0]], "den": [float(c) for c in plant.den[0][0]]}


@dataclass
class ManipulatorDesign:
    """Per-actuator results (``results[i]`` on ``plants[i]``, one plant per pose) and the coupled checks."""

    poses: np.ndarray
    results: list[TuningResult]
    plants: list[list[control.LTI]]
    radius_without_gravity: list[float]
    radius_with_gravity: list[float]
    infeasible: list[str]

    def as_dict(self) -> dict:
        """JSON: ``joints`` maps d1, d3, d5, d7 to a single-joint ``motiontwin tune`` document each."""
        return {"method": "per-actuator design on the CheungManipulator FMU linearised at several poses",
                "poses": self.poses.tolist(), "pose_fields": ["x [m]", "y [m]", "z [m]", "theta [rad]"],
                "joints": {a: r.as_dict() | {"plants": [plant_document(p) for p in plants]}
                           for a, r, plants in zip(ACTUATORS, self.results, self.plants)},
                "coupled_closed_loop_radius": {"without_gravity": self.radius_without_gravity,
                                               "with_gravity": self.radius_with_gravity},
                "infeasible": self.infeasible}


def tune_manipulator(fmu: str | Path, poses: np.ndarray, flexible: JointModel | None, ts: float = 5e-4,
                     spec: TuningSpec = TuningSpec(), delay_samples: int = 1, **tune_options) -> ManipulatorDesign:
    """Tune d1, d3, d5, d7 each on its channel at every pose (times H(s) of ``flexible`` unless None), then
    check the four designs together on the coupled plant at every pose, with and without gravity.
    An infeasible actuator keeps its least-violating design and is listed in ``infeasible``."""
    from motiontwin.ident.tuning import InfeasibleSpecError

    rigid = linearize_poses(fmu, poses, gravity=False)
    heavy = linearize_poses(fmu, poses, gravity=True)
    h = flexible_mode(flexible) if flexible is not None else None
    plants, results, infeasible = [], [], []
    for i, name in enumerate(ACTUATORS):
        channels = [actuator_channel(m, i, f"pose {k} actuator {name}") for k, m in enumerate(rigid)]
        if h is not None:
            channels = [c * h for c in channels]
        try:
            result = tune(channels, ts, spec, delay_samples, **tune_options)
        except InfeasibleSpecError as err:
            result = err.result
            infeasible.append(f"actuator {name}: {err}")
        plants.append(channels)
        results.append(result)
    params = [r.parameters for r in results]
    return ManipulatorDesign(poses, results, plants,
                             [decentralised_radius(params, m, delay_samples, h) for m in rigid],
                             [decentralised_radius(params, m, delay_samples, h) for m in heavy], infeasible)

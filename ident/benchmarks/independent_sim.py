"""The independent truth simulator's closed loop: a rigid axis m dv/dt = F - d v plus the laws of
:mod:`ident.benchmarks.independent_laws`, a sampled linear controller z+ = A z + B [r; q_meas],
u = C z + D [r; q_meas] held over each period Ts, an encoder (sensor law, white noise, quantisation) and
process force noise. Several lanes (runs with other noise or with the effect switched off) are integrated
side by side as numpy arrays.

Integrator: classic fixed-step Runge-Kutta 4 with ``substeps`` steps per controller period, written here
(no scipy, no CasADi, no FMU). Fixed steps because the loop is sampled: the force is constant over each period,
so a step never straddles an input jump and no event location is needed; the laws are continuous in the
state (regularised sign, continuous dead zone), so RK4 keeps its order except at contact onsets. With Ts/2
steps (the benchmark's ``independent.SUBSTEPS``) its fastest dynamics (LuGre's pre-sliding, the backlash
contact, the friction regularisation) stay inside RK4's stability region (|h lambda| < 2.7).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motiontwin.ident.benchmarks.independent_laws import Law, quantize


@dataclass
class Axis:
    """The rigid body: mass (or inertia) and viscous damping, linear [kg, N.s/m] or rotary [kg.m2, N.m.s/rad]."""

    mass: float
    damping: float
    rotary: bool = False


@dataclass
class Loop:
    """What a closed-loop run needs besides its drive: the plant (axis and laws), the controller matrices,
    the encoder resolution and the RK4 substeps per sample."""

    axis: Axis
    laws: list[Law]
    ts: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    resolution: float = 0.0
    substeps: int = 4
    gains: np.ndarray = field(default_factory=lambda: np.ones((0, 1)))   # (n_laws, lanes), 1 = law acts

    def __post_init__(self) -> None:
        rows, start = [], 2
        for law in self.laws:
            rows.append(slice(start, start + law.n_states))
            start += law.n_states
        self.n_states = start
        #: (law, its state rows, its gain row) of the laws that exert a force
        self.forces = [(law, r, i) for i, (law, r) in enumerate(zip(self.laws, rows))
                       if law.kind in ("force", "transmission")]
        self.load = next((r.start for law, r in zip(self.laws, rows) if law.kind == "transmission"), None)
        #: the body's own mass: the axis' minus a load carried through a transmission law
        self.body_mass = self.axis.mass - sum(law.params["m2"] for law in self.laws if law.kind == "transmission")


def derivatives(loop: Loop, state: np.ndarray, force: np.ndarray) -> np.ndarray:
    """d(state)/dt of the plant under the applied ``force`` (lanes,); state rows x, v, the laws' states."""
    x, v = state[0], state[1]
    total = force - loop.axis.damping * v
    out = np.empty_like(state)
    out[0] = v
    for law, rows, i in loop.forces:
        f, ds = law.force(x, v, state[rows], loop.gains[i])
        total = total + f
        if law.n_states:
            out[rows] = ds
    out[1] = total / loop.body_mass
    return out


def rk4_step(loop: Loop, state: np.ndarray, force: np.ndarray, h: float) -> np.ndarray:
    """One classic Runge-Kutta 4 step of length ``h`` at constant ``force``."""
    k1 = derivatives(loop, state, force)
    k2 = derivatives(loop, state + 0.5 * h * k1, force)
    k3 = derivatives(loop, state + 0.5 * h * k2, force)
    k4 = derivatives(loop, state + h * k3, force)
    return state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def true_position(loop: Loop, state: np.ndarray) -> np.ndarray:
    """The position the encoder is mounted on: the load behind a transmission law, else the body."""
    return state[0] if loop.load is None else state[loop.load]


def initial_state(loop: Loop, lanes: int, x0: float = 0.0) -> np.ndarray:
    """At rest at ``x0`` (a load behind a gap centred in it)."""
    state = np.zeros((loop.n_states, lanes))
    state[0] = x0
    if loop.load is not None:
        state[loop.load] = x0
    return state


def simulate(loop: Loop, r: np.ndarray, u_ext: np.ndarray, process: np.ndarray, sensor_noise: np.ndarray,
             quantise: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Closed loop on the controller grid, from rest at x = 0 and a zero controller state. ``r``, ``u_ext``,
    ``process`` (force noise held over each period), ``sensor_noise``: (n, lanes) arrays; ``quantise``: per
    lane whether the encoder rounds to ``loop.resolution`` (default all). Returns (n, lanes) arrays q (measured),
    u (the command plus u_ext, what the recording holds), f (the force the plant got) and q_true."""
    n, lanes = r.shape
    quantise = np.ones(lanes, bool) if quantise is None else np.asarray(quantise, bool)
    if loop.gains.shape != (len(loop.laws), lanes):
        raise ValueError(f"gains must be (n_laws, lanes) = ({len(loop.laws)}, {lanes}), got {loop.gains.shape}")
    state = initial_state(loop, lanes)
    z = np.zeros((loop.A.shape[0], lanes))
    h = loop.ts / loop.substeps
    out = {k: np.empty((n, lanes)) for k in ("q", "u", "f", "q_true")}
    for k in range(n):
        q_true = true_position(loop, state)
        q_seen = q_true
        for law, gain in zip(loop.laws, loop.gains):
            q_seen = law.sense(q_seen, gain)
        q_seen = q_seen + sensor_noise[k]
        q_meas = np.where(quantise, quantize(q_seen, loop.resolution), q_seen)
        y = np.vstack([r[k], q_meas])
        u = (loop.C @ z + loop.D @ y)[0] + u_ext[k]
        z = loop.A @ z + loop.B @ y
        f = u
        for law, gain in zip(loop.laws, loop.gains):
            f = law.actuate(f, gain)
        applied = f + process[k]
        out["q"][k], out["u"][k], out["f"][k], out["q_true"][k] = q_meas, u, f, q_true
        for _ in range(loop.substeps):
            state = rk4_step(loop, state, applied, h)
    return out

"""Diagnosis benchmark on a truth independent of the diagnosis: bundles simulated by
:mod:`ident.benchmarks.independent_sim` (own RK4 integrator) with the laws of
:mod:`ident.benchmarks.independent_laws` (written from the literature; neither ``ident.diagnosis.effects``
nor the ``MotionTwin.Effects`` Modelica library is used), process force noise (white and first-order
coloured), encoder quantisation and white noise, a jittered time column (the controller itself runs at its
fixed Ts), 2-100 kg linear and 0.02-1 kg.m2 rotary axes, the four plant forms of
:data:`ident.benchmarks.truth.PLANT_FORMS` with mass and damping 20-50 % off.

Each effect is concealed near the edge of detectability: its size is scaled so that it moves the measured
position (noise-free) by a few micrometres (linear) or tens of microradians (rotary) on the train or the
validation drive; a current limit sits at the largest share of the peak force that conceals it as much (the
PID winds up behind it); a constant offset force is drawn (the PID's integral takes it up: it shows in the
force only). Out-of-catalogue laws (v|v| drag, a friction bump at one place) have the right answer
"unexplained"; an encoder cyclic error is the catalogue's sensor effect ``encoder_error``.

Next to each bundle folder ``OUT/SET/CASE`` the file ``OUT/SET/CASE.truth.json`` holds the true laws and
parameters, the expected answers, the concealment, and the ACHIEVABLE FLOOR: ``floor_rms``, the validation RMS
of the measured position against the truth re-simulated without any noise (what a correct deterministic model,
as the diagnosis' validation simulation is, can reach; the median over that run and reruns perturbed by 1e-12 of
the force, since a loop with backlash can be chaotic, ``floor_spread`` their extremes), and
``floor_reseed_rms``, against the truth re-simulated with other noise seeds (about sqrt(2) x ``floor_rms`` in a
linear loop), and ``without_effect_rms``, against the truth re-simulated noise-free without its effects (how far
the effect shows above the floor on the validation run); ``force_floor_rms`` and ``force_without_effect_rms`` the same for the recorded force u (an effect the
loop's integral action rejects, a constant force, shows in u only). Units: SI.

    python -m motiontwin.ident.benchmarks.independent generate OUT_DIR [--set heldout|tuning] [--case A,B]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiontwin.harness.recording import atomic_write_texts, make_recording, write_recording
from motiontwin.ident.benchmarks.independent_laws import EXPECTED, MAIN_PARAMETER, coloured_noise, make_law
from motiontwin.ident.benchmarks.independent_sim import Axis, Loop, simulate
from motiontwin.ident.benchmarks.truth import PLANT_FORMS, controller_json, pid_controller, rotary_text

TS = 5e-4
PRE_S, PRE_MOVE_S = 2.5, 2.0   # pre-roll cut off the recordings: a slow move from x = 0 to r[0], then a dwell [s]
ROTARY_SCALE = 20.0         # rad per m: a rotary axis is the linear one with lengths x20 (an arm of 5 cm)
RESOLUTION = {False: 5e-9, True: 7.5e-7}    # encoder quantum: 5 nm linear, 2^23 counts per turn rotary
NOISE = {False: 10e-9, True: 5e-7}          # encoder white noise std
JITTER = 0.2e-3 * TS        # +- bound of the time column's jitter (bundle readers accept steps within 1e-3 Ts)

#: case -> laws; parameters-only controls, single effects, two-effect combinations, out of the catalogue
CASES: dict[str, tuple[str, ...]] = {
    "params_coloured_a": (), "params_coloured_b": (), "params_quiet": (),
    "offset": ("offset",), "coulomb": ("coulomb",), "stribeck": ("stribeck",), "lugre": ("lugre",),
    "backlash": ("backlash",), "current_limit": ("current_limit",), "cogging": ("cogging",),
    "coulomb+cogging": ("coulomb", "cogging"), "offset+stribeck": ("offset", "stribeck"),
    "drag": ("drag",), "friction_bump": ("friction_bump",), "encoder_error": ("encoder_error",),
}
#: the same cases with seeds of their own per set: "tuning" to develop on, "heldout" to check a change, "audit"
#: run only to report a change's effect on data no decision was ever tuned to (first run in session 23)
SET_SEEDS = {"tuning": 7000, "heldout": 9000, "audit": 11000}
#: laws not sized by their concealment: a constant force (the PID's integral takes it up, it shows in the
#: force, not in the position) and the current limit (set below the largest force the loop asks for)
FIXED_SIZE = ("offset", "current_limit")


@dataclass
class Case:
    """Everything drawn for one bundle from its seed."""

    name: str
    seed: int
    axis: Axis
    laws: list
    targets: list[float | None]     # concealment target of each law [m or rad] (None: sized otherwise)
    stroke: float
    scale: float                    # 1 (linear) or ROTARY_SCALE
    white_std: float                # process force noise, white per sample [N]
    coloured_std: float             # process force noise, first-order coloured [N]
    coloured_tau: float             # its time constant [s]
    form: str
    nominal: tuple[float, float]    # (m, d) written into plant.mo
    pole_pitch: float | None = None


def _law_parameters(name: str, m_e: float, L: float, stroke: float, rng: np.random.Generator) -> dict:
    """Trial parameters of a law (its size is calibrated afterwards) in the axis' own units. ``m_e``: the mass
    of the linear equivalent (J L^2), ``L``: 1 linear, ROTARY_SCALE rotary (x = q/L, F = torque*L)."""
    f, mass = m_e / L, m_e / L ** 2    # the force (torque) of 1 m/s2 on the equivalent, the own mass (inertia)
    if name == "offset":      # not sized by concealment: the PID's integral action takes a constant force up
        return {"F0": 0.1 * f * rng.uniform(0.5, 2) * rng.choice([-1, 1])}
    if name == "coulomb":
        return {"Fc": 0.03 * f}
    if name == "stribeck":
        fc = 0.02 * f
        return {"Fc": fc, "Fs": fc * rng.uniform(2, 3), "vs": rng.uniform(0.002, 0.006) * L,
                "delta": rng.uniform(1, 2)}
    if name == "lugre":
        fc, z0 = 0.02 * f, rng.uniform(40e-6, 100e-6) * L
        return {"Fc": fc, "Fs": 1.5 * fc, "vs": 0.005 * L, "z0": z0, "sigma1": 0.4 * math.sqrt(fc / z0 * mass)}
    if name == "cogging":
        return {"A1": 0.02 * f, "A2": 0.02 * f * rng.uniform(0.2, 0.5), "N": 3.0,
                "pitch": 0.032 if L == 1 else 2 * math.pi / 8, "phi1": rng.uniform(-3, 3), "phi2": rng.uniform(-3, 3)}
    if name == "backlash":
        m2, fa = 0.3 * mass, rng.uniform(150, 300)
        k = m2 * (2 * math.pi * fa) ** 2
        return {"b": 5e-6 * L, "m2": m2, "k": k, "c": 2 * 0.1 * math.sqrt(k * m2)}
    if name == "current_limit":
        return {"Fmax": math.inf, "fraction": rng.uniform(0.5, 1.5)}
    if name == "drag":
        return {"c": 0.5 * m_e / L ** 3}
    if name == "friction_bump":
        return {"Fb": 0.05 * f, "x0": stroke * rng.uniform(0.3, 0.7), "w": 0.05 * stroke}
    if name == "encoder_error":
        return {"a1": 1e-6 * L, "a2": 0.3e-6 * L * rng.uniform(0.5, 1.5), "lam": 1e-3 * L,
                "phi1": rng.uniform(-3, 3), "phi2": rng.uniform(-3, 3)}
    raise KeyError(f"unknown law {name!r}")


def draw_case(name: str, seed: int) -> Case:
    """The axis, laws, noise and plant form of case ``name`` drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    rotary = bool(rng.integers(2))
    L = ROTARY_SCALE if rotary else 1.0
    mass = float(np.exp(rng.uniform(math.log(0.02), math.log(1.0)))) if rotary else \
        float(np.exp(rng.uniform(math.log(2.0), math.log(100.0))))
    axis = Axis(mass, mass * rng.uniform(3, 10), rotary)
    stroke = rng.uniform(0.06, 0.14) * L
    # a rotary inertia J moves like a linear mass J*L^2 over lengths x L
    m_equiv = mass * L * L if rotary else mass
    laws = [make_law(n, _law_parameters(n, m_equiv, L, stroke, rng)) for n in CASES[name]]
    targets = [rng.uniform(2e-6, 6e-6) * L if law.name not in FIXED_SIZE else None for law in laws]
    quiet = name == "params_quiet"
    white = 0.0 if quiet else 0.005 * m_equiv / L * rng.uniform(0.5, 2)     # 0.005 m/s2 on the equivalent
    coloured = 0.0 if quiet else 0.01 * m_equiv / L * rng.uniform(0.5, 2)
    forms = sorted(PLANT_FORMS)
    form = forms[seed % len(forms)]
    nominal = (mass * (1 + rng.uniform(0.2, 0.5) * rng.choice([-1, 1])),
               axis.damping * (1 + rng.uniform(0.2, 0.5) * rng.choice([-1, 1])))
    pitch = next((law.params["pitch"] for law in laws if law.name == "cogging"), None)
    return Case(name, seed, axis, laws, targets, stroke, L, white, coloured, rng.uniform(0.02, 0.1), form, nominal,
                pitch)


def _quintic(n: int) -> np.ndarray:
    """Minimum-jerk profile 10 s^3 - 15 s^4 + 6 s^5 over n samples, from 0 to 1."""
    s = np.linspace(0, 1, n)
    return s ** 3 * (10 - 15 * s + 6 * s * s)


def drive(duration: float, stroke: float, force: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Reference and u_ext: minimum-jerk point-to-point moves of random length and speed with dwells over
    the first 80 %, then a Schroeder-phased multisine force (10-300 Hz, RMS ``force``) on u_ext at rest."""
    n = int(round(duration / TS))
    r = np.empty(n)
    u_ext = np.zeros(n)
    moving = int(0.8 * n)
    pos, k = stroke * rng.uniform(0.3, 0.7), 0
    r[:] = pos
    while k < moving - int(0.2 / TS):
        target = stroke * rng.uniform(0.05, 0.95)
        speed = stroke * rng.choice([0.05, 0.2, 0.6, 1.5]) * rng.uniform(0.7, 1.3)
        steps = min(max(int(1.875 * abs(target - pos) / speed / TS), int(0.06 / TS)), moving - k)
        r[k:k + steps] = pos + (target - pos) * _quintic(steps)
        r[k + steps:] = target
        pos = target
        k += steps + int(rng.uniform(0.05, 0.3) / TS)
    freqs = np.geomspace(10, 300, 24)
    phases = -np.pi * np.arange(1, 25) * np.arange(24) / 24
    t = np.arange(n - moving) * TS
    wave = np.sin(2 * np.pi * np.outer(t, freqs) + phases).sum(axis=1)
    u_ext[moving:] = force * wave / np.sqrt(np.mean(wave ** 2)) * np.minimum(1, t / 0.05)
    return r, u_ext


def with_preroll(r: np.ndarray, u_ext: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Prepend the pre-roll: a slow minimum-jerk move from 0 to r[0] (gentler than any recorded move, so that a
    current limit is not reached before the recording), then a dwell; returns r, u_ext, its length."""
    pre, move = int(round(PRE_S / TS)), int(round(PRE_MOVE_S / TS))
    head = np.full(pre, r[0])
    head[:move] = r[0] * _quintic(move)
    return np.concatenate([head, r]), np.concatenate([np.zeros(pre), u_ext]), pre


# -- simulation of a case ------------------------------------------------------------------------

SUBSTEPS = 2                # RK4 steps per controller period (Ts/2: |h lambda| < 1.1 for the stiffest law)
DURATIONS = (8.0, 4.0)      # train, validation [s]


def make_loop(case: Case, laws: list, gains: np.ndarray, substeps: int = SUBSTEPS) -> Loop:
    """The closed loop of ``case`` with ``laws`` switched per lane by ``gains`` (n_laws, lanes)."""
    ctrl = pid_controller(TS, mass=case.axis.mass)
    return Loop(case.axis, laws, TS, ctrl.A, ctrl.B, ctrl.C, ctrl.D, RESOLUTION[case.axis.rotary], substeps,
                np.asarray(gains, float))


def process_noise(case: Case, n: int, rng: np.random.Generator) -> np.ndarray:
    """Process force noise of one run: white per sample plus first-order coloured [N or N.m]."""
    white = case.white_std * rng.standard_normal(n)
    return white + (coloured_noise(n, case.coloured_std, case.coloured_tau, TS, rng) if case.coloured_std else 0.0)


def _drive_lanes(drives: list[tuple[np.ndarray, np.ndarray, int]], per: int) -> tuple[np.ndarray, ...]:
    """r and u_ext of ``per`` lanes per drive (padded to the longest), and the recorded span of each drive."""
    n = max(d[0].size for d in drives)
    r, u_ext = np.zeros((n, per * len(drives))), np.zeros((n, per * len(drives)))
    for j, (rr, uu, _) in enumerate(drives):
        r[:, j * per:(j + 1) * per] = np.concatenate([rr, np.full(n - rr.size, rr[-1])])[:, None]
        u_ext[:rr.size, j * per:(j + 1) * per] = uu[:, None]
    return r, u_ext, [slice(pre, rr.size) for rr, _, pre in drives]


def _noise_free(case: Case, laws: list, gains: np.ndarray, r: np.ndarray, u_ext: np.ndarray) -> dict:
    zeros = np.zeros_like(r)
    return simulate(make_loop(case, laws, gains), r, u_ext, zeros, zeros, quantise=np.zeros(r.shape[1], bool))


def calibrate(case: Case, drives: list[tuple[np.ndarray, np.ndarray, int]]) -> list:
    """The laws sized to their concealment targets on the drives (r, u_ext, pre-roll length; train and
    validation): each law alone, noise-free, scaled so that max |q_with - q_without| over both drives equals
    its target (one linear rescaling); an offset as drawn; a current limit by :func:`_current_limit`."""
    if not case.laws:
        return []
    per = 1 + len(case.laws)                       # lanes per drive: without the laws, then each law alone
    gains = np.zeros((len(case.laws), per * len(drives)))
    for j in range(len(drives)):
        gains[np.arange(len(case.laws)), j * per + 1 + np.arange(len(case.laws))] = 1
    r, u_ext, spans = _drive_lanes(drives, per)
    out = _noise_free(case, case.laws, gains, r, u_ext)
    sized = []
    for i, (law, target) in enumerate(zip(case.laws, case.targets)):
        if law.name == "current_limit":
            peak = max(float(np.max(np.abs(out["f"][span, j * per]))) for j, span in enumerate(spans))
            sized.append(_current_limit(case, law, drives, peak))
            continue
        moved = max(float(np.max(np.abs(out["q"][span, j * per + 1 + i] - out["q"][span, j * per])))
                    for j, span in enumerate(spans))
        sized.append(law if target is None or moved == 0 else law.scaled(target / moved))
    return sized


CLIP_SHARES = 1 - np.geomspace(0.003, 0.1, 10)   # current limits tried, as shares of the peak force


def _current_limit(case: Case, law, drives: list, peak: float):
    """The current limit at the largest share of ``peak`` whose concealment (max |q_with - q_without| over
    both drives, noise-free) reaches the drawn ``fraction`` x 4 um (x L): the PID winds up behind the limit,
    so the concealment grows steeply as the limit falls (all shares in one integration, one lane each)."""
    per = 1 + CLIP_SHARES.size
    r, u_ext, spans = _drive_lanes(drives, per)
    fmax = np.tile(np.concatenate([[np.inf], CLIP_SHARES * peak]), len(drives))
    out = _noise_free(case, [make_law("current_limit", {"Fmax": fmax})], np.ones((1, r.shape[1])), r, u_ext)
    moved = np.max([np.max(np.abs(out["q"][span, j * per + 1:(j + 1) * per] - out["q"][span, j * per:j * per + 1]),
                           axis=0) for j, span in enumerate(spans)], axis=0)
    goal = law.params["fraction"] * 4e-6 * case.scale
    k = int(np.flatnonzero(moved >= goal)[0]) if np.any(moved >= goal) else CLIP_SHARES.size - 1
    return make_law("current_limit", {"Fmax": float(CLIP_SHARES[k] * peak), "share_of_peak": float(CLIP_SHARES[k])})


def simulate_case(case: Case) -> dict:
    """Train and validation recordings of ``case`` and what truth.json reports: in one integration of seven
    lanes, train (noisy; noise-free; noise-free without the effects) and validation (noisy; noise-free; noisy
    with other seeds; noise-free without the effects). Returns recordings (time, r, u, q, u_ext per part), the sized laws, the concealment and
    the floor."""
    rng = np.random.default_rng(case.seed + 1)
    force = 0.02 * case.axis.mass * case.scale     # u_ext multisine RMS: 0.02 m/s2 x the equivalent mass x L
    drives = [with_preroll(*drive(d, case.stroke, force, rng)) for d in DURATIONS]
    pre = drives[0][2]
    laws = calibrate(case, drives)
    n = max(d[0].size for d in drives)
    pad = [np.concatenate([x, np.full(n - x.size, x[-1])]) for d in drives for x in d[:2]]
    r = np.column_stack([pad[0]] * 3 + [pad[2]] * 4)
    u_ext = np.column_stack([pad[1]] * 3 + [pad[3]] * 4)
    noisy = np.array([True, False, False, True, False, True, False])
    process = np.zeros((n, 7))
    sensor = np.zeros((n, 7))
    for lane in np.flatnonzero(noisy):
        process[:, lane] = process_noise(case, n, rng)
        sensor[:, lane] = NOISE[case.axis.rotary] * rng.standard_normal(n)
    gains = np.tile(np.array([1, 1, 0, 1, 1, 1, 0.0]), (len(laws), 1))
    out = simulate(make_loop(case, laws, gains), r, u_ext, process, sensor, quantise=noisy)
    parts = {}
    for part, lane, drive_ in (("train", 0, drives[0]), ("validation", 3, drives[1])):
        m = drive_[0].size
        k = np.arange(m - pre)
        jitter = rng.uniform(-JITTER, JITTER, k.size) * (k > 0)     # the first sample at t = 0
        parts[part] = {"time": k * TS + jitter, "r": drive_[0][pre:], "u": out["u"][pre:m, lane],
                       "q": out["q"][pre:m, lane], "u_ext": drive_[1][pre:]}
    m_train, m_val = drives[0][0].size, drives[1][0].size
    moved = out["q"][pre:m_train, 1] - out["q"][pre:m_train, 2]
    q_val, u_val = out["q"][pre:m_val, 3:], out["u"][pre:m_val, 3:]
    floors = perturbed_floors(case, laws, drives[1], q_val[:, 0], u_val[:, 0], (q_val[:, 1], u_val[:, 1]))
    return {"recordings": parts, "laws": laws,
            "concealment": {"max_abs": float(np.max(np.abs(moved))), "rms": float(np.sqrt(np.mean(moved ** 2))),
                            "force_max_abs": float(np.max(np.abs(np.diff(out["u"][pre:m_train, 1:3], axis=1))))},
            **floors,
            "floor_reseed_rms": float(np.sqrt(np.mean((q_val[:, 0] - q_val[:, 2]) ** 2))),
            "without_effect_rms": float(np.sqrt(np.mean((q_val[:, 0] - q_val[:, 3]) ** 2))),
            "force_without_effect_rms": float(np.sqrt(np.mean((u_val[:, 0] - u_val[:, 3]) ** 2)))}


PERTURBATION = 1e-12    # force perturbations of the noise-free reruns, relative to the drive's force scale
PERTURBED_RUNS = 4


def perturbed_floors(case: Case, laws: list, drive_: tuple[np.ndarray, np.ndarray, int], q_rec: np.ndarray,
                     u_rec: np.ndarray, noise_free: tuple[np.ndarray, np.ndarray]) -> dict:
    """The achievable floor robust to the loop's sensitivity: the validation recording (``q_rec``, ``u_rec``)
    against the noise-free truth (``noise_free``) and against ``PERTURBED_RUNS`` reruns of it with white force
    perturbations of ``PERTURBATION`` (its own seed, so the recordings do not change); ``floor_rms`` and
    ``force_floor_rms`` are the medians. Why: a loop with backlash can be chaotic (round-off of 1e-20 grows to
    2e-5 rad within 0.5 s on the tuning backlash case, whose floor was 3.4e-5 in one run and 6.2e-5 in another):
    one noise-free run is then a lucky draw, not what a deterministic model can reach. Elsewhere the reruns
    equal the noise-free run and the floor is unchanged. ``floor_spread`` gives the runs' extremes."""
    r, u_ext, pre = drive_
    n = r.size
    rng = np.random.default_rng(case.seed + 2)
    scale = PERTURBATION * 0.02 * case.axis.mass * case.scale
    lanes = PERTURBED_RUNS
    out = simulate(make_loop(case, laws, np.ones((len(laws), lanes))), np.repeat(r[:, None], lanes, 1),
                   np.repeat(u_ext[:, None], lanes, 1), scale * rng.standard_normal((n, lanes)),
                   np.zeros((n, lanes)), quantise=np.zeros(lanes, bool))
    runs_q = [noise_free[0]] + [out["q"][pre:, k] for k in range(lanes)]
    runs_u = [noise_free[1]] + [out["u"][pre:, k] for k in range(lanes)]
    q = [float(np.sqrt(np.mean((q_rec - run) ** 2))) for run in runs_q]
    u = [float(np.sqrt(np.mean((u_rec - run) ** 2))) for run in runs_u]
    return {"floor_rms": float(np.median(q)), "force_floor_rms": float(np.median(u)),
            "floor_spread": [min(q), max(q)], "force_floor_spread": [min(u), max(u)],
            "floor_noise_free_rms": q[0]}


# -- bundles ---------------------------------------------------------------------------------------

def _main_parameter(law) -> dict:
    """The law's main parameter as the catalogue effect's contract states it (name and value)."""
    key, contract, factor = MAIN_PARAMETER[law.name]
    return {"truth": key, "contract": contract, "value": factor * law.params[key]}


def write_bundle(folder: Path, case: Case) -> dict:
    """Write the bundle (experiment.json, plant.mo, train.csv, validation.csv) into ``folder`` and
    ``folder.truth.json`` beside it; returns the truth document."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sim = simulate_case(case)
    form = PLANT_FORMS[case.form]
    units = {"r": "rad", "q": "rad", "u": "N.m", "u_ext": "N.m"} if case.axis.rotary else None
    for part, rec in sim["recordings"].items():
        write_recording(folder / f"{part}.csv", make_recording(
            rec["time"], {k: rec[k] for k in ("r", "u", "q", "u_ext")}, units, sample_time=TS, seed=case.seed,
            excited="minimum-jerk point-to-point moves, then a multisine 10-300 Hz on u_ext",
            metadata={"truth": "independent truth simulator (ident.benchmarks.independent)"}))
    ctrl = pid_controller(TS, mass=case.axis.mass)
    plant = {"modelica": "plant.mo", "class": form.class_name, "input": form.input, "output": form.output}
    if case.pole_pitch is not None:
        plant["pole_pitch"] = case.pole_pitch
    experiment = {"plant": plant, "controller": controller_json(ctrl),
                  "recordings": {"train": "train.csv", "validation": "validation.csv"}}
    laws = [{"law": law.name, "expected": EXPECTED[law.name], "parameters": law.params,
             **({"main": _main_parameter(law)} if law.name in MAIN_PARAMETER else {})} for law in sim["laws"]]
    truth = {"case": case.name, "seed": case.seed, "simulator": "ident.benchmarks.independent (RK4, Ts/%d)" % SUBSTEPS,
             "axis": {"mass": case.axis.mass, "damping": case.axis.damping, "rotary": case.axis.rotary},
             "plant_form": case.form, "mass_parameter": form.mass, "mass_scale": form.scale,
             "nominal": {"mass": case.nominal[0], "damping": case.nominal[1]}, "stroke": case.stroke,
             "laws": laws, "expected": sorted({law["expected"] for law in laws}),
             "noise": {"encoder_resolution": RESOLUTION[case.axis.rotary], "encoder_std": NOISE[case.axis.rotary],
                       "process_white_std": case.white_std, "process_coloured_std": case.coloured_std,
                       "process_coloured_tau": case.coloured_tau, "time_jitter_bound": JITTER},
             "concealment_targets": case.targets, "concealment": sim["concealment"],
             "floor_rms": sim["floor_rms"], "floor_spread": sim["floor_spread"],
             "floor_noise_free_rms": sim["floor_noise_free_rms"], "floor_reseed_rms": sim["floor_reseed_rms"],
             "without_effect_rms": sim["without_effect_rms"], "force_floor_rms": sim["force_floor_rms"],
             "force_floor_spread": sim["force_floor_spread"],
             "force_without_effect_rms": sim["force_without_effect_rms"]}
    atomic_write_texts({
        folder / "plant.mo": (rotary_text(form.text) if case.axis.rotary else form.text).format(
            a=float(round(case.nominal[0], 4)) * form.scale, b=float(round(case.nominal[1], 4)) * form.scale),
        folder / "experiment.json": json.dumps(experiment, indent=2),
        folder.parent / f"{folder.name}.truth.json": json.dumps(truth, indent=2),
    })
    return truth


def case_list(which: str) -> list[tuple[str, int]]:
    """(case, seed) of the set ``which``: the same cases, seeds of their own per set."""
    return [(name, SET_SEEDS[which] + i) for i, name in enumerate(CASES)]


def generate(out: Path, which: str, only: list[str] | None = None) -> None:
    """Write the bundles of the set ``which`` (or the cases ``only``) into ``out/which/CASE``."""
    for name, seed in case_list(which):
        if only and name not in only:
            continue
        t0 = time.perf_counter()
        case = draw_case(name, seed)
        truth = write_bundle(out / which / name, case)
        unit = "rad" if case.axis.rotary else "m"
        print(f"{which}/{name}: seed {seed}, {'rotary' if case.axis.rotary else 'linear'} {case.axis.mass:.3g}, "
              f"form {case.form}, concealment {truth['concealment']['max_abs']:.3g} {unit}, "
              f"floor {truth['floor_rms']:.3g} {unit}, {time.perf_counter() - t0:.1f} s", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m motiontwin.ident.benchmarks.independent")
    parser.add_argument("command", choices=["generate"])
    parser.add_argument("out", type=Path)
    parser.add_argument("--set", default="heldout", choices=sorted(SET_SEEDS))
    parser.add_argument("--case", default=None, help="one case, or several separated by commas")
    args = parser.parse_args(argv)
    generate(args.out, args.set, args.case.split(",") if args.case else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())

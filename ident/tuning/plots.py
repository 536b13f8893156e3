"""Loop-shaping figure of a tuned joint: Bode of L, |S| and |T|, and the Nyquist plot of L (matplotlib).

One figure per joint, every plant set (actuator position / pose) overlaid in its own colour: |L| and the phase
of L with the gain and phase crossovers, |S| and |T| with the Ms bound and the closed-loop bandwidth, and the
Nyquist plot of L near -1 with, per set, the circle of radius 1/Ms around -1 (the modulus margin), the
phase-crossover point -10^(-GM/20) (GM) and the unit-circle point at angle -180 deg + PM (PM).
The loop is that of ``ident.tuning.loop_system``: discrete, with the hold and the computation delay.

Replot from a design file of ``motiontwin tune --out`` (no re-tuning)::

    python -m motiontwin.ident.tuning.plots build/tune/joint.json --out harness/examples/figures

writes ``tuning_joint.png`` (single-joint design) or ``tuning_manipulator_d1.png`` .. ``_d7.png`` (``--manipulator``).

Units: frequency in Hz, magnitudes in dB, phase in degrees.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import control
import numpy as np

from motiontwin.harness.recording import write_figure
from motiontwin.ident.frf import JointModel, state_space_response
from motiontwin.ident.tuning import LoopMargins, TuningSpec, frequency_grid, loop_margins, loop_system

__all__ = ["loop_responses", "loop_figure", "write_loop_figure", "plants_from_document", "replot_design"]


def loop_responses(parameters: dict[str, float], plants: Sequence[JointModel | control.LTI],
                   delay_samples: int = 1, points: int = 3000) -> tuple[np.ndarray, list[np.ndarray]]:
    """(f [Hz], [L(e^{j 2 pi f Ts}) per plant set]) on a log grid up to Nyquist."""
    out = []
    f = None
    for plant in plants:
        loop = loop_system(parameters, plant, delay_samples)
        f = frequency_grid(loop.dt, points) if f is None else f
        out.append(state_space_response((loop.A, loop.B, loop.C, loop.D), np.exp(2j * np.pi * f * loop.dt)))
    return f, out


def _db(x: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.abs(x))


def loop_figure(parameters: dict[str, float], plants: Sequence[JointModel | control.LTI],
                delay_samples: int = 1, labels: Sequence[str] | None = None, title: str = "",
                spec: TuningSpec | None = None, margins: Sequence[LoopMargins] | None = None):
    """2x2 matplotlib Figure (see the module docstring); ``margins`` default to ``loop_margins`` per set."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(labels) if labels is not None else [f"set {k}" for k in range(len(plants))]
    margins = list(margins) if margins is not None else [loop_margins(parameters, p, delay_samples) for p in plants]
    f, loops = loop_responses(parameters, plants, delay_samples)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5))
    (ax_mag, ax_nyq), (ax_phase, ax_sens) = axes
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    theta = np.linspace(0, 2 * np.pi, 361)
    for k, (loop, m, label) in enumerate(zip(loops, margins, labels)):
        c = colours[k % len(colours)]
        s, t = 1 / (1 + loop), loop / (1 + loop)
        ax_mag.semilogx(f, _db(loop), color=c, label=label)
        phase = np.degrees(np.unwrap(np.angle(loop)))
        ax_phase.semilogx(f, phase - 360 * math.ceil(phase[0] / 360), color=c)  # start in (-360, 0]
        ax_sens.semilogx(f, _db(s), color=c, label=f"|S| {label}")
        ax_sens.semilogx(f, _db(t), color=c, ls="--", label=f"|T| {label}")
        if math.isfinite(m.gain_crossover_hz):
            ax_mag.axvline(m.gain_crossover_hz, color=c, lw=0.6, ls=":")
        if math.isfinite(m.bandwidth_hz):
            ax_sens.plot(m.bandwidth_hz, -20 * math.log10(math.sqrt(2)), "v", color=c, ms=6)
        ax_nyq.plot(loop.real, loop.imag, color=c, label=label)
        ax_nyq.plot(loop.real, -loop.imag, color=c, lw=0.6, ls="--")
        if math.isfinite(m.ms):
            r = 1 / m.ms
            ax_nyq.plot(-1 + r * np.cos(theta), r * np.sin(theta), color=c, lw=0.8, ls="-.")
        if math.isfinite(m.gm_db):
            ax_nyq.plot(-10 ** (-m.gm_db / 20), 0.0, "x", color=c, ms=9, mew=2)
        if math.isfinite(m.pm_deg):
            angle = math.radians(-180 + m.pm_deg)
            ax_nyq.plot(math.cos(angle), math.sin(angle), "o", color=c, ms=7, mfc="none", mew=1.5)
    ax_mag.axhline(0, color="k", lw=0.6)
    ax_mag.set_ylabel("|L| [dB]")
    ax_mag.set_title("open loop L = C z^-d P_zoh (dotted: gain crossovers)")
    ax_mag.set_ylim(max(-80, ax_mag.get_ylim()[0]), ax_mag.get_ylim()[1])
    ax_mag.legend(fontsize=7, loc="lower left")
    ax_phase.axhline(-180, color="k", lw=0.6)
    ax_phase.set_ylabel("phase of L [deg]")
    ax_phase.set_xlabel("frequency [Hz]")
    if spec is not None:
        ax_sens.axhline(20 * math.log10(spec.ms_max), color="r", lw=0.8, ls=":", label=f"Ms bound {spec.ms_max:g}")
    ax_sens.axhline(0, color="k", lw=0.6)
    ax_sens.set_ylim(-60, 15)
    ax_sens.set_xlabel("frequency [Hz]")
    ax_sens.set_ylabel("[dB]")
    ax_sens.set_title("|S| (solid), |T| (dashed), CLBW where |T| = -3 dB (triangles)")
    ax_sens.legend(fontsize=6, ncol=2, loc="lower right")
    ax_nyq.plot(np.cos(theta), np.sin(theta), color="0.6", lw=0.6, ls=":")
    ax_nyq.plot(-1, 0, "k+", ms=10)
    ax_nyq.set_xlim(-3, 1.5)
    ax_nyq.set_ylim(-2.5, 2.0)
    ax_nyq.set_aspect("equal")
    ax_nyq.set_xlabel("Re L")
    ax_nyq.set_ylabel("Im L")
    ax_nyq.set_title("Nyquist of L: circle 1/Ms around -1, x = GM point, o = PM point")
    for ax in axes.flat:
        ax.grid(True, which="both", lw=0.3)
    summary = [f"{lab}: GM {m.gm_db:.1f} dB, PM {m.pm_deg:.1f} deg, CLBW {m.bandwidth_hz:.0f} Hz, Ms {m.ms:.2f}"
               for lab, m in zip(labels, margins)]
    text = [title] + summary if title else summary
    fig.suptitle("\n".join(text), fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.014 * len(text)))
    return fig


def write_loop_figure(path: str | os.PathLike, parameters: dict[str, float],
                      plants: Sequence[JointModel | control.LTI], delay_samples: int = 1,
                      labels: Sequence[str] | None = None, title: str = "", spec: TuningSpec | None = None,
                      margins: Sequence[LoopMargins] | None = None) -> Path:
    """Render :func:`loop_figure` to a PNG at ``path`` atomically (through :func:`harness.recording.write_figure`)."""
    import matplotlib.pyplot as plt

    fig = loop_figure(parameters, plants, delay_samples, labels, title, spec, margins)
    try:
        return write_figure(path, fig, dpi=110)
    finally:
        plt.close(fig)


def plants_from_document(entries: list, where: str) -> list[JointModel | control.LTI]:
    """Plant sets of a design JSON: JointModel fields (gain, alpha, resonances, antiresonances) or num/den."""
    plants: list[JointModel | control.LTI] = []
    for k, entry in enumerate(entries):
        if isinstance(entry, dict) and "gain" in entry:
            plants.append(JointModel(float(entry["gain"]), float(entry["alpha"]),
                                     tuple(tuple(map(float, r)) for r in entry.get("resonances", ())),
                                     tuple(tuple(map(float, r)) for r in entry.get("antiresonances", ()))))
        elif isinstance(entry, dict) and {"num", "den"} <= set(entry):
            plants.append(control.tf(entry["num"], entry["den"]))
        else:
            raise ValueError(f"{where}: field 'plants[{k}]' is neither a JointModel (gain, alpha, ...) nor num/den "
                             "(plants given as FMU linearisations are stored as text and cannot be replotted)")
    return plants


def replot_design(design: Path | str, out: Path | str) -> list[Path]:
    """Redraw the loop figures of a ``motiontwin tune --out`` design file (one joint or a manipulator's four).

    Parameters
    ----------
    design : path
        JSON written by ``motiontwin tune --out``.
    out : path
        Folder for ``tuning_joint.png`` or ``tuning_manipulator_d1.png`` ... ``_d7.png``.

    Returns
    -------
    list of Path
        The figures written.

    Raises
    ------
    ValueError
        When the file is not JSON (naming line and column) or a field is missing or unusable.
    """
    from motiontwin.fmus.limits import load_json

    design, out = Path(design), Path(out)
    doc = load_json(design)
    if not isinstance(doc, dict):
        raise ValueError(f"{design}: expected a JSON object (a design written by tune --out)")
    joints = ({f"manipulator_{k}": v for k, v in doc["joints"].items()} if "joints" in doc else {"joint": doc})
    written = []
    for name, joint in joints.items():
        where = f"{design}: joint {name}"
        for key in ("parameters", "plants", "spec", "delay_samples"):
            if key not in joint:
                raise ValueError(f"{where}: field '{key}' is missing")
        plants = plants_from_document(joint["plants"], where)
        spec = TuningSpec(**joint["spec"])
        labels = [f"set {k}: K={p.gain:.3g}" if isinstance(p, JointModel) else f"pose {k}"
                  for k, p in enumerate(plants)]
        written.append(write_loop_figure(out / f"tuning_{name}.png", joint["parameters"], plants,
                                         int(joint["delay_samples"]), labels, f"{design.name}: {name}", spec))
    return written

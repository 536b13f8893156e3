"""The outputs of the controller comparison (:mod:`motiontwin.comparison`): the table against the paper's
values (text and JSON), one recording per controller, and the joint and end-effector error figures. Units as
there: errors in um (angles in urad), times in ms."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from motiontwin.comparison import (CT_CLASS, JOINTS, LABELS, PAPER_TABLE3, PAPER_TABLE4, PLANT_CLASS, POSE_AXES,
                                   POSE_BANDS, ROBUST_CLASS, SS_WINDOW, TS, ComparisonResult, ControllerRun)
from motiontwin.harness import metrics
from motiontwin.harness.recording import Recording, atomic_write_texts, make_recording, write_figure, write_recording


def _fmt(value: float, scale: float, digits: str = ".1f") -> str:
    return "n/s" if not math.isfinite(value) else format(value * scale, digits)


def _row(name: str, ct: float, ct_paper: float, rc: float, rc_paper: float, scale: float, digits: str) -> str:
    return f"{name:38}{_fmt(ct, scale, digits):>9}{ct_paper:>10}{_fmt(rc, scale, digits):>9}{rc_paper:>10}"


def format_table(result: ComparisonResult) -> str:
    """Table 3 and Table 4 as text: ours beside the paper's (CT = computed-torque PID, RC = robust)."""
    ct, rc = result.table["computed_torque"], result.table["robust"]
    p3ct, p3rc = PAPER_TABLE3["computed_torque"], PAPER_TABLE3["robust"]
    p4ct, p4rc = PAPER_TABLE4["computed_torque"], PAPER_TABLE4["robust"]
    head = f"{'':38}{'CT ours':>9}{'CT paper':>10}{'RC ours':>9}{'RC paper':>10}"
    lines = ["Table 3: actuators (ours / paper)", head]
    rows = [("max. dynamic error", "max_dynamic_error", "max_dynamic_error_um", "um", 1e6, ".1f"),
            ("settling time (+-5 um)", "settling_time", "settling_time_ms", "ms", 1e3, ".1f"),
            ("steady-state error", "steady_state_error", "steady_state_error_um", "um", 1e6, ".2f")]
    for label, key, paper_key, unit, scale, digits in rows:
        for k, joint in enumerate(JOINTS):
            lines.append(_row(f"{label} of {joint} ({unit})", ct["joints"][key][k], p3ct[paper_key][k],
                              rc["joints"][key][k], p3rc[paper_key][k], scale, digits))
    lines += ["", "Table 4: end-effector, error forward(r) - forward(q) (ours / paper)", head]
    for k, axis in enumerate(POSE_AXES):
        band = "+-0.2 mrad" if axis == "theta" else "+-5 um"
        lines.append(_row(f"settling time {axis} ({band}, ms)", ct["end_effector"]["settling_time"][k],
                          p4ct["settling_time_ms"][k], rc["end_effector"]["settling_time"][k],
                          p4rc["settling_time_ms"][k], 1e3, ".1f"))
    for k, axis in enumerate(POSE_AXES):
        unit, scale = ("mrad", 1e3) if axis == "theta" else ("um", 1e6)
        lines.append(_row(f"accuracy {axis} (ours {unit}, paper um)", ct["end_effector"]["steady_state_error"][k],
                          p4ct["accuracy"][k], rc["end_effector"]["steady_state_error"][k], p4rc["accuracy"][k],
                          scale, ".3f"))
    lines += ["", f"move {result.t_start:g} s to {result.t_end:g} s; steady state = mean of the last {SS_WINDOW:g} s; "
              "n/s = not settled by the end of the run",
              f"robust gains: {result.design_source}; computed torque: triple pole at "
              f"{_ct_pole_hz(result):.3g} Hz, m_hat = diag M(start), full-model feedforward"]
    for c, label in (("robust", "RC"), ("computed_torque", "CT")):
        if result.margins.get(c):
            lines.append(f"{label} loop margins on the rigid joints (d1, d3, d5, d7): " + ", ".join(
                f"GM {m['gm_db']:.1f} dB / PM {m['pm_deg']:.1f} deg"
                + (f" / disk GM {m['disk_gm_db']:.1f} dB" if "disk_gm_db" in m else "") for m in result.margins[c]))
    return "\n".join(lines)

def _ct_pole_hz(result: ComparisonResult) -> float:
    return result.runs["computed_torque"].parameters[0]["Ki"] ** (1 / 3) / (2 * math.pi)


def table_document(result: ComparisonResult) -> dict[str, Any]:
    """JSON-ready table: ours (SI) and the paper's, design parameters, move window and wall times."""
    return {"units": {"ours": "SI (m, s, rad)", "paper": "um, ms (Table 4 theta accuracy as printed)"},
            "move": {"t_start": result.t_start, "t_end": result.t_end, "target_pose": result.target_pose.tolist()},
            "steady_state_window": SS_WINDOW,
            "settling_band": {"joints": metrics.DEFAULT_BAND, "end_effector": POSE_BANDS},
            "ours": result.table, "paper": result.paper, "loop_margins": result.margins,
            "design_source": result.design_source,
            "parameters": {c: r.parameters for c, r in result.runs.items()},
            "wall_time": {c: r.wall_time for c, r in result.runs.items()}}


def recording_of(run: ControllerRun, source: str) -> Recording:
    """A harness.recording of one run: r, q, e, u, ff per joint (d1...), pose and its reference."""
    columns: dict[str, np.ndarray] = {}
    units: dict[str, str] = {"time": "s"}
    for k, j in enumerate(JOINTS):
        for name, values, unit in ((f"r_{j}", run.reference[:, k], "m"), (f"q_{j}", run.position[:, k], "m"),
                                   (f"e_{j}", run.error[:, k], "m"), (f"u_{j}", run.force[:, k], "N"),
                                   (f"ff_{j}", run.feedforward_force[:, k], "N")):
            columns[name], units[name] = values, unit
    for k, a in enumerate(POSE_AXES):
        unit = "rad" if a == "theta" else "m"
        columns[a], units[a] = run.pose[:, k], unit
        columns[f"{a}_ref"], units[f"{a}_ref"] = run.pose_reference[:, k], unit
    return make_recording(run.time, columns, units, sample_time=TS,
                          excited="Cheung & Hung substrate move (91.4, 91.4, 123.7 mm, -0.7854 rad) -> "
                                  "(95.1, 96.9, 122.3 mm, -0.8 rad) in 70 ms",
                          fmus={"plant": PLANT_CLASS,
                                "controllers": ROBUST_CLASS if run.controller == "robust" else CT_CLASS},
                          parameters={f"c_{j}": p for j, p in zip(JOINTS, run.parameters)},
                          metadata={"controller": run.controller, "gains": source})


def plot(result: ComparisonResult, out: Path) -> list[Path]:
    """Figs. 4-7 (joint position error, both controllers) and the end-effector error, as PNGs in ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    for k, (ax, joint) in enumerate(zip(axes.flat, JOINTS)):
        for c, style in (("computed_torque", "C1"), ("robust", "C0")):
            run = result.runs[c]
            ax.plot(run.time * 1e3, run.error[:, k] * 1e6, style, lw=1, label=LABELS[c])
        ax.axhspan(-5, 5, color="0.85", zorder=0, label="+-5 um")
        ax.axvline(result.t_end * 1e3, color="k", ls=":", lw=0.8)
        ax.set_title(f"Fig. {4 + k}: position error of {joint}")
        ax.set_ylabel("r - q [um]")
        ax.grid(alpha=0.3)
    paths.append(_finish(fig, axes, out / "comparison_joint_errors.png"))

    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5), sharex=True)
    for k, (ax, axis) in enumerate(zip(axes.flat, POSE_AXES)):
        scale, unit = (1e3, "mrad") if axis == "theta" else (1e6, "um")
        for c, style in (("computed_torque", "C1"), ("robust", "C0")):
            run = result.runs[c]
            ax.plot(run.time * 1e3, run.pose_error[:, k] * scale, style, lw=1, label=LABELS[c])
        band = POSE_BANDS[k] * scale
        ax.axhspan(-band, band, color="0.85", zorder=0)
        ax.axvline(result.t_end * 1e3, color="k", ls=":", lw=0.8)
        ax.set_title(f"end-effector error in {axis}")
        ax.set_ylabel(f"[{unit}]")
        ax.grid(alpha=0.3)
    paths.append(_finish(fig, axes, out / "comparison_end_effector.png"))
    return paths


def _finish(fig, axes, path: Path) -> Path:
    """Time axis on the bottom row, legend on the first panel, the PNG written atomically and the figure closed."""
    import matplotlib.pyplot as plt

    for ax in axes[1]:
        ax.set_xlabel("time [ms]")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    write_figure(path, fig, dpi=120)
    plt.close(fig)
    return path


def write_outputs(result: ComparisonResult, out: str | Path) -> list[Path]:
    """Recordings, table.txt, table.json and the figures into ``out`` (each file written atomically)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for c, run in result.runs.items():
        written += list(write_recording(out / f"{c}.csv", recording_of(run, result.design_source)))
    atomic_write_texts({out / "table.txt": format_table(result) + "\n",
                        out / "table.json": json.dumps(table_document(result), indent=2, default=_json_default) + "\n"})
    written += [out / "table.txt", out / "table.json"]
    written += plot(result, out)
    return written


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")

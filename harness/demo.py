"""``motiontwin demo``: build the example joint FMUs and check a co-simulation against the analytic answer.

Writes ``OUT/fmi2/*.fmu``, ``OUT/fmi3/*.fmu`` and ``OUT/step_response.png``, and prints the largest
deviation of the Co-Simulation result from the closed-form step response of ``m*q'' = F - d*q'``.
"""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np

from fmus import build

JOINT = "MotionTwin.Plants.LinearMotorJoint"


def step_response(t: np.ndarray, force: float, m: float, d: float) -> np.ndarray:
    """Closed-form position of m*q'' = F - d*q' from rest."""
    return force / d * (t - m / d * (1.0 - np.exp(-d * t / m)))


def run(out: Path) -> dict[str, float]:
    """Build, simulate both FMI versions, compare with the analytic solution, plot; returns max errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    fmus = build.build([JOINT], out_dir=out)
    force, m, d = 3.0, 2.0, 10.0
    errors: dict[str, float] = {}
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for fmu in fmus:
        result = fmpy.simulate_fmu(str(fmu.path), fmi_type="CoSimulation", stop_time=1.0, output_interval=5e-4,
                                   start_values={"u": force, "m": m, "d": d}, output=["q"])
        exact = step_response(result["time"], force, m, d)
        errors[f"FMI {fmu.fmi_version}"] = float(np.max(np.abs(result["q"] - exact)))
        ax.plot(result["time"], result["q"] * 1e3, label=f"FMU, FMI {fmu.fmi_version} CS")
    ax.plot(result["time"], exact * 1e3, "k--", label="analytic")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position q [mm]")
    ax.set_title(f"{JOINT}: step force {force} N")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "step_response.png", dpi=120)
    plt.close(fig)
    for fmu in fmus:
        print(fmu.path)
    for name, err in errors.items():
        print(f"{name}: max |q_fmu - q_analytic| = {err:.2e} m")
    print(out / "step_response.png")
    return errors

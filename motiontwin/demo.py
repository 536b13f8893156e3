"""``motiontwin demo``: the project end to end on built-in example data.

1. Build the example joint FMUs (FMI 2.0 and 3.0) and check a co-simulated step response against the
   closed-form answer of ``m*q'' = F - d*q'`` (``OUT/step_response.png``).
2. Generate a closed-loop recording of an axis whose Coulomb friction the nominal model leaves out and the
   controller conceals (a few micrometres), then diagnose it: ``OUT/diagnosis/report.md`` says what is
   missing, and ``OUT/diagnosis`` holds the augmented Modelica model, its FMU and the validation fit.
"""
from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np

from motiontwin.fmus import build
from motiontwin.harness.recording import write_figure

JOINT = "MotionTwin.Plants.LinearMotorJoint"


def step_response(t: np.ndarray, force: float, m: float, d: float) -> np.ndarray:
    """Closed-form position of m*q'' = F - d*q' from rest."""
    return force / d * (t - m / d * (1.0 - np.exp(-d * t / m)))


def run(out: Path) -> dict[str, float]:
    """Both parts of the demo; returns the step-response errors and the validation RMS before/after."""
    errors = fmu_step_response(out)
    errors.update(concealed_friction(out))
    return errors


def concealed_friction(out: Path) -> dict[str, float]:
    """Write a concealed Coulomb-friction bundle (6 s + 3 s at 2 kHz) and diagnose it."""
    from motiontwin.ident import diagnosis
    from motiontwin.ident.benchmarks import single_axis as benchmark

    bundle = out / "bundle" / "coulomb_friction"
    benchmark.write_bundle(bundle, "coulomb_friction", seed=21, durations=(6.0, 3.0))
    print(f"bundle (truth in {bundle.parent / 'coulomb_friction.truth.json'}): {bundle}")
    doc = diagnosis.diagnose_bundle(bundle, out / "diagnosis")
    for effect in doc["effects"]:
        print(f"found {effect['name']} {effect['parameters']}: {effect['explanation']}")
    val = doc["validation"]
    print(f"validation RMS: nominal {val['nominal_rms']:.3g} m, augmented {val['augmented_rms']:.3g} m")
    print(out / "diagnosis" / "report.md")
    return {"nominal_rms": val["nominal_rms"], "augmented_rms": val["augmented_rms"]}


def fmu_step_response(out: Path) -> dict[str, float]:
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
    write_figure(out / "step_response.png", fig, dpi=120)
    plt.close(fig)
    for fmu in fmus:
        print(fmu.path)
    for name, err in errors.items():
        print(f"{name}: max |q_fmu - q_analytic| = {err:.2e} m")
    print(out / "step_response.png")
    return errors

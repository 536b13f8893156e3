"""Example scripts run and reproduce the figures the README quotes."""
from __future__ import annotations

from motiontwin.harness.examples import joint_bode


def test_cheung_joint_bode_matches_the_paper_transfer_function(tmp_path):
    out = tmp_path / "bode.png"
    result = joint_bode.main(["--out", str(out)])
    assert out.stat().st_size > 10_000
    assert result["max_relative_difference"] < 1e-9  # FMU linearisation vs eqs. (6)-(8)
    assert abs(result["resonance_hz"] / result["omega_hz"] - 1) < 0.02
    assert abs(result["antiresonance_hz"] / result["omega_bar_hz"] - 1) < 0.02


def test_example_loop_and_sweep_files_run_as_the_readme_shows(tmp_path):
    """harness/examples/joint_loop.toml with the README's build command, then its sweep file: the move settles
    at the 5 mm target (the loop is stable and tracks), and every Monte Carlo case of joint_sweep.toml runs with
    its own plant gain and noise seed (final positions differ between seeds, agree within the noise effect)."""
    import json
    import shutil
    from pathlib import Path

    import numpy as np

    from motiontwin.fmus import build
    from motiontwin.cli import main
    from motiontwin.harness.recording import read_recording

    examples = Path(__file__).resolve().parents[1] / "harness" / "examples"
    folder = tmp_path / "harness" / "examples"
    shutil.copytree(examples, folder, ignore=shutil.ignore_patterns("*.png", "*.py", "__pycache__"))
    shutil.copytree(examples.parent / "experiments", tmp_path / "harness" / "experiments")
    build.build(["MotionTwin.Plants.CheungJoint", "MotionTwin.Controllers.RobustJointController"],
                out_dir=tmp_path / "build" / "fmus", workers=1)
    run = tmp_path / "run.csv"
    assert main(["run", str(folder / "joint_loop.toml"), "--input",
                 f"r={tmp_path / 'harness/experiments/point_to_point_5mm.toml'}:position", "--out", str(run)]) == 0
    q = read_recording(run)["plant.q"]
    assert abs(q[-1] - 5e-3) < 5e-6 and np.max(q) < 5.2e-3   # settled near the target, overshoot < 4 %
    out = tmp_path / "sweep"
    assert main(["sweep", str(folder / "joint_sweep.toml"), "--out", str(out)]) == 0
    rows = json.loads((out / "sweep.json").read_text())["cases"]
    assert len(rows) == 60 and {r["parameters"]["plant.K"] for r in rows} == {0.7, 1.0, 1.3}
    finals = np.array([r["final"]["plant.q"] for r in rows])
    assert np.all(np.abs(finals - 5e-3) < 2e-5) and np.unique(finals).size == 60

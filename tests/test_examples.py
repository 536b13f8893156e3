"""Example scripts run and reproduce the figures the README quotes."""
from __future__ import annotations

from harness.examples import joint_bode


def test_cheung_joint_bode_matches_the_paper_transfer_function(tmp_path):
    out = tmp_path / "bode.png"
    result = joint_bode.main(["--out", str(out)])
    assert out.stat().st_size > 10_000
    assert result["max_relative_difference"] < 1e-9  # FMU linearisation vs eqs. (6)-(8)
    assert abs(result["resonance_hz"] / result["omega_hz"] - 1) < 0.02
    assert abs(result["antiresonance_hz"] / result["omega_bar_hz"] - 1) < 0.02

"""Bode/Nyquist/sensitivity figure of a tuned joint (ident.tuning.plots): the plotted curves and margin markers
against python-control on a loop built in tests/test_tuning.py from the paper's equations."""
from __future__ import annotations

import math

import matplotlib.image
import numpy as np
import pytest

from motiontwin.cli import main
from motiontwin.ident import tuning
from motiontwin.ident.tuning import plots as tuning_plots
from tests.test_tuning import NOMINAL, TS, independent_loop, python_control_margins

PLANTS = tuning.position_sets(NOMINAL)[::2]  # the light and the heavy actuator position


@pytest.fixture(scope="module")
def design() -> dict[str, float]:
    p = {k: float(tuning.TABLE2["d1"][k]) for k in tuning.DESIGN_NAMES} | {"tau": 2 * TS, "Ts": TS}
    return tuning.rescale_to_bandwidth(p, NOMINAL, 69.6)[0]


def test_figure_curves_and_markers_match_python_control(design: dict[str, float]) -> None:
    fig = tuning_plots.loop_figure(design, PLANTS, 1, ["light", "heavy"], "test", tuning.TuningSpec())
    try:
        ax_mag, ax_nyq, ax_phase, ax_sens = fig.axes[:4]
        for k, plant in enumerate(PLANTS):
            loop = independent_loop(design, plant)
            gm, pm, _, resp = python_control_margins(loop)
            # |L| curve k of the Bode axis equals the independent loop's response
            line = [ln for ln in ax_mag.get_lines() if len(ln.get_xdata()) > 100][k]
            f, db = line.get_xdata(), line.get_ydata()
            ref = np.asarray(loop(np.exp(2j * np.pi * f[::50] * TS))).ravel()
            assert np.max(np.abs(db[::50] - 20 * np.log10(np.abs(ref)))) < 1e-6
            # markers: GM cross at -10^(-GM/20) on the real axis, PM circle on the unit circle at -180 + PM
            crosses = [ln for ln in ax_nyq.get_lines() if ln.get_marker() == "x"]
            circles = [ln for ln in ax_nyq.get_lines() if ln.get_marker() == "o"]
            assert crosses[k].get_xdata()[0] == pytest.approx(-10 ** (-gm / 20), abs=2e-3)
            angle = math.radians(-180 + pm)
            assert circles[k].get_xdata()[0] == pytest.approx(math.cos(angle), abs=2e-3)
            assert circles[k].get_ydata()[0] == pytest.approx(math.sin(angle), abs=2e-3)
            # the 1/Ms circle: radius 1/max|S| = min|1 + L| around -1
            ring = [ln for ln in ax_nyq.get_lines() if ln.get_linestyle() == "-."][k]
            radius = np.hypot(ring.get_xdata() + 1, ring.get_ydata())
            assert radius == pytest.approx(np.min(np.abs(1 + resp)), rel=2e-3)
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_png_written_atomically(design: dict[str, float], tmp_path) -> None:
    out = tuning_plots.write_loop_figure(tmp_path / "figs" / "tuning_test.png", design, PLANTS[:1], 1)
    image = matplotlib.image.imread(out)
    assert image.ndim == 3 and image.shape[0] > 500 and image.shape[1] > 800
    assert [p.name for p in out.parent.iterdir()] == ["tuning_test.png"]  # no temporary file left behind



def test_replot_from_design_file(design: dict[str, float], tmp_path) -> None:
    """motiontwin plot-tuning DESIGN.json --out DIR rebuilds the plant sets from the JSON and draws them."""
    import json
    from dataclasses import asdict

    result = tuning.TuningResult(design, [tuning.loop_margins(design, PLANTS[0])], tuning.TuningSpec(), TS, 1)
    path = tmp_path / "joint.json"
    path.write_text(json.dumps(result.as_dict() | {"plants": [asdict(PLANTS[0])]}))
    assert tuning_plots.plants_from_document(json.loads(path.read_text())["plants"], "x") == [PLANTS[0]]
    assert main(["plot-tuning", str(path), "--out", str(tmp_path / "figs")]) == 0
    (png,) = (tmp_path / "figs").iterdir()
    assert png.name == "tuning_joint.png" and matplotlib.image.imread(png).ndim == 3
    assert tuning_plots.replot_design(path, tmp_path / "again") == [tmp_path / "again" / "tuning_joint.png"]
    with pytest.raises(ValueError, match=r"x: field 'plants\[0\]' is neither"):
        tuning_plots.plants_from_document(["<StateSpace>"], "x")

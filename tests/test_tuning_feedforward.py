"""Feedforward gains of eq. (12) (ident.tuning.feedforward_gains) against an analytic Taylor inverse of the loop
path and a quintic point-to-point move simulated on a loop built here with python-control."""
from __future__ import annotations

import math

import control
import numpy as np
import pytest

from motiontwin.ident import tuning
from tests.test_tuning import NOMINAL, TS, paper_controller, paper_plant

DELAY = control.tf([1.0], [1.0, 0.0], dt=TS)


@pytest.fixture(scope="module")
def design() -> dict[str, float]:
    """Table 2 d1's shape with Kp, Ki, Kd scaled to the paper's 69.6 Hz CLBW on the nominal joint (stable)."""
    p = {k: float(tuning.TABLE2["d1"][k]) for k in tuning.DESIGN_NAMES} | {"tau": 2 * TS, "Ts": TS}
    return tuning.rescale_to_bandwidth(p, NOMINAL, 69.6)[0]


def taylor_gains(p: dict[str, float]) -> tuple[float, float, float]:
    """G_f = s (s + alpha)(1 + c1 s)/(K g_L): the inverse of K/(s(s+alpha)) through the lag's DC gain g_L, with c1 the
    first-order phase lag of everything else on the path: lag, notch, resonance pair, hold (Ts/2) and delay (Ts)."""
    (w, z), (wb, zb) = NOMINAL.resonances[0], NOMINAL.antiresonances[0]
    two_pi = 2 * math.pi
    g_l = p["KL"] * p["fc"] / p["fp"]
    w0sq, bw = two_pi ** 2 * p["wl"] * p["wh"], two_pi * abs(p["wh"] - p["wl"])
    c1 = (1.5 * TS - (1 / (two_pi * p["fc"]) - 1 / (two_pi * p["fp"])) - (bw / p["sigma"] - bw) / w0sq
          - (2 * zb / wb - 2 * z / w))
    k, alpha = NOMINAL.gain, NOMINAL.alpha
    return alpha / (k * g_l), (1 + alpha * c1) / (k * g_l), c1 / (k * g_l)


def test_narrow_band_fit_is_taylor_inverse_of_low_frequency_model(design: dict[str, float]) -> None:
    kv, ka, kj = taylor_gains(design)
    fit = tuning.feedforward_gains(design, [NOMINAL], 1, (0.1, 2.0))
    assert fit.Kv == pytest.approx(kv, rel=1e-6)
    assert fit.Ka == pytest.approx(ka, rel=1e-4)
    assert fit.Kj == pytest.approx(kj, rel=0.02)  # the Taylor form drops alpha*c2 from Kj
    assert fit.residual < 1e-4
    no_jerk = tuning.feedforward_gains(design, [NOMINAL], 1, (0.1, 2.0), jerk=False)
    assert no_jerk.Kj == 0.0 and no_jerk.residual > 10 * fit.residual


def quintic(distance: float, duration: float, t: np.ndarray) -> np.ndarray:
    """Rows r, r', r'', r''' of the rest-to-rest quintic 10 s^3 - 15 s^4 + 6 s^5, s = t/duration (held after)."""
    s = np.clip(t / duration, 0, 1)
    moving = (t <= duration).astype(float)
    return np.vstack([distance * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5),
                      moving * distance / duration * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4),
                      moving * distance / duration ** 2 * (60 * s - 180 * s ** 2 + 120 * s ** 3),
                      moving * distance / duration ** 3 * (60 - 360 * s + 360 * s ** 2)])


def tracking_error(p: dict[str, float], gains: dict[str, float], ref: np.ndarray) -> np.ndarray:
    """e = S r - S P F u_f on the loop built here (Tustin eqs. 9-11, one-sample delay, ZOH eqs. 6-8)."""
    c = control.ss(control.c2d(control.ss(paper_controller(p)), TS, method="tustin"))
    s = control.tf("s")
    two_pi = 2 * np.pi
    f_lf = p["KL"] * (s + two_pi * p["fc"]) / (s + two_pi * p["fp"])
    w0sq, bw = two_pi ** 2 * p["wl"] * p["wh"], two_pi * abs(p["wh"] - p["wl"])
    f_n = (s ** 2 + bw / p["sigma"] * s + w0sq) / (s ** 2 + bw * s + w0sq)
    lag_notch = control.c2d(control.ss(f_lf * f_n), TS, method="tustin")
    plant = control.ss(DELAY) * control.c2d(control.ss(paper_plant(NOMINAL)), TS, method="zoh")
    sens = control.feedback(control.ss([], [], [], [[1.0]], dt=TS), c * plant)
    uf = gains["Kv"] * ref[1] + gains["Ka"] * ref[2] + gains["Kj"] * ref[3]
    t = np.arange(ref.shape[1]) * TS
    e_ref = control.forced_response(sens, t, ref[0]).outputs
    e_ff = control.forced_response(sens * plant * lag_notch, t, uf).outputs
    return np.asarray(e_ref - e_ff).ravel()


def test_quintic_move_error_shrinks_with_fitted_feedforward(design: dict[str, float]) -> None:
    """A 10 mm quintic move in 50 ms on the nominal joint: the fitted feedforward cuts the peak tracking error
    by more than 100x against feedback only, and the jerk term (lag/delay compensation) by more than 5x again."""
    t = np.arange(0, 0.1, TS)
    ref = quintic(0.01, 0.05, t)
    fb = np.max(np.abs(tracking_error(design, {"Kv": 0.0, "Ka": 0.0, "Kj": 0.0}, ref)))
    fit = tuning.feedforward_gains(design, [NOMINAL], 1, (0.1, 35.0))
    ff = np.max(np.abs(tracking_error(design, fit.gains(), ref)))
    fit2 = tuning.feedforward_gains(design, [NOMINAL], 1, (0.1, 35.0), jerk=False)
    ff2 = np.max(np.abs(tracking_error(design, fit2.gains(), ref)))
    assert fb > 1e-5  # feedback alone lags by tens of micrometres
    assert ff < fb / 100
    assert ff < ff2 / 5
    # the inverse of the rigid model alone (Kv = alpha/(K g_L), Ka = 1/(K g_L), what harness.comparison uses)
    g_l = design["KL"] * design["fc"] / design["fp"]
    rigid = {"Kv": NOMINAL.alpha / (NOMINAL.gain * g_l), "Ka": 1 / (NOMINAL.gain * g_l), "Kj": 0.0}
    assert ff < np.max(np.abs(tracking_error(design, rigid, ref))) / 5

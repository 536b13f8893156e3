"""Unit checks of recordings (ident.units) on the identify paths: declared units, explicit conversion,
refusal of mis-declared units.

References: the truth parameters of the simulated joint (tests/ident_truth.py) and of Cheung's joint
model (tests/test_ident_frf.py), and the same recording written in SI, which must give the same estimates
as its mm/deg twin after conversion.
"""
import numpy as np
import pytest
import scipy.signal

from motiontwin.harness import recording
from motiontwin.harness.kinematics import HEXAPOD, hexapod_inverse
from motiontwin.ident.frf import identify_frf_recording
from motiontwin.ident.hexapod import identify_hexapod_recording, random_pose_excitation
from motiontwin.ident.joint import identify_joint_recording
from motiontwin.ident.units import UnitError, checked_columns
from tests.ident_truth import JOINT_TRUTH, noisy_periods, simulate_joint_period
from tests.test_ident_frf import FS, TRUTH, _simulate

JOINT_NAMES = list(JOINT_TRUTH)
JOINT_VALUES = np.array([JOINT_TRUTH[n] for n in JOINT_NAMES])


@pytest.fixture(scope="module")
def joint_data():
    _, q, u = simulate_joint_period()
    qs, us = noisy_periods(q, u, 10, 1e-4, 0.5, np.random.default_rng(3))
    return np.arange(qs.size) * 1e-3, qs, us


@pytest.fixture(scope="module")
def sweep():
    t = np.arange(int(40 * FS)) / FS
    u = 0.1 * scipy.signal.chirp(t, f0=0.5, f1=500, t1=t[-1], method="logarithmic")
    return t, u, _simulate(u, np.random.default_rng(0))


def _rec(t, columns, units):
    return recording.make_recording(t, columns, units)


def test_wrong_kind_of_unit_is_refused_naming_column_declared_and_expected():
    t = np.arange(10) * 1e-3
    with pytest.raises(UnitError, match=r"column 'u' is declared in 'V'.*force in N or N\.m"):
        checked_columns(_rec(t, {"q": t, "u": t}, {"u": "V"}), {"q": "position", "u": "force"})
    with pytest.raises(UnitError, match=r"column 'time' is declared in 'min'.*time in s"):
        checked_columns(_rec(t, {"q": t, "u": t}, {"time": "min"}), {"q": "position", "u": "force"})
    with pytest.raises(UnitError, match=r"'q' in rad, 'u' in N mix linear and rotary"):
        checked_columns(_rec(t, {"q": t, "u": t}, {"q": "rad", "u": "N"}), {"q": "position", "u": "force"})


def test_convertible_units_are_converted_and_reported():
    t = np.arange(10) * 1e-3
    rec = _rec(t * 1e3, {"q": np.full(10, 90.0), "u": np.full(10, 2.0)}, {"time": "ms", "q": "deg", "u": "kN.m"})
    cols = checked_columns(rec, {"q": "position", "u": "force"}, source="lab.csv")
    np.testing.assert_allclose(cols.time, t, rtol=1e-15)
    np.testing.assert_allclose(cols["q"], np.pi / 2, rtol=1e-15)
    np.testing.assert_allclose(cols["u"], 2000.0, rtol=1e-15)
    assert cols.units == {"q": "rad", "u": "N.m"}
    assert any("'q' converted from deg to rad" in n for n in cols.notes)
    assert any("'time' converted from ms to s" in n for n in cols.notes)
    assert any("'u' converted from kN.m to N.m" in n for n in cols.notes)


def test_joint_in_degrees_gives_the_radian_estimates_and_the_truth(joint_data):
    t, q, u = joint_data
    kwargs = dict(min_speed=0.2)
    si, notes_si = identify_joint_recording(_rec(t, {"q": q, "u": u}, {"q": "rad", "u": "N.m"}), 0.5, 10.0, **kwargs)
    deg, notes_deg = identify_joint_recording(
        _rec(t, {"q": np.degrees(q), "u": u}, {"q": "deg", "u": "N.m"}), 0.5, 10.0, **kwargs)
    assert notes_si == [] and any("from deg to rad" in n for n in notes_deg)
    np.testing.assert_allclose(deg.fit.estimate, si.fit.estimate, rtol=1e-9)
    assert np.all(np.abs(si.fit.estimate - JOINT_VALUES) / np.abs(JOINT_VALUES) < 0.03)


def test_joint_positions_in_degrees_declared_rad_are_refused(joint_data):
    t, q, u = joint_data
    rec = _rec(t, {"q": np.degrees(q), "u": u}, {"q": "rad", "u": "N.m"})
    with pytest.raises(UnitError, match=r"fitted J = .* from the a-priori .* column 'q'"):
        identify_joint_recording(rec, 0.5, 10.0, min_speed=0.2, nominal_inertia=0.4)


def test_frf_in_mm_gives_the_metre_estimates_and_the_truth(sweep):
    t, u, q = sweep
    fit_m, _ = identify_frf_recording(_rec(t, {"u": u, "q": q}, {"q": "m", "u": "N"}))
    fit_mm, notes = identify_frf_recording(_rec(t, {"u": u, "q": 1e3 * q}, {"q": "mm", "u": "N"}))
    assert any("'q' converted from mm to m" in n for n in notes)
    np.testing.assert_allclose(fit_mm.model.to_vector(), fit_m.model.to_vector(), rtol=1e-6, atol=1e-6)
    assert fit_m.model.gain == pytest.approx(TRUTH.gain, rel=0.02)
    assert fit_m.model.alpha == pytest.approx(TRUTH.alpha, rel=0.02)


def test_frf_positions_in_mm_declared_m_are_refused(sweep):
    t, u, q = sweep
    with pytest.raises(UnitError, match=r"column 'q' declared in m has an implausible span"):
        identify_frf_recording(_rec(t, {"u": u, "q": 1e3 * q}, {"q": "m", "u": "N"}), source="sweep.csv")
    # A 0.5 kg mover (K = 2) moving 1e-3 q, recorded in mm but declared m: the motion looks plausible,
    # the fitted moving mass (1000x too small) gives it away.
    force, position_mm = u * TRUTH.gain / 2.0 * 1e-3, 1e3 * (1e-3 * q)
    with pytest.raises(UnitError, match=r"moving mass 1/K = 0.0005.* outside the plausible range.*column 'q'"):
        identify_frf_recording(_rec(t, {"u": force, "q": position_mm}, {"q": "m", "u": "N"}))


def test_hexapod_lengths_in_mm_declared_m_are_refused_before_kinematics():
    excitation = random_pose_excitation(np.array([0.06, 0.06, 0.05, 0.12, 0.12, 0.15]), 0.5, 5,
                                        np.random.default_rng(1))
    t = np.arange(400) / 200.0
    lengths = np.array([hexapod_inverse(x, HEXAPOD) for x in excitation.trajectory(t)[0]])
    columns = {f"L{i + 1}": 1e3 * lengths[:, i] for i in range(6)}
    columns.update({f"tau{i + 1}": np.ones_like(t) for i in range(6)})
    units = {f"L{i + 1}": "m" for i in range(6)}
    with pytest.raises(UnitError, match=r"column 'L1' \(declared m\) has median .* 1.01e\+03x the leg length"):
        identify_hexapod_recording(_rec(t, columns, units), 0.5, 2.5)
    with pytest.raises(UnitError, match=r"column 'L1' is declared in 'deg', but a length in m is expected"):
        identify_hexapod_recording(_rec(t, columns, {**units, "L1": "deg"}), 0.5, 2.5)


def test_hexapod_in_mm_and_kn_gives_the_si_estimates_within_their_intervals():
    from motiontwin.ident.hexapod import measure_periods
    from tests.test_ident_hexapod import F0, FS, N_PERIODS, NH, NOISE, _period, base, truth

    _, _, lengths, forces = _period()
    lengths, forces = measure_periods(lengths, forces, N_PERIODS, NOISE, np.random.default_rng(5))
    t = np.arange(len(lengths)) / FS
    names = [f"L{i + 1}" for i in range(6)] + [f"tau{i + 1}" for i in range(6)]
    si = _rec(t, dict(zip(names, np.hstack([lengths, forces]).T)), {})
    lab = _rec(t, dict(zip(names, np.hstack([1e3 * lengths, 1e-3 * forces]).T)),
               {n: "mm" if n.startswith("L") else "kN" for n in names})
    fit_si, _ = identify_hexapod_recording(si, F0, NH * F0, base=base())
    fit_lab, notes = identify_hexapod_recording(lab, F0, NH * F0, base=base())
    assert sum("converted from mm to m" in n for n in notes) == 6
    assert sum("converted from kN to N" in n for n in notes) == 6
    np.testing.assert_allclose(fit_lab.fit.estimate, fit_si.fit.estimate, rtol=1e-6)
    truth_base = base().from_full(truth().theta())
    assert np.all(np.abs(fit_si.fit.estimate - truth_base) <= 5 * fit_si.fit.std)

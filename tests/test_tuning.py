"""Tuning of the robust joint controller (ident.tuning) against independent references: analytic margins of
textbook loops, python-control on a loop built here from the paper's equations, the FMU's own binary."""
from __future__ import annotations

import math
import re

import control
import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave

from motiontwin.cli.arguments import name_values
from motiontwin.fmus import build, writeback
from motiontwin.ident import tuning
from motiontwin.ident.tuning import margins as tuning_margins
from motiontwin.ident.frf import JointModel

TS = 5e-4
NOMINAL = JointModel(1.0, 10.0, ((2450.0, 0.05),), ((1885.0, 0.05),))  # CheungJoint defaults (1 kg)
SPEC = tuning.TuningSpec(gm_min_db=7.0, pm_min_deg=40.0, pm_max_deg=60.0, ms_max=2.0, tau_max_s=0.05)


def paper_controller(p: dict[str, float]) -> control.TransferFunction:
    """Eqs. (9)-(11) built here with python-control (notch read as in the FMU docs; Hz -> rad/s), continuous."""
    s = control.tf("s")
    two_pi = 2 * np.pi
    gc = (p["Kd"] * s ** 2 + p["Kp"] * s + p["Ki"]) / (p["tau"] * s ** 2 + s)
    fl = p["KL"] * (s + two_pi * p["fc"]) / (s + two_pi * p["fp"])
    w0sq, bw = two_pi ** 2 * p["wl"] * p["wh"], two_pi * abs(p["wh"] - p["wl"])
    fn = (s ** 2 + bw / p["sigma"] * s + w0sq) / (s ** 2 + bw * s + w0sq)
    return gc * fl * fn


def paper_plant(m: JointModel) -> control.TransferFunction:
    """Eqs. (6)-(8), one resonance pair, built here."""
    s = control.tf("s")
    (w, z), (wb, zb) = m.resonances[0], m.antiresonances[0]
    return m.gain / (s * (s + m.alpha)) * (w ** 2 / wb ** 2) * (s ** 2 + 2 * zb * wb * s + wb ** 2) / (
        s ** 2 + 2 * z * w * s + w ** 2)


def independent_loop(p: dict[str, float], plant: JointModel) -> control.StateSpace:
    """Tustin controller * one sample delay * ZOH plant, all from python-control and this file."""
    c = control.c2d(control.ss(paper_controller(p)), TS, method="tustin")
    delay = control.ss(control.tf([1.0], [1.0, 0.0], dt=TS))
    return c * delay * control.c2d(control.ss(paper_plant(plant)), TS, method="zoh")


def python_control_margins(loop: control.StateSpace) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(GM [dB], PM [deg], f [Hz], L) from control.stability_margins on a dense response up to Nyquist.
    (On the LTI object itself, python-control's poly/'frd' fallback misplaces crossovers of these
    lightly damped 11th-order loops, e.g. GM -8.4 dB for the d1 loop whose Nyquist plot gives 14.4 dB.)"""
    f = np.logspace(-1, np.log10(0.9995 / (2 * TS)), 8000)
    resp = np.asarray(loop(np.exp(2j * np.pi * f * TS))).ravel()
    gm, pm, *_ = control.stability_margins((np.abs(resp), np.degrees(np.angle(resp)), 2 * np.pi * f))
    return 20 * math.log10(gm), pm, f, resp


@pytest.fixture(scope="module")
def tuned() -> tuning.TuningResult:
    return tuning.tune(tuning.position_sets(NOMINAL), TS, SPEC, seed=1, popsize=5, maxiter=8, refine=1,
                       refine_evaluations=250, progress=False, points=600)


def test_margins_of_textbook_continuous_loop() -> None:
    """L = 2/(s(s+1)(s+2)): phase crossover at sqrt(2) rad/s with |L| = 1/3 (GM = 20 log 3); gain crossover
    from the polynomial w^6 + 5 w^4 + 4 w^2 - 4 = 0."""
    w = np.logspace(-2, 2, 20000)
    s = 1j * w
    loop = 2 / (s * (s + 1) * (s + 2))
    m = tuning.margins_from_response(w / (2 * np.pi), loop, stable=True)
    roots = np.roots([1, 0, 5, 0, 4, 0, -4])
    wc = float(max(r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0))
    pm = 180 - 90 - math.degrees(math.atan(wc)) - math.degrees(math.atan(wc / 2))
    assert m.gm_db == pytest.approx(20 * math.log10(3), abs=1e-3)
    assert m.phase_crossover_hz == pytest.approx(math.sqrt(2) / (2 * np.pi), rel=1e-4)
    assert m.pm_deg == pytest.approx(pm, abs=1e-3)
    t = np.abs(loop / (1 + loop))
    assert m.ms == pytest.approx(float(np.max(1 / np.abs(1 + loop))), rel=1e-9)
    assert t[w < m.bandwidth_hz * 2 * np.pi].min() >= 1 / math.sqrt(2) - 1e-3


@pytest.mark.parametrize("k", [0.3, 0.6])
def test_margins_of_textbook_discrete_loop(k: float) -> None:
    """L(z) = k/(z(z-1)) (integrator + one sample delay): on |z| = 1, GM = -20 log k at theta = pi/3 and
    PM = 90 deg - 1.5 theta_c with theta_c = 2 asin(k/2); python-control agrees."""
    f = tuning.frequency_grid(TS, 20000)
    z = np.exp(2j * np.pi * f * TS)
    m = tuning.margins_from_response(f, k / (z * (z - 1)), stable=True)
    theta_c = 2 * math.asin(k / 2)
    assert m.gm_db == pytest.approx(-20 * math.log10(k), abs=1e-3)
    assert m.pm_deg == pytest.approx(90 - 1.5 * math.degrees(theta_c), abs=1e-3)
    gm, pm, *_ = control.stability_margins(control.tf([k], [1, -1, 0], dt=TS))
    assert m.gm_db == pytest.approx(20 * math.log10(gm), abs=1e-2)
    assert m.pm_deg == pytest.approx(pm, abs=1e-2)


@pytest.mark.parametrize("k", [0.3, 0.6])
def test_exact_crossovers_of_textbook_discrete_loop_to_round_off_on_a_coarse_grid(k: float) -> None:
    """L(z) = k/(z(z-1)) on 60 grid points: the crossovers are found on the loop itself, not interpolated on
    the grid (GM -20 log k at f = 1/(6 Ts), PM 90 deg - 1.5 theta_c at theta_c = 2 asin(k/2)) to 1e-9,
    where the grid's own interpolation is off by 1e-3 and more."""
    f = tuning.frequency_grid(TS, 60)

    def loop_at(x: float) -> complex:
        z = np.exp(2j * np.pi * x * TS)
        return k / (z * (z - 1))

    gm, pm, f_pc, f_gc = tuning_margins.exact_crossovers(loop_at, f, np.array([loop_at(x) for x in f]))
    theta_c = 2 * math.asin(k / 2)
    assert gm == pytest.approx(-20 * math.log10(k), abs=1e-9)
    assert f_pc == pytest.approx(1 / (6 * TS), rel=1e-9)
    assert pm == pytest.approx(90 - 1.5 * math.degrees(theta_c), abs=1e-9)
    assert f_gc == pytest.approx(theta_c / (2 * math.pi * TS), rel=1e-9)
    grid = tuning.margins_from_response(f, np.array([loop_at(x) for x in f]), stable=True)
    assert abs(grid.pm_deg - pm) > 1e-3


def test_loop_margins_equal_python_controls_stability_margins_on_the_cheung_loop() -> None:
    """The reported GM, PM and crossovers of the Table 2 d1 loop equal python-control's ``stability_margins``
    on the independent loop's dense response (a spline through 8000 points) to its interpolation error."""
    p = tuning.controller_defaults()
    m = tuning.loop_margins(p, NOMINAL)
    f = np.logspace(-1, np.log10(0.9995 / (2 * TS)), 8000)
    resp = np.asarray(independent_loop(p, NOMINAL)(np.exp(2j * np.pi * f * TS))).ravel()
    gm, pm, _, wpc, wgc, _ = control.stability_margins((np.abs(resp), np.degrees(np.angle(resp)), 2 * np.pi * f))
    assert m.gm_db == pytest.approx(20 * math.log10(gm), abs=1e-5)
    assert m.pm_deg == pytest.approx(pm, abs=1e-5)
    assert m.phase_crossover_hz == pytest.approx(wpc / (2 * np.pi), rel=1e-6)
    assert m.gain_crossover_hz == pytest.approx(wgc / (2 * np.pi), rel=1e-6)


def test_fmu_law_equals_paper_equations_tustin() -> None:
    """The symbolic model's Tustin matrices (what the FMU runs) = python-control's Tustin of eqs. (9)-(11)."""
    rng = np.random.default_rng(0)
    cases = [tuning.controller_defaults()] + [
        dict(Kp=10 ** rng.uniform(2, 5), Ki=10 ** rng.uniform(0, 5), Kd=10 ** rng.uniform(0, 3), tau=1e-3,
             KL=rng.uniform(1, 10), fp=rng.uniform(50, 400), fc=rng.uniform(400, 900), sigma=rng.uniform(1, 30),
             wl=rng.uniform(200, 450), wh=rng.uniform(300, 600), Ts=TS) for _ in range(3)]
    f = tuning.frequency_grid(TS, 300)
    z = np.exp(2j * np.pi * f * TS)
    for p in cases:
        fmu_law = tuning.controller_system(p)
        reference = control.c2d(paper_controller(p), TS, method="tustin")
        a, b = np.asarray(fmu_law(z)).ravel(), np.asarray(reference(z)).ravel()
        assert np.max(np.abs(a - b) / np.abs(b)) < 1e-8


def test_fast_margins_match_python_control_on_cheung_loop() -> None:
    """The search's numpy evaluation agrees with python-control's stability_margins on the Table 2 d1 loop."""
    p = tuning.controller_defaults()
    fast = tuning_margins._LoopEvaluator([NOMINAL], TS, 1).evaluate(p)[0]
    gm, pm, *_ = python_control_margins(independent_loop(p, NOMINAL))
    assert fast.stable
    assert fast.gm_db == pytest.approx(gm, abs=0.1)
    assert fast.pm_deg == pytest.approx(pm, abs=0.1)


def test_tuned_design_meets_spec_on_independent_loop(tuned: tuning.TuningResult) -> None:
    """Re-check every plant set on a loop built in this file: closed-loop poles inside the unit circle,
    GM, PM band, Ms, and the reported bandwidth."""
    assert not tuned.violations
    for plant, reported in zip(tuning.position_sets(NOMINAL), tuned.margins):
        loop = independent_loop(tuned.parameters, plant)
        assert np.all(np.abs(control.poles(control.feedback(loop, 1))) < 1)
        gm, pm, f, resp = python_control_margins(loop)
        assert abs(gm) >= SPEC.gm_min_db - 0.05
        assert SPEC.pm_min_deg - 0.1 <= pm <= SPEC.pm_max_deg + 0.1
        ms = np.max(1 / np.abs(1 + resp))
        assert ms <= SPEC.ms_max + 0.01
        t = np.abs(resp / (1 + resp))
        assert t[np.searchsorted(f, reported.bandwidth_hz)] == pytest.approx(1 / math.sqrt(2), abs=0.01)
    assert min(m.bandwidth_hz for m in tuned.margins) > 30.0


def test_infeasible_spec_names_constraint_and_value() -> None:
    """A bandwidth above the 390 Hz resonance (and 1/(6 Ts)) cannot be had with GM >= 7 dB: the error names the
    constraint, the value the best design reaches (its own re-checked margins) and the shortfall."""
    spec = tuning.TuningSpec(bandwidth_min_hz=400.0)
    message = r"CLBW >= 400 Hz infeasible: best design reaches [0-9.]+ Hz \(short by [0-9.]+ Hz\)"
    with pytest.raises(tuning.InfeasibleSpecError, match=message) as info:
        tuning.tune([NOMINAL], TS, spec, popsize=4, maxiter=4, refine=1, refine_evaluations=50, progress=False,
                    points=400)
    name, value, limit, unit = next(v for v in info.value.violations if v[0].startswith("CLBW"))
    assert (limit, unit) == (400.0, "Hz") and value < 400.0
    assert value == pytest.approx(min(m.bandwidth_hz for m in info.value.result.margins))


@pytest.mark.parametrize("plant, field", [
    (JointModel(1.0, -5.0, ((2450.0, 0.05),), ((1885.0, 0.05),)), "alpha"),
    (JointModel(1.0, 10.0, ((2450.0, -0.01),), ((1885.0, 0.05),)), "zeta[1]"),
    (JointModel(float("nan"), 10.0), "gain K"),
    (JointModel(0.0, 10.0), "gain K"),
])
def test_bad_plant_is_rejected_with_field(plant: JointModel, field: str) -> None:
    with pytest.raises(tuning.TuningError, match=re.escape(field)):
        tuning.tune([NOMINAL, plant], TS, SPEC, popsize=2, maxiter=1, progress=False)


def test_unstable_lti_plant_is_rejected() -> None:
    """s^2 - 3 s: the message names the set and the unstable pole at +3 rad/s."""
    with pytest.raises(tuning.TuningError, match=r"plant set 0: open-loop unstable poles \[\(3(\.0)?\+0j\)\] rad/s"):
        tuning.tune([control.tf([1.0], [1.0, -3.0, 0.0])], TS, SPEC, popsize=2, maxiter=1, progress=False)


def test_table2_rescaled_to_paper_bandwidth() -> None:
    """Rescaling a Table 2 design by g reaches the paper's CLBW; the scaled loop equals g times the loop."""
    rows = tuning.table2_comparison(NOMINAL, TS)
    for row in rows:
        assert row["CLBW"] == pytest.approx(row["paper CLBW"], rel=2e-3)
    d1 = rows[0]
    p = {k: float(tuning.TABLE2["d1"][k]) for k in tuning.DESIGN_NAMES} | {"tau": 2 * TS, "Ts": TS}
    p |= {"Ki": p["Ki"] / TS, "Kd": p["Kd"] * TS}   # the DSP's per-sample PID gains in continuous time
    gm, *_ = python_control_margins(float(d1["scale"]) * independent_loop(p, NOMINAL))
    assert d1["GM"] == pytest.approx(gm, abs=0.1)


def test_write_back_tuned_values_into_controller_fmu(tuned: tuning.TuningResult, tmp_path) -> None:
    """A new controller FMU whose binary defaults (read after initialisation) equal the tuned values."""
    model = build.load_model(tuning.CONTROLLER_CLASS)
    original = build.build_fmu(model, tmp_path / "orig", "2.0").path
    values = {k: v for k, v in tuned.parameters.items() if k != "Ts"}
    out = writeback.write_back(original, values, tmp_path / "tuned.fmu", {"method": "ident.tuning"})
    md = fmpy.read_model_description(str(out))
    variables = {v.name: v for v in md.modelVariables}
    for name, value in values.items():
        assert float(variables[name].start) == pytest.approx(value, rel=1e-15)
    unzipped = fmpy.extract(str(out), unzipdir=str(tmp_path / "tuned"))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="tuned")
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        got = fmu.getReal([variables[n].valueReference for n in values])
    finally:
        fmu.terminate()
        fmu.freeInstance()
    assert got == pytest.approx(list(values.values()), rel=1e-15)


def test_cli_plant_parsing_defaults_and_errors() -> None:
    """--plant fields override the CheungJoint start values; a bad field is named."""
    defaults = {"K": 1.0, "alpha": 10.0, "omega": 2450.0, "zeta": 0.05, "omega_bar": 1885.0, "zeta_bar": 0.05}
    plant = tuning.joint_model_from_fields(name_values("K=0.7, omega=2600", "--plant"), defaults)
    assert plant == JointModel(0.7, 10.0, ((2600.0, 0.05),), ((1885.0, 0.05),))
    with pytest.raises(tuning.TuningError, match=r"--plant 'K=1,mass=2': field 'mass' is not one of K, alpha"):
        tuning.joint_model_from_fields(name_values("K=1,mass=2", "--plant"), defaults, "--plant 'K=1,mass=2'")
    with pytest.raises(ValueError, match=r"--plant 'zeta=x': field 'zeta' = 'x' is not a number"):
        name_values("zeta=x", "--plant")
    with pytest.raises(ValueError, match=r"--plant 'K': field 'K' must be NAME=VALUE"):
        name_values("K", "--plant")


def test_plant_from_linearised_fmu_gives_same_margins(tmp_path) -> None:
    """The CheungJoint FMU linearised through its directional derivatives (harness.linearize) is a valid plant
    and gives the margins of the eq. (6)-(8) transfer function."""
    from motiontwin.harness.linearize import linearize

    fmu = build.build_fmu(build.load_model(tuning.PLANT_CLASS), tmp_path, "3.0").path
    plant = linearize(fmu, ["u"], ["q"])
    p = tuning.controller_defaults()
    from_fmu, from_tf = tuning.loop_margins(p, plant, points=3000), tuning.loop_margins(p, NOMINAL, points=3000)
    assert from_fmu.gm_db == pytest.approx(from_tf.gm_db, abs=1e-3)
    assert from_fmu.pm_deg == pytest.approx(from_tf.pm_deg, abs=1e-3)
    assert from_fmu.bandwidth_hz == pytest.approx(from_tf.bandwidth_hz, rel=1e-4)


def test_infeasible_upper_and_lower_bounds_say_over_or_short_by_how_much() -> None:
    """Ms <= 1.05 with CLBW >= 150 Hz on the 390 Hz resonance: every missed constraint is named with the worst
    value over the sets (recomputed here from the attached design's margins) and 'over by' / 'short by' it."""
    spec = tuning.TuningSpec(ms_max=1.05, bandwidth_min_hz=150.0)
    plants = tuning.position_sets(NOMINAL)
    with pytest.raises(tuning.InfeasibleSpecError) as info:
        tuning.tune(plants, TS, spec, popsize=4, maxiter=4, refine=1, refine_evaluations=50, progress=False,
                    points=400)
    err = info.value
    assert err.violations
    margins = [tuning.loop_margins(err.result.parameters, p) for p in plants]
    worst = {"Ms": max(m.ms for m in margins), "CLBW": min(m.bandwidth_hz for m in margins)}
    for name, value, limit, unit in err.violations:
        side = "over" if value > limit else "short"
        u = f" {unit}" if unit else ""
        assert f"{name} infeasible: best design reaches {value:.3g}{u} ({side} by {abs(limit - value):.3g}{u})" \
            in str(err)
        key = next((k for k in worst if name.startswith(k)), None)
        if key:
            assert value == pytest.approx(worst[key], rel=1e-3)
    assert any(v[0].startswith("Ms") and "over by" in str(err) for v in err.violations)


def test_tuned_document_keeps_old_fields_and_adds_feedforward(tuned: tuning.TuningResult) -> None:
    """--out JSON stays backward compatible; Kv, Ka, Kj are the least-squares inverse of the sampled path."""
    doc = tuned.as_dict()
    assert {"method", "parameters", "spec", "sample_period", "delay_samples", "margins", "violations"} <= set(doc)
    fit = tuning.feedforward_gains(tuned.parameters, tuning.position_sets(NOMINAL), 1, tuple(doc["feedforward"]
                                                                                               ["band_hz"]))
    assert {k: doc["parameters"][k] for k in ("Kv", "Ka", "Kj")} == pytest.approx(fit.gains(), rel=1e-9)
    # the inverse of K/(s(s + alpha)) through the lag's DC gain, to within the +-30 % spread of K over the sets
    g_l = tuned.parameters["KL"] * tuned.parameters["fc"] / tuned.parameters["fp"]
    assert doc["parameters"]["Ka"] * g_l * NOMINAL.gain == pytest.approx(1.0, rel=0.3)

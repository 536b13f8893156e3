"""Output-error refit (issue 5, method 6) against recordings made by an independent simulator: the
project's FMU run by fmpy (the C runtime's RODAS4 integrator), open loop and in a sampled closed loop,
with white encoder noise. Units: s, m, N."""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import fmpy
import numpy as np
import pytest
import scipy.signal as sps

from motiontwin.cli import main
from motiontwin.fmus import build, writeback
from motiontwin.harness.recording import make_recording, write_recording
from motiontwin.ident import multipleshooting as ms
from motiontwin.ident import oeloop
from motiontwin.ident import outputerror as oe
from motiontwin.ident.controller import Controller, controller_document
from tests.fmi_util import fmpy_closed_loop

CLASS = "MotionTwin.Plants.LinearMotorJoint"
TS = 5e-4                      # 2 kHz
TRUTH = {"m": 2.6, "d": 14.0}  # the Modelica defaults (start of every fit) are m = 2, d = 10
NOISE = 2e-6                   # encoder noise std [m]


@pytest.fixture(scope="module")
def model():
    return build.load_model(CLASS)


@pytest.fixture(scope="module")
def fmu(model, tmp_path_factory) -> Path:
    return build.build_fmu(model, tmp_path_factory.mktemp("oe_fmu"), "2.0").path


def multisine(n: int, amplitude: float, f_max: float, seed: int) -> np.ndarray:
    """Zero-mean sum of sines at 1..f_max Hz with random phases."""
    t = np.arange(n) * TS
    phases = np.random.default_rng(seed).uniform(0, 2 * np.pi, int(f_max))
    return amplitude * sum(np.sin(2 * np.pi * (k + 1) * t + ph) for k, ph in enumerate(phases)) / np.sqrt(f_max)


def fmpy_open_loop(fmu: Path, u: np.ndarray, values: dict[str, float]) -> np.ndarray:
    """Position of the FMU (co-simulation, input held over each step) at the sample instants."""
    t = np.arange(u.size) * TS
    signal = np.zeros(u.size, dtype=[("time", float), ("u", float)])
    signal["time"], signal["u"] = t, u
    res = fmpy.simulate_fmu(str(fmu), stop_time=t[-1], step_size=TS, output_interval=TS, input=signal,
                            output=["q"], start_values=values)
    return res["q"]


def pd_controller() -> Controller:
    """PD with a first-order derivative filter on e = r - q, Tustin-discretised: 2e4 N/m, 300 N.s/m, 1 ms."""
    kp, kd, tau = 2e4, 300.0, 1e-3
    a, b, c, d, _ = sps.cont2discrete(tuple(np.array([[v]]) for v in (-1 / tau, 1.0, -kd / tau ** 2, kp + kd / tau)),
                                     TS, "bilinear")
    return Controller(TS, np.atleast_2d(a), np.hstack([b, -b]), np.atleast_2d(c), np.hstack([d, -d]))


@pytest.fixture(scope="module")
def open_loop_data(fmu):
    n = 4000
    u = multisine(n, 20.0, 40, seed=1)
    return u, fmpy_open_loop(fmu, u, TRUTH)


def test_open_loop_recovers_fmu_parameters(model, open_loop_data):
    u, q_true = open_loop_data
    q = q_true + NOISE * np.random.default_rng(0).standard_normal(u.size)
    rec = make_recording(np.arange(u.size) * TS, {"u": u, "q": q})
    result = oe.identify(model, rec, ["m", "d"])
    est, std = result.statistics.as_dict(), dict(zip(result.statistics.names, result.statistics.std))
    for name, true in TRUTH.items():
        assert abs(est[name] / true - 1) < 2e-3, (name, est[name])
        assert abs(est[name] - true) < 4 * std[name], (name, est[name], std[name])
    assert result.fit.rms_q == pytest.approx(NOISE, rel=0.1)   # the residual is the encoder noise only


def _closed_loop_recording(fmu, n: int = 4000):
    """The PD controller and a recording of its loop closed around the FMU (truth TRUTH, encoder noise fed
    back through the controller), driven by multisine r and u_ext."""
    ctrl = pd_controller()
    rng = np.random.default_rng(2)
    r = 1e-3 * multisine(n, 1.0, 10, seed=3)
    u_ext = multisine(n, 5.0, 80, seed=4)
    q, u = fmpy_closed_loop(fmu, ctrl, r, u_ext, NOISE * rng.standard_normal(n), TRUTH, TS)
    return ctrl, make_recording(np.arange(n) * TS, {"r": r, "u": u, "q": q, "u_ext": u_ext})


def test_closed_loop_recovers_fmu_parameters(model, fmu):
    """Recording of the loop closed around the FMU (the controller sees the noise); the refit simulates the
    same sampled loop from r and u_ext and fits the position and force channels."""
    ctrl, rec = _closed_loop_recording(fmu)
    result = oe.identify(model, rec, ["m", "d"], controller=ctrl)
    est = result.statistics.as_dict()
    std = dict(zip(result.statistics.names, result.statistics.std))
    for name, true in TRUTH.items():
        assert abs(est[name] / true - 1) < 5e-3, (name, est[name])
        assert abs(est[name] - true) < 5 * std[name], (name, est[name], std[name])


def test_std_from_covariance_matches_monte_carlo(model, open_loop_data):
    """Over 40 noise realisations the spread of the estimates equals the std predicted by s^2 (J^T J)^-1
    (a 40-seed sample std is within about +-25% of the true one at 2 sigma)."""
    u, q_true = open_loop_data
    t = np.arange(u.size) * TS
    rec0 = make_recording(t, {"u": u, "q": q_true})
    loop = oe.build_loop(model, None, "x", ["m", "d"], {}, u.size, ts=TS)
    estimates, predicted = [], []
    for seed in range(40):
        rec = make_recording(t, {"u": u, "q": q_true + NOISE * np.random.default_rng(100 + seed).standard_normal(u.size)})
        fit = oe.fit(loop, rec, oe.Weights(NOISE), start=TRUTH, estimate_initial=["x"])
        stats = oe.statistics(loop, fit)
        estimates.append(stats.estimate)
        predicted.append(stats.std)
    ratio = np.std(estimates, axis=0, ddof=1) / np.mean(predicted, axis=0)
    assert np.all((ratio > 0.7) & (ratio < 1.35)), ratio
    bias = np.mean(estimates, axis=0) - [TRUTH["m"], TRUTH["d"]]
    assert np.all(np.abs(bias) < 3 * np.mean(predicted, axis=0) / np.sqrt(40)), bias
    assert rec0.time.size == u.size


def test_bounds_from_modelica_and_respected(model, open_loop_data):
    assert oe.default_bounds(model, ["m", "d"]) == {"m": (1e-9, np.inf), "d": (0.0, np.inf)}
    u, q_true = open_loop_data
    rec = make_recording(np.arange(u.size) * TS, {"u": u, "q": q_true})
    loop = oe.build_loop(model, None, "x", ["m", "d"], {}, u.size, ts=TS)
    fit = oe.fit(loop, rec, oe.Weights(NOISE), bounds={"d": (0.0, 12.0)})
    assert 0.0 <= fit.values["d"] <= 12.0 and fit.values["d"] == pytest.approx(12.0, rel=1e-6)  # truth 14: active


def test_unknown_parameter_and_missing_column(model, open_loop_data):
    u, q = open_loop_data
    rec = make_recording(np.arange(u.size) * TS, {"u": u, "q": q})
    with pytest.raises(KeyError, match="LinearMotorJoint has no free parameter 'mass'.*parameters are m, d"):
        oe.identify(model, rec, ["mass", "d"])
    with pytest.raises(KeyError, match="no column 'r'"):
        oe.identify(model, rec, ["m"], controller=pd_controller())
    with pytest.raises(KeyError, match="no column 'force'"):
        oe.identify(model, rec, ["m"], signals=oe.Signals(input="force"))


def _cli_args(recording: Path, out: Path, controller: Path | None = None) -> list[str]:
    """``motiontwin identify oe`` arguments: refit m and d of the library joint."""
    return (["identify", "oe", str(recording), "--class", CLASS, "--free", "m,d", "--out", str(out)]
            + (["--controller", str(controller)] if controller else []))


def test_cli_writes_fit_that_writeback_reproduces(fmu, open_loop_data, tmp_path, capsys):
    """identify oe -> JSON -> write-back into a new FMU -> fmpy re-simulation reproduces the fitted model."""
    u, q_true = open_loop_data
    q = q_true + NOISE * np.random.default_rng(5).standard_normal(u.size)
    csv = tmp_path / "rec.csv"
    write_recording(csv, make_recording(np.arange(u.size) * TS, {"u": u, "q": q}))
    out = tmp_path / "fit.json"
    assert main(_cli_args(csv, out)) == 0
    doc = json.loads(out.read_text())
    assert set(doc) >= {"parameters", "std", "covariance", "names", "method", "recording"}
    assert np.array(doc["covariance"]).shape == (2, 2)
    new_fmu = writeback.write_back(fmu, doc["parameters"], tmp_path / "fitted.fmu", {"method": doc["method"]})
    q_new = fmpy_open_loop(new_fmu, u, {})
    assert np.sqrt(np.mean((q_new - q) ** 2)) == pytest.approx(NOISE, rel=0.1)
    bad = tmp_path / "bad.csv"
    write_recording(bad, make_recording(np.arange(u.size) * TS, {"u": u, "x": q}))
    capsys.readouterr()
    assert main(_cli_args(bad, tmp_path / "never.json")) == 1
    assert re.search(r"bad.csv, row 1: required column 'q' missing", capsys.readouterr().err)
    assert not (tmp_path / "never.json").exists()


def test_cli_closed_loop_controller_file(tmp_path, model, fmu):
    ctrl = pd_controller()
    path = tmp_path / "controller.json"
    path.write_text(json.dumps(controller_document(ctrl)))
    n = 1500
    r = 1e-3 * multisine(n, 1.0, 10, seed=6)
    u_ext = multisine(n, 5.0, 80, seed=7)
    q, u = fmpy_closed_loop(fmu, ctrl, r, u_ext, np.zeros(n), TRUTH, TS)
    csv = tmp_path / "loop.csv"
    write_recording(csv, make_recording(np.arange(n) * TS, {"r": r, "u": u, "q": q, "u_ext": u_ext}))
    out = tmp_path / "fit.json"
    assert main(_cli_args(csv, out, path)) == 0
    est = json.loads(out.read_text())["parameters"]
    assert est["m"] == pytest.approx(TRUTH["m"], rel=1e-3) and est["d"] == pytest.approx(TRUTH["d"], rel=1e-3)


def _chain_inputs(loop: oe.Loop, n: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    ns = loop.model.x.numel() + (loop.controller.n_states if loop.closed else 0)
    W = np.vstack([1e-3 * np.sin(np.arange(n) * TS * 2 * np.pi * 3), rng.standard_normal(n),
                   NOISE * rng.standard_normal(n)])
    return 1e-4 * rng.standard_normal(ns), W, loop.theta(TRUTH), loop.pfix()


def _relative_error(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.max(np.abs(b))
    return float(np.max(np.abs(a - b)) / scale) if scale > 0 else float(np.max(np.abs(a)))


def pid_controller(kp: float, ki: float, kd: float, tau: float) -> Controller:
    """PID with a first-order derivative filter on e = r - q (two states, a full A), Tustin-discretised."""
    num, den = np.polyadd(np.polymul([kp, ki], [tau, 1.0]), [kd, 0.0, 0.0]), np.polymul([1.0, 0.0], [tau, 1.0])
    a, b, c, d, _ = sps.cont2discrete(sps.tf2ss(num, den), TS, "bilinear")
    return Controller(TS, a, np.hstack([b, -b]), c, np.hstack([d, -d]))


def exact_closed_loop(ctrl: Controller, values: dict[str, float], s0: np.ndarray, W: np.ndarray) -> np.ndarray:
    """q at the sample instants of m dv/dt = u - d v (exact zero-order-hold discretisation) in the loop of
    ``ctrl`` on [r, q + noise], u = controller + u_ext (W's rows r, u_ext, noise)."""
    m, d = values["m"], values["d"]
    ad, bd, *_ = sps.cont2discrete((np.array([[0.0, 1.0], [0.0, -d / m]]), np.array([[0.0], [1 / m]]),
                                    np.eye(2), np.zeros((2, 1))), TS, "zoh")
    x, z, q = s0[:2].copy(), s0[2:].copy(), np.empty(W.shape[1])
    for k in range(W.shape[1]):
        q[k] = x[0]
        y = np.array([W[0, k], x[0] + W[2, k]])
        u = ctrl.C @ z + ctrl.D @ y + W[1, k]
        z = ctrl.A @ z + ctrl.B @ y
        x = ad @ x + bd[:, 0] * u[0]
    return q


def test_a_second_controller_of_the_same_pattern_reuses_the_compiled_chain(model, tmp_path, monkeypatch):
    """The controller's nonzero entries are inputs of the compiled step, not constants folded into its C code:
    the loop of a second controller with the same nonzero pattern compiles nothing, and each loop's free run and
    Jacobian follow its own gains (against the exact discretisation of the linear plant in the same loop, and
    its finite differences)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    n = 600
    controllers = [pid_controller(2e4, 1e5, 300.0, 1e-3), pid_controller(8e3, 2e4, 90.0, 5e-4)]
    libraries = []
    for ctrl in controllers:
        loop = oe.build_loop(model, ctrl, "x", ["m", "d"], {}, n, ts=TS, substeps=8, native=True)
        libraries.append(sorted(p.name for p in (tmp_path / "motiontwin" / "ident").glob("*.so")))
        s0, W, theta, pfix = _chain_inputs(loop, n, seed=5)
        q, _ = loop.sim(s0, W, theta, pfix)
        reference = exact_closed_loop(ctrl, TRUTH, s0, W)
        assert _relative_error(q[0], reference) < 1e-9
        dq = loop.jac(s0, W, theta, pfix)[0]
        for k, name in enumerate(["m", "d"]):
            step = 1e-6 * TRUTH[name]
            up, down = ({**TRUTH, name: TRUTH[name] + sign * step} for sign in (1, -1))
            slope = (exact_closed_loop(ctrl, up, s0, W) - exact_closed_loop(ctrl, down, s0, W)) / (2 * step)
            assert _relative_error(dq[:, k], slope) < 1e-5
    assert libraries[0] and libraries[1] == libraries[0]
    assert _relative_error(exact_closed_loop(controllers[1], TRUTH, s0, W),
                           exact_closed_loop(controllers[0], TRUTH, s0, W)) > 0.1


@pytest.mark.parametrize("closed", [False, True])
def test_compiled_chain_matches_casadi_mapaccum(model, closed):
    """The C chain (generated step + driver) and CasADi's own mapaccum chain of the same step function give
    the same free run and the same sensitivity Jacobian."""
    n = 1500
    ctrl = pd_controller() if closed else None
    loops = [oe.build_loop(model, ctrl, "x", ["m", "d"], {}, n, ts=TS, substeps=4, native=native)
             for native in (True, False)]
    assert not isinstance(loops[0].sim, __import__("casadi").Function)
    args = _chain_inputs(loops[0], n, seed=3)
    for fast, ref in zip(loops[0].sim(*args), loops[1].sim(*args)):
        assert np.shape(fast) == ref.shape and _relative_error(fast, ref) < 1e-12
    for fast, ref in zip(loops[0].jac(*args), loops[1].jac(*args)):
        assert np.shape(fast) == ref.shape and _relative_error(fast, ref) < 1e-12


@pytest.mark.parametrize("closed", [False, True])
def test_a_step_of_many_substeps_is_one_substep_chained_and_gives_the_written_out_values(model, closed,
                                                                                           monkeypatch):
    """A small plant at many RK4 substeps (a stiff LuGre bristle state takes 100+) is built as one substep chained
    in a loop, not written out: its step and sensitivity step do not grow with the substeps (written out, the
    KUKA robot test's compiled from 1-11 MB of C, 800 s of gcc on a cold cache), with the written-out step's free
    run and Jacobian (CasADi's own evaluation of both, so no compiler is needed here)."""
    n = 300
    ctrl = pd_controller() if closed else None

    default = oeloop.INLINE_STEP_INSTRUCTIONS

    def loop(substeps: int, limit: int) -> oe.Loop:
        monkeypatch.setattr(oeloop, "INLINE_STEP_INSTRUCTIONS", limit)
        return oe.build_loop(model, ctrl, "x", ["m", "d"], {}, n, ts=TS, substeps=substeps, native=False)

    sizes = {k: loop(k, 0).step.n_instructions() for k in (8, 64)}
    assert sizes[8] == sizes[64] < loop(8, 10 ** 9).step.n_instructions()
    # the default threshold chains 1024 substeps of this plant (9 instructions) and writes 2 out
    assert loop(1024, default).step.n_instructions() == sizes[8] and loop(2, default).step.is_a("SXFunction")
    chained, written = loop(64, 0), loop(64, 10 ** 9)
    args = _chain_inputs(written, n, seed=4)
    for a, b in zip(chained.sim(*args), written.sim(*args)):
        assert _relative_error(a, b) < 1e-12
    for a, b in zip(chained.jac(*args), written.jac(*args)):
        assert np.size(b) and _relative_error(a, b) < 1e-12


def test_casadis_chains_are_built_when_first_called_and_give_the_compiled_chains_values(model, monkeypatch):
    """Without the compiled chain (``native=False``) the free run and Jacobian are CasADi ``mapaccum`` chains, built
    on their first call: a caller that only steps the loop (the k-step-ahead score) builds none (0.37 s each on the
    KUKA test's 64-substep loop); once called they give the compiled chain's values."""
    n = 400
    built = []
    real_chain = oeloop._chain
    monkeypatch.setattr(oeloop, "_chain", lambda *args: built.append(args[1]) or real_chain(*args))
    lazy = oe.build_loop(model, pd_controller(), "x", ["m", "d"], {}, n, ts=TS, substeps=4, native=False)
    assert built == [] and lazy.step is not None
    compiled = oe.build_loop(model, pd_controller(), "x", ["m", "d"], {}, n, ts=TS, substeps=4, native=True)
    args = _chain_inputs(compiled, n, seed=6)
    for a, b in zip(lazy.sim(*args), compiled.sim(*args)):
        assert _relative_error(a, b) < 1e-12
    assert built == [n]
    for a, b in zip(lazy.jac(*args), compiled.jac(*args)):
        assert np.size(b) and _relative_error(a, b) < 1e-12
    lazy.sim(*args)
    assert built == [n, n]


def test_initial_state_sensitivities_of_chosen_states_only(model):
    """A loop compiled with the start sensitivities of some states gives the same parameter columns and, for
    those states, the same start columns as one compiled with every state's; the fit's Jacobian refuses a
    state whose columns were not compiled (a wrong estimate, not a silent zero)."""
    n = 600
    ctrl = pd_controller()
    full, some = (oe.build_loop(model, ctrl, "x", ["m", "d"], {}, n, ts=TS, substeps=4, initial_states=states)
                  for states in (None, [2]))
    assert full.initial_states == (0, 1, 2) and some.initial_states == (2,)
    args = _chain_inputs(full, n, seed=5)
    jq, ju, jq0, ju0 = full.jac(*args)
    sq, su, sq0, su0 = some.jac(*args)
    np.testing.assert_array_equal(sq, jq)
    np.testing.assert_array_equal(su, ju)
    assert np.shape(sq0)[1] == 1 and np.abs(jq0[:, 2]).max() > 0
    np.testing.assert_array_equal(np.ravel(sq0), jq0[:, 2])
    np.testing.assert_array_equal(np.ravel(su0), ju0[:, 2])
    weights = oe.Weights(1e-6, 1e-2)
    columns = oe.weighted_jacobian(some, *args, [2], weights)
    np.testing.assert_array_equal(columns, oe.weighted_jacobian(full, *args, [2], weights))
    with pytest.raises(ValueError, match=r"states \[0\]"):
        oe.weighted_jacobian(some, *args, [0], weights)


def test_compiled_chain_cached_and_fallback_without_compiler(model, monkeypatch, tmp_path):
    """The library is compiled once per generated source (second build reuses the cached file); without a
    working C compiler the loop falls back to the CasADi chain (unless the compiled one is demanded)."""
    from motiontwin.ident import chain

    casadi_chains = []      # the CasADi chains built, each when its loop's free run is first called
    real_chain = oeloop._chain
    monkeypatch.setattr(oeloop, "_chain", lambda *args: casadi_chains.append(args[1]) or real_chain(*args))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    oe.build_loop(model, None, "x", ["m"], {}, 50, ts=TS, substeps=2)
    built = sorted((tmp_path / "motiontwin" / "ident").glob("chain-*.so"))
    mtime = built[0].stat().st_mtime_ns
    native = oe.build_loop(model, None, "x", ["m"], {}, 50, ts=TS, substeps=2)
    assert sorted((tmp_path / "motiontwin" / "ident").glob("chain-*.so")) == built
    assert built[0].stat().st_mtime_ns == mtime
    monkeypatch.setenv("CC", "no-such-compiler-motiontwin")
    assert not chain.available()
    fallback = oe.build_loop(model, None, "x", ["m"], {}, 50, ts=TS, substeps=2)
    args = _chain_inputs(native, 50, seed=4)
    assert _relative_error(native.sim(*args)[0], fallback.sim(*args)[0]) < 1e-12
    assert casadi_chains == [50]
    monkeypatch.setenv("MOTIONTWIN_NATIVE_CHAIN", "0")
    monkeypatch.delenv("CC")
    assert not chain.available()
    monkeypatch.delenv("MOTIONTWIN_NATIVE_CHAIN")
    monkeypatch.setenv("CC", "false")   # a "compiler" that always fails
    oe.build_loop(model, None, "x", ["m"], {}, 50, ts=TS, substeps=2).sim(*args)
    assert casadi_chains == [50, 50]
    with pytest.raises(RuntimeError, match="compiling"):
        oe.build_loop(model, None, "x", ["m"], {}, 50, ts=TS, substeps=2, native=True)


def _agree(a: oe.OutputErrorResult, b: oe.OutputErrorResult) -> np.ndarray:
    """|a - b| of the estimates in units of b's standard deviation."""
    return np.abs(a.statistics.estimate - b.statistics.estimate) / b.statistics.std


def test_multiple_shooting_open_loop_recovers_truth_and_matches_single(model, open_loop_data):
    u, q_true = open_loop_data
    q = q_true + NOISE * np.random.default_rng(0).standard_normal(u.size)
    rec = make_recording(np.arange(u.size) * TS, {"u": u, "q": q})
    single = oe.identify(model, rec, ["m", "d"])
    multiple = oe.identify(model, rec, ["m", "d"], shooting="multiple", segments=4)
    est, std = multiple.statistics.as_dict(), dict(zip(multiple.statistics.names, multiple.statistics.std))
    for name, true in TRUTH.items():
        assert abs(est[name] / true - 1) < 2e-3, (name, est[name])
        assert abs(est[name] - true) < 4 * std[name], (name, est[name], std[name])
    assert multiple.fit.success
    assert np.all(_agree(multiple, single) < 1e-3), _agree(multiple, single)
    assert multiple.statistics.std == pytest.approx(single.statistics.std, rel=1e-6)
    assert multiple.fit.cost == pytest.approx(single.fit.cost, rel=1e-9)


def test_multiple_shooting_closed_loop_recovers_truth_and_matches_single(model, fmu):
    """The loop state at each node holds the plant and the controller states."""
    ctrl, rec = _closed_loop_recording(fmu)
    single = oe.identify(model, rec, ["m", "d"], controller=ctrl)
    multiple = oe.identify(model, rec, ["m", "d"], controller=ctrl, shooting="multiple", segments=4)
    est, std = multiple.statistics.as_dict(), dict(zip(multiple.statistics.names, multiple.statistics.std))
    for name, true in TRUTH.items():
        assert abs(est[name] / true - 1) < 5e-3, (name, est[name])
        assert abs(est[name] - true) < 5 * std[name], (name, est[name], std[name])
    assert multiple.fit.success
    assert np.all(_agree(multiple, single) < 1e-3), _agree(multiple, single)


def test_cli_multiple_shooting(open_loop_data, tmp_path, capsys):
    from motiontwin.cli import main

    u, q_true = open_loop_data
    q = q_true + NOISE * np.random.default_rng(5).standard_normal(u.size)
    csv = tmp_path / "rec.csv"
    write_recording(csv, make_recording(np.arange(u.size) * TS, {"u": u, "q": q}))
    out = tmp_path / "fit.json"
    assert main(["identify", "oe", str(csv), "--class", CLASS, "--free", "m,d", "--shooting", "multiple",
                 "--segments", "4", "--out", str(out)]) == 0
    assert "multiple shooting, 4 segments" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["method"].startswith("output-error refit, CasADi multiple shooting (4 segments, IPOPT")
    assert doc["converged"] and np.array(doc["covariance"]).shape == (2, 2)
    for name, true in TRUTH.items():
        assert abs(doc["parameters"][name] - true) < 4 * doc["std"][name], (name, doc["parameters"][name])
    assert main(["identify", "oe", str(csv), "--class", CLASS, "--free", "m,d", "--shooting", "multiple",
                 "--segments", "0"]) == 1
    assert "non-empty segments" in capsys.readouterr().err


UNSTABLE = """model UnstableJoint "Mass on a negative spring (a linearised magnetic bearing): m*der(v) = u - d*v + k*x"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 4 "viscous damping";
  parameter Real k(unit = "N/m", min = 0) = 100 "negative stiffness";
  input Real u(unit = "N") "actuator force";
  output Real q(unit = "m") "position";
  Real x(unit = "m", start = 0, fixed = true) "position state";
  Real v(unit = "m/s", start = 0, fixed = true) "velocity state";
equation
  der(x) = v;
  m * der(v) = u - d * v + k * x;
  q = x;
end UnstableJoint;
"""


def test_multiple_shooting_unstable_plant_from_poor_start(tmp_path):
    """Open-loop unstable plant (pole at +6.1 rad/s, growth 1e4 over the 1.5 s record), start 3x off on each
    parameter (m, d x3, k /3): single shooting with identify's budget of 50 free runs stalls far from the
    optimum (it needs a few hundred), multiple shooting over 4 segments reaches it. The data is the exact
    ZOH discretisation of the truth (scipy), not the refit's RK4."""
    (tmp_path / "UnstableJoint.mo").write_text(UNSTABLE)
    model = build.load_model("UnstableJoint", tmp_path / "UnstableJoint.mo")
    truth, ts, n = {"m": 2.0, "d": 4.0, "k": 100.0}, 1e-3, 1500
    t = np.arange(n) * ts
    phases = np.random.default_rng(1).uniform(0, 2 * np.pi, 20)
    u = sum(np.sin(2 * np.pi * (j + 1) * t + ph) for j, ph in enumerate(phases)) / np.sqrt(20)
    a = np.array([[0.0, 1.0], [truth["k"] / truth["m"], -truth["d"] / truth["m"]]])
    ad, bd, *_ = sps.cont2discrete((a, np.array([[0.0], [1 / truth["m"]]]), np.eye(2), np.zeros((2, 1))), ts)
    x, q = np.zeros(2), np.zeros(n)
    for i in range(n):
        q[i], x = x[0], ad @ x + bd[:, 0] * u[i]
    sigma = 1e-3 * np.std(q)
    rec = make_recording(t, {"u": u, "q": q + sigma * np.random.default_rng(0).standard_normal(n)})
    loop = oe.build_loop(model, None, "x", ["m", "d", "k"], truth, n, ts=ts)
    weights, start = oe.Weights(sigma), {"m": 6.0, "d": 12.0, "k": 100.0 / 3}
    best = oe.fit(loop, rec, weights, start=truth, estimate_initial=["x"])
    std = oe.statistics(loop, best).std
    single = oe.fit(loop, rec, weights, start=start, estimate_initial=["x"], max_nfev=50)
    multiple = ms.fit(loop, rec, weights, 4, start=start, estimate_initial=["x"])
    assert single.cost > 5 * best.cost, (single.values, single.cost, best.cost)
    assert multiple.success and multiple.cost == pytest.approx(best.cost, rel=1e-9)
    estimate = loop.theta(multiple.values)
    assert np.all(np.abs(estimate - loop.theta(truth)) < 3 * std), (multiple.values, std)
    assert np.all(np.abs(estimate - loop.theta(best.values)) < 1e-3 * std)
    assert oe.fit(loop, rec, weights, start=start, estimate_initial=["x"], max_nfev=400).cost == \
        pytest.approx(best.cost, rel=1e-9)


def test_multiple_shooting_arguments(model, open_loop_data):
    u, q = open_loop_data
    rec = make_recording(np.arange(u.size) * TS, {"u": u, "q": q})
    loop = oe.build_loop(model, None, "x", ["m", "d"], {}, u.size, ts=TS)
    with pytest.raises(ValueError, match="non-empty segments"):
        ms.fit(loop, rec, oe.Weights(NOISE), 0)
    with pytest.raises(ValueError, match="hessian must be"):
        ms.fit(loop, rec, oe.Weights(NOISE), 4, hessian="bfgs")
    with pytest.raises(ValueError, match="shooting must be"):
        oe.identify(model, rec, ["m"], shooting="double")


#: Coulomb level and constant force of the PrismaticAxis truth; the plant file's defaults are Fc = F0 = 0
COULOMB = {"m": 2.6, "d": 14.0, "Fc": 0.8, "F0": 1.5, "v_eps": 5e-3}


def test_parameters_starting_at_zero_reach_the_truth(tmp_path):
    """Fc and F0 of a PrismaticAxis start at 0 (its defaults), free, on the loop closed around its FMU with
    Coulomb friction and a constant force: the refit reaches the truth, and multiple shooting started at
    those zeros reaches the single-shooting optimum (1e-6 relative). A zero start is scaled by what the data
    ask for (``oefit.parameter_scale``); scaled by 1e-12, IPOPT stopped short of it (d 3e-5 off, 11 instead of
    6 evaluations), and scipy's step test (xtol, relative to the scaled variables' norm) can stop the
    single-shooting fit as soon as such a parameter has moved."""
    model = build.load_model("MotionTwin.Plants.PrismaticAxis")
    fmu = build.build_fmu(model, tmp_path, "2.0").path
    n = 3000
    ctrl = pd_controller()
    r = 2e-3 * multisine(n, 1.0, 6, seed=5)
    u_ext = multisine(n, 5.0, 80, seed=6)
    q, u = fmpy_closed_loop(fmu, ctrl, r, u_ext, NOISE * np.random.default_rng(7).standard_normal(n), COULOMB, TS)
    rec = make_recording(np.arange(n) * TS, {"r": r, "u": u, "q": q, "u_ext": u_ext})
    free, start = ["m", "d", "Fc", "F0"], {"v_eps": COULOMB["v_eps"], "Fc": 0.0, "F0": 0.0}
    result = oe.identify(model, rec, free, controller=ctrl, start=start)
    est, std = result.statistics.as_dict(), dict(zip(result.statistics.names, result.statistics.std))
    for name in free:
        assert abs(est[name] / COULOMB[name] - 1) < 0.02, (name, est[name])
        assert abs(est[name] - COULOMB[name]) < 5 * std[name], (name, est[name], std[name])
    loop = oe.build_loop(model, ctrl, "q", free, {"m": 2.0, "d": 10.0, **start}, n)
    weights = oe.Weights(NOISE, float(np.sqrt(np.mean((u - result.fit.u_sim) ** 2))))
    single, multiple = oe.fit(loop, rec, weights), ms.fit(loop, rec, weights, 4)
    assert single.success and multiple.success
    for name in free:
        assert multiple.values[name] == pytest.approx(single.values[name], rel=1e-6), name
        assert single.values[name] == pytest.approx(est[name], rel=1e-3), name


def test_a_start_whose_free_run_nearly_overflows_does_not_stop_the_fit(tmp_path):
    """The unstable plant started at k = 2.9e5 (truth 100): its free run reaches 3.8e242, finite, but the squares
    of its residual are not, and scipy's trust region then failed on NaN. Each sample's weighted residual is
    capped (``oefit.RESIDUAL_LIMIT``, as a non-finite one already was): the fit returns, with the diverged run's
    true cost, inf, where it could not move."""
    (tmp_path / "UnstableJoint.mo").write_text(UNSTABLE)
    model = build.load_model("UnstableJoint", tmp_path / "UnstableJoint.mo")
    ts, n = 1e-3, 1500
    t = np.arange(n) * ts
    rec = make_recording(t, {"u": np.sin(2 * np.pi * 3 * t), "q": np.zeros(n)})
    loop = oe.build_loop(model, None, "x", ["k"], {"m": 2.0, "d": 4.0, "k": 100.0}, n, ts=ts)
    q, _ = oe.simulate(loop, rec, {"k": 2.9e5})
    assert np.all(np.isfinite(q)) and np.max(np.abs(q)) > 1e200
    result = oe.fit(loop, rec, oe.Weights(1e-6), start={"k": 2.9e5}, max_nfev=10)
    assert result.cost == np.inf and result.values["k"] == pytest.approx(2.9e5)


def test_the_fit_reports_the_values_its_last_point_gives_without_running_it_again(model, fmu):
    """The fit keeps the solver's last Jacobian and its last accepted point's free run (issue 25): its cost,
    residual, simulation and Jacobian equal those computed afresh at the values it returns (the reference), and
    it runs no free run beyond the solver's own evaluations and the start's."""
    ctrl, rec = _closed_loop_recording(fmu, n=2000)
    loop = oe.build_loop(model, ctrl, "x", ["m", "d"], {"m": 3.0, "d": 10.0}, rec.time.size)
    weights = oe.Weights(NOISE, 0.05)
    runs, jacobians = [], []
    sim, jac = loop.sim, loop.jac
    loop = dataclasses.replace(loop, sim=lambda *a: runs.append(1) or sim(*a),
                               jac=lambda *a: jacobians.append(1) or jac(*a))
    fit = oe.fit(loop, rec, weights, start={"m": 3.0, "d": 10.0}, max_nfev=10)
    r, q, u = oe.residuals(loop, rec, fit.values, weights)
    assert fit.cost == oe.squared_norm(r) and np.array_equal(fit.residual, r)
    assert np.array_equal(fit.q_sim, q) and np.array_equal(fit.u_sim, u)
    values = fit.values
    s0 = oe.initial_state(loop, rec, values)
    reference = oe.weighted_jacobian(loop, s0, oe.drive(rec, signals=loop.channels, closed=True), loop.theta(values),
                                     np.array([values[n] for n in loop.fixed]), [], weights)
    np.testing.assert_allclose(fit.jacobian, reference, rtol=1e-12, atol=0)
    assert len(runs) - 1 <= fit.nfev + 1      # the solver's free runs and the start's check; -1: the reference's
    assert len(jacobians) - 1 <= fit.nfev     # one per accepted point at most; -1: the reference's

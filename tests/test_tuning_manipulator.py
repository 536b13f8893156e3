"""Per-actuator tuning on the CheungManipulator FMU (ident.tuning.manipulator) against analytic properties of the
rigid model M(d) dv/dt + c_v v = u at rest and against single-loop python-control results."""
from __future__ import annotations

import control
import numpy as np
import pytest

from motiontwin.fmus import build
from motiontwin.ident import tuning
from motiontwin.ident.tuning import manipulator as tm
from tests.test_tuning import NOMINAL, TS


@pytest.fixture(scope="module")
def fmu(tmp_path_factory) -> str:
    return str(build.build_fmu(build.load_model(tm.MANIPULATOR_CLASS), tmp_path_factory.mktemp("manip"), "3.0").path)


@pytest.fixture(scope="module")
def poses() -> np.ndarray:
    return tm.workspace_poses(2)


def test_channel_is_integrator_over_viscous_friction(fmu: str, poses: np.ndarray) -> None:
    """At rest with g = 0, q_i/u_i = e_i' (M s + c_v I)^-1 e_i / s: one pole at 0, s q/u -> 1/c_v = 0.2 s/kg as
    s -> 0 whatever the pose, and s^2 q/u -> (M^-1)_ii, the B-matrix entry of the linearisation, as s -> inf."""
    for mimo in tm.linearize_poses(fmu, poses):
        for i in range(4):
            channel = tm.actuator_channel(mimo, i, f"actuator {i}")
            poles = control.poles(channel)
            assert np.sum(np.abs(poles) < 1e-9) == 1 and np.all(poles.real <= 1e-9)
            assert complex(channel(1e-6j) * 1e-6j).real == pytest.approx(1 / 5.0, rel=1e-6)
            w = 1e6j
            assert complex(channel(w) * w ** 2).real == pytest.approx(mimo.B[4 + i, i], rel=1e-4)


def test_gravity_makes_the_channel_unstable_and_tune_says_so(fmu: str, poses: np.ndarray) -> None:
    """With gravity the rest pose is not an equilibrium of eq. (7): positive real poles, named by tune."""
    heavy = tm.linearize_poses(fmu, poses[:1], gravity=True)[0]
    assert np.max(control.poles(heavy).real) > 0.1
    with pytest.raises(tuning.TuningError, match=r"plant set 0: open-loop unstable poles \[\(0\.\d+"):
        tuning.tune([heavy[0, 0]], TS, popsize=2, maxiter=1, progress=False)


def test_decentralised_radius_of_decoupled_plant_is_single_loop_radius() -> None:
    """Four identical, uncoupled joints under four identical controllers: the MIMO closed loop's spectral radius
    is the single loop's (python-control feedback of tuning.loop_system)."""
    p = {k: float(tuning.TABLE2["d1"][k]) for k in tuning.DESIGN_NAMES} | {"tau": 2 * TS, "Ts": TS}
    p = tuning.rescale_to_bandwidth(p, NOMINAL, 69.6)[0]
    joint = control.ss(NOMINAL.transfer_function())
    radius = tm.decentralised_radius([p] * 4, control.append(joint, joint, joint, joint))
    single = np.max(np.abs(control.poles(control.feedback(tuning.loop_system(p, NOMINAL), 1))))
    assert radius == pytest.approx(single, abs=1e-9)
    assert radius < 1


def test_pose_outside_workspace_is_named() -> None:
    with pytest.raises(tuning.TuningError, match=r"pose 1 .* outside the Table 1 ranges"):
        tm.workspace_poses(2, ((0.0, 0.0, 0.0, 0.0), (0.02, 0.02, 0.0, 0.0)))


def test_per_actuator_design_document(fmu: str, poses: np.ndarray) -> None:
    """A short search on two poses: one design per actuator, margins recomputed per pose, JSON per joint."""
    design = tm.tune_manipulator(fmu, poses, NOMINAL, TS, tuning.TuningSpec(pm_min_deg=40), seed=1, popsize=4,
                                 maxiter=3, refine=1, refine_evaluations=30, progress=False, points=300)
    doc = design.as_dict()
    assert list(doc["joints"]) == ["d1", "d3", "d5", "d7"]
    for name, result, plants in zip(tm.ACTUATORS, design.results, design.plants):
        joint = doc["joints"][name]
        assert set(tuning.DESIGN_NAMES) | {"Kv", "Ka", "Kj"} <= set(joint["parameters"])
        assert len(joint["margins"]) == len(poses) == len(plants)
        # the channel times H(s) of eq. (8): high-frequency mass line of the plant unchanged by H (unit DC gain)
        again = tuning.loop_margins(result.parameters, plants[-1], points=2000)
        assert again.stable == result.margins[-1].stable
        if again.stable:
            assert again.gm_db == pytest.approx(result.margins[-1].gm_db, abs=0.05)
    assert len(doc["coupled_closed_loop_radius"]["with_gravity"]) == len(poses)

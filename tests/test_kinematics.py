"""harness.kinematics: round trips, the paper's poses, and Jacobians against finite differences."""
import itertools

import numpy as np
import pytest

from motiontwin.harness import kinematics as kin


def _workspace_poses() -> list[np.ndarray]:
    """Grid over the ~35 x 35 x 6 mm workspace around the paper's poses, plus the two paper poses."""
    grid = itertools.product(np.linspace(0.080, 0.105, 6), np.linspace(0.080, 0.105, 6),
                             np.linspace(0.1205, 0.1250, 4), np.linspace(-0.95, -0.62, 5))
    poses = [np.array(p) for p in grid]
    with np.errstate(invalid="ignore"):  # poses outside the reachable set give NaN and are dropped
        poses = [p for p in poses if kin.cheung_in_range(kin.cheung_inverse(p))]
    return [kin.CHEUNG_START_POSE, kin.CHEUNG_END_POSE] + poses


def test_cheung_round_trip_over_workspace():
    poses = _workspace_poses()
    assert len(poses) > 50
    for pose in poses:
        d = kin.cheung_inverse(pose)
        assert np.all(np.isfinite(d))
        np.testing.assert_allclose(kin.cheung_forward(d), pose, rtol=0, atol=1e-9)
        np.testing.assert_allclose(kin.cheung_inverse(kin.cheung_forward(d)), d, rtol=0, atol=1e-9)


def test_cheung_paper_poses_reachable_and_consistent_with_eq3():
    """Start/end poses map into the Table 1 actuator ranges and satisfy eq. (3) as printed."""
    for pose in (kin.CHEUNG_START_POSE, kin.CHEUNG_END_POSE):
        d = kin.cheung_inverse(pose)
        assert kin.cheung_in_range(d)
        (x1, y1), (x2, y2) = kin.cheung_points(d)
        assert x1 > x2 and y1 < y2  # the paper's workspace assumption
        assert np.arctan((y2 - y1) / (x2 - x1)) == pytest.approx(pose[3], abs=1e-12)
        assert (x1 + x2) / 2 == pytest.approx(pose[0], abs=1e-12)
    # Symmetric start pose: d5 = d3 and d7 = d1 (to the 4-digit precision of the paper's pose)
    d = kin.cheung_inverse(kin.CHEUNG_START_POSE)
    assert d[2] == pytest.approx(d[1], abs=1e-6) and d[3] == pytest.approx(d[0], abs=1e-6)


def test_cheung_forward_from_actuator_grid():
    g = kin.CHEUNG
    for d in itertools.product(np.linspace(g.d_min[0], g.d_max[0], 5), np.linspace(g.d_min[1], g.d_max[1], 5),
                               np.linspace(g.d_min[2], g.d_max[2], 5), np.linspace(g.d_min[3], g.d_max[3], 5)):
        d = np.array(d)
        (x1, y1), (x2, y2) = kin.cheung_points(d)
        if not (x1 > x2 and y1 < y2):
            continue
        np.testing.assert_allclose(kin.cheung_inverse(kin.cheung_forward(d)), d, rtol=0, atol=1e-9)


def test_hexapod_direct_inverts_inverse():
    rng = np.random.default_rng(1)
    for _ in range(50):
        pose = kin.HEXAPOD_HOME + rng.uniform([-0.1, -0.1, -0.1, -0.2, -0.2, -0.3], [0.1, 0.1, 0.1, 0.2, 0.2, 0.3])
        lengths = kin.hexapod_inverse(pose)
        np.testing.assert_allclose(kin.hexapod_direct(lengths), pose, rtol=0, atol=1e-9)


def test_hexapod_inverse_is_symmetric_at_home():
    lengths = kin.hexapod_inverse(kin.HEXAPOD_HOME)
    a, b = kin.hexapod_anchors()
    np.testing.assert_allclose(lengths, lengths[0], rtol=1e-14)
    # independent check of one leg by the law of cosines in the XY projection
    planar = np.hypot(*(a[0, :2] - b[0, :2]))
    assert lengths[0] == pytest.approx(np.hypot(planar, kin.HEXAPOD_HOME[2]), rel=1e-14)


def test_anchors_handed_out_are_copies_of_the_ones_the_kinematics_keep():
    """The kinematics compute the anchors once per geometry; changing the arrays a caller got changes nothing."""
    before = kin.hexapod_inverse(kin.HEXAPOD_HOME)
    a, b = kin.hexapod_anchors()
    a[:] = 0.0
    b[:] = 0.0
    np.testing.assert_array_equal(kin.hexapod_inverse(kin.HEXAPOD_HOME), before)
    assert np.ptp(kin.hexapod_anchors()[0]) > 0


def test_hexapod_length_jacobian_matches_finite_differences():
    pose = np.array([0.03, -0.02, 0.78, 0.1, -0.05, 0.2])
    jac = kin.hexapod_length_jacobian(pose)
    h = 1e-6
    fd = np.column_stack([(kin.hexapod_inverse(pose + h * e) - kin.hexapod_inverse(pose - h * e)) / (2 * h)
                          for e in np.eye(6)])
    np.testing.assert_allclose(jac, fd, rtol=0, atol=1e-8)


def test_rotation_and_angular_velocity_map_agree():
    """H maps angle rates to the world angular velocity: skew(w) = dR/dt R^T."""
    angles, rates = np.array([0.3, -0.4, 0.7]), np.array([0.2, -0.5, 0.9])
    h = 1e-6
    r_dot = (kin.rotation(angles + h * rates) - kin.rotation(angles - h * rates)) / (2 * h)
    skew = r_dot @ kin.rotation(angles).T
    w = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
    np.testing.assert_allclose(kin.angular_velocity_map(angles) @ rates, w, atol=1e-9)


def test_hexapod_direct_reports_non_convergence():
    with pytest.raises(RuntimeError):
        kin.hexapod_direct(np.full(6, 0.01))  # shorter than rB - rP: unreachable


def test_pose_rates_to_twist_matches_finite_differences():
    """w = H x_dot and w_dot = H x_ddot + H_dot x_dot along a smooth pose trajectory."""
    def pose_at(t):
        return kin.HEXAPOD_HOME + np.array([0.01, -0.02, 0.03, 0.2, -0.1, 0.3]) * np.sin(3 * t + np.arange(6))

    t, h = 0.4, 1e-5
    pose = pose_at(t)
    pose_dot = (pose_at(t + h) - pose_at(t - h)) / (2 * h)
    pose_ddot = (pose_at(t + h) - 2 * pose + pose_at(t - h)) / h**2
    twist, twist_dot = kin.pose_rates_to_twist(pose, pose_dot, pose_ddot)

    def twist_at(tt):
        return kin.pose_rates_to_twist(pose_at(tt), (pose_at(tt + h) - pose_at(tt - h)) / (2 * h), pose_ddot)[0]

    np.testing.assert_allclose(twist_dot, (twist_at(t + h) - twist_at(t - h)) / (2 * h), atol=1e-4)
    np.testing.assert_allclose(twist[:3], pose_dot[:3])

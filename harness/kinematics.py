"""Kinematics of the two parallel manipulators, as plain numpy functions for trajectory planning.

SI units throughout (m, rad). Mirrors the Modelica functions ``MotionTwin.Plants.Cheung*Kinematics``
and ``MotionTwin.Plants.HexapodLegLengths`` (same geometry defaults).

4-DOF manipulator (Cheung & Hung, eqs. (2)-(5), Table 1). Actuators ``d = [d1, d3, d5, d7]``, pose
``[x, y, z, theta]``. Two errata of the paper are corrected here:

- eq. (5), fourth line: ``d7 = y2 - sqrt(l^2 - (x2 - dx)^2)`` (the paper repeats ``d5``);
- eq. (4), the y lines: ``y1 = y + r*sin(theta)``, ``y2 = y - r*sin(theta)`` with
  ``r = sqrt(k^2 - (z - dz)^2)``. As printed (``y1 = y - r sin``), eq. (4) contradicts eq. (3)
  (it gives ``tan(theta) = -(y2 - y1)/(x2 - x1)``) and the workspace assumption ``y1 < y2``, and the
  paper's start pose would need ``|y1 - dy| > l``.

6-DOF hexapod (PaLiDA-like, Abdellatif & Heimann): pose ``[x, y, z, a, b, c]`` with the platform
orientation ``R = Rx(a) @ Ry(b) @ Rz(c)``; legs are the distances between base anchors ``A_j`` and
platform anchors ``p + R b_j``. Velocities are twists ``[v; w]`` (world frame), eq. (16) of the paper.
:func:`hexapod_regressor` is the linear-in-parameters form (eq. (7)) of ``MotionTwin.Plants.Hexapod``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CheungGeometry:
    """Table 1 dimensions: link lengths l = l2 = l4 = l6 = l8, k = k10 = k12, offsets dx, dy, dz (m)."""

    l: float = 0.070
    k: float = 0.1166
    dx: float = 0.010
    dy: float = 0.010
    dz: float = 0.010
    d_min: tuple[float, float, float, float] = (0.0595, 0.1195, 0.1195, 0.0595)  # d1, d3, d5, d7
    d_max: tuple[float, float, float, float] = (0.0995, 0.1595, 0.1595, 0.0995)


CHEUNG = CheungGeometry()

#: The paper's point-to-point move (Section 5): start and end pose (m, m, m, rad).
CHEUNG_START_POSE = np.array([0.0914, 0.0914, 0.1237, -0.7854])
CHEUNG_END_POSE = np.array([0.0951, 0.0969, 0.1223, -0.8])


def cheung_points(d: np.ndarray, geom: CheungGeometry = CHEUNG) -> tuple[np.ndarray, np.ndarray]:
    """Joint points P = (x1, y1) and Q = (x2, y2) from actuator positions, eq. (2)."""
    d1, d3, d5, d7 = np.asarray(d, dtype=float)
    p = np.array([(d1 + d3) / 2, np.sqrt(geom.l**2 - (d3 - d1) ** 2 / 4) + geom.dy])
    q = np.array([np.sqrt(geom.l**2 - (d5 - d7) ** 2 / 4) + geom.dx, (d5 + d7) / 2])
    return p, q


def cheung_forward(d: np.ndarray, geom: CheungGeometry = CHEUNG) -> np.ndarray:
    """End-effector pose [x, y, z, theta] from actuator positions [d1, d3, d5, d7], eqs. (2)-(3)."""
    (x1, y1), (x2, y2) = cheung_points(d, geom)
    z = np.sqrt(geom.k**2 - ((x2 - x1) ** 2 + (y2 - y1) ** 2) / 4) + geom.dz
    theta = np.arctan2(y1 - y2, x1 - x2)  # = atan((y2 - y1)/(x2 - x1)) for x1 > x2
    return np.array([(x1 + x2) / 2, (y1 + y2) / 2, z, theta])


def cheung_inverse(pose: np.ndarray, geom: CheungGeometry = CHEUNG) -> np.ndarray:
    """Actuator positions [d1, d3, d5, d7] from the pose [x, y, z, theta], eqs. (4)-(5) (errata applied)."""
    x, y, z, theta = np.asarray(pose, dtype=float)
    r = np.sqrt(geom.k**2 - (z - geom.dz) ** 2)
    x1, x2 = x + r * np.cos(theta), x - r * np.cos(theta)
    y1, y2 = y + r * np.sin(theta), y - r * np.sin(theta)
    h1 = np.sqrt(geom.l**2 - (y1 - geom.dy) ** 2)
    h2 = np.sqrt(geom.l**2 - (x2 - geom.dx) ** 2)
    return np.array([x1 - h1, x1 + h1, y2 + h2, y2 - h2])


def cheung_in_range(d: np.ndarray, geom: CheungGeometry = CHEUNG) -> bool:
    """True when all actuator positions lie in their Table 1 ranges (condition (1))."""
    d = np.asarray(d, dtype=float)
    return bool(np.all(d >= np.array(geom.d_min)) and np.all(d <= np.array(geom.d_max)))


@dataclass(frozen=True)
class HexapodGeometry:
    """Symmetric 6-6 Stewart-Gough geometry (m, rad); anchor pairs at 120 deg spacing.

    Base anchors lie at angles 0, 120, 240 deg +- ``base_half_angle`` on a circle of ``base_radius``
    in the plane z = 0; platform anchors at 60, 180, 300 deg +- ``platform_half_angle`` on a
    circle of ``platform_radius`` in the platform frame's z = 0 plane.
    """

    base_radius: float = 0.5
    platform_radius: float = 0.1
    base_half_angle: float = np.deg2rad(10.0)
    platform_half_angle: float = np.deg2rad(10.0)


HEXAPOD = HexapodGeometry()

#: Home pose of the default hexapod (m, rad).
HEXAPOD_HOME = np.array([0.0, 0.0, 0.8, 0.0, 0.0, 0.0])


def hexapod_anchors(geom: HexapodGeometry = HEXAPOD) -> tuple[np.ndarray, np.ndarray]:
    """Base anchors A (6x3, world) and platform anchors b (6x3, platform frame), leg j = row j."""
    a, b = _anchors(geom)
    return a.copy(), b.copy()


@functools.lru_cache(maxsize=8)
def _anchors(geom: HexapodGeometry) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hexapod_anchors`, computed once per geometry (the direct kinematics asks for them per Newton step
    of every sample); read-only, shared."""
    gb, gp = geom.base_half_angle, geom.platform_half_angle
    third = 2 * np.pi / 3
    base_angles = np.array([gb, third - gb, third + gb, 2 * third - gb, 2 * third + gb, 3 * third - gb])
    plat_angles = np.array([third / 2 - gp, third / 2 + gp, 1.5 * third - gp, 1.5 * third + gp,
                            2.5 * third - gp, 2.5 * third + gp])
    a = geom.base_radius * np.column_stack([np.cos(base_angles), np.sin(base_angles), np.zeros(6)])
    b = geom.platform_radius * np.column_stack([np.cos(plat_angles), np.sin(plat_angles), np.zeros(6)])
    a.flags.writeable = b.flags.writeable = False
    return a, b


def rotation(angles: np.ndarray) -> np.ndarray:
    """Rotation matrix R = Rx(a) @ Ry(b) @ Rz(c) of the platform frame."""
    a, b, c = angles
    ca_, sa = np.cos(a), np.sin(a)
    cb, sb = np.cos(b), np.sin(b)
    cc, sc = np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca_, -sa], [0, sa, ca_]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rx @ ry @ rz


def angular_velocity_map(angles: np.ndarray) -> np.ndarray:
    """H(angles) with omega_world = H @ d(angles)/dt for R = Rx(a) Ry(b) Rz(c)."""
    a, b, _ = angles
    return np.array([[1, 0, np.sin(b)],
                     [0, np.cos(a), -np.sin(a) * np.cos(b)],
                     [0, np.sin(a), np.cos(a) * np.cos(b)]])


def hexapod_inverse(pose: np.ndarray, geom: HexapodGeometry = HEXAPOD) -> np.ndarray:
    """Leg lengths (6,) from the pose [x, y, z, a, b, c]."""
    return _legs(np.asarray(pose, dtype=float), geom)[1]


def hexapod_length_jacobian(pose: np.ndarray, geom: HexapodGeometry = HEXAPOD) -> np.ndarray:
    """d(leg lengths)/d(pose) (6x6): row j = [u_j, (r_j x u_j) @ H] with u_j the leg unit vector."""
    pose = np.asarray(pose, dtype=float)
    return _length_jacobian(pose, *_legs(pose, geom))


def _legs(pose: np.ndarray, geom: HexapodGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(platform anchors in the world frame relative to p, leg lengths, leg vectors) at ``pose``."""
    a, b = _anchors(geom)
    r = b @ rotation(pose[3:]).T
    legs = pose[:3] + r - a
    return r, np.linalg.norm(legs, axis=1), legs


def _length_jacobian(pose: np.ndarray, r: np.ndarray, lengths: np.ndarray, legs: np.ndarray) -> np.ndarray:
    u = legs / lengths[:, None]
    (r0, r1, r2), (u0, u1, u2) = r.T, u.T      # r x u row by row, as np.cross forms it (same round-off)
    cross = np.column_stack([r1 * u2 - r2 * u1, r2 * u0 - r0 * u2, r0 * u1 - r1 * u0])
    return np.hstack([u, cross @ angular_velocity_map(pose[3:])])


def hexapod_direct(lengths: np.ndarray, geom: HexapodGeometry = HEXAPOD, guess: np.ndarray | None = None,
                   tol: float = 1e-13, max_iter: int = 50) -> np.ndarray:
    """Pose from leg lengths by Newton-Raphson, starting from ``guess`` (default: the home pose).

    Raises ``RuntimeError`` when the iteration does not converge (e.g. a guess on another assembly
    branch or near a singular configuration).
    """
    lengths = np.asarray(lengths, dtype=float)
    pose = np.array(HEXAPOD_HOME if guess is None else guess, dtype=float)
    for _ in range(max_iter):
        r, now, legs = _legs(pose, geom)
        residual = now - lengths
        if np.max(np.abs(residual)) < tol:
            return pose
        pose = pose - np.linalg.solve(_length_jacobian(pose, r, now, legs), residual)
    if np.max(np.abs(hexapod_inverse(pose, geom) - lengths)) < 1e3 * tol:
        return pose
    raise RuntimeError(f"hexapod direct kinematics did not converge in {max_iter} iterations")


def angular_velocity_map_rate(angles: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """Time derivative of :func:`angular_velocity_map` along the angle rates."""
    a, b, _ = angles
    da, db, _ = rates
    return np.array([[0, 0, np.cos(b) * db],
                     [0, -np.sin(a) * da, -np.cos(a) * np.cos(b) * da + np.sin(a) * np.sin(b) * db],
                     [0, np.cos(a) * da, -np.sin(a) * np.cos(b) * da - np.cos(a) * np.sin(b) * db]])


def pose_rates_to_twist(pose: np.ndarray, pose_dot: np.ndarray, pose_ddot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Twist [v; w] and its derivative from pose rates, eq. (16): w = H x_dot, w_dot = H x_ddot + H_dot x_dot."""
    h = angular_velocity_map(pose[3:])
    h_dot = angular_velocity_map_rate(pose[3:], pose_dot[3:])
    twist = np.concatenate([pose_dot[:3], h @ pose_dot[3:]])
    twist_dot = np.concatenate([pose_ddot[:3], h @ pose_ddot[3:] + h_dot @ pose_dot[3:]])
    return twist, twist_dot


#: Parameter order of :func:`hexapod_regressor` (names as in ``MotionTwin.Plants.Hexapod``).
HEXAPOD_PARAMETERS = (["mE", "IxxE", "IyyE", "IzzE", "m3", "I2", "s2"]
                      + [f"rc{j}" for j in range(1, 7)] + [f"cv{j}" for j in range(1, 7)])


def hexapod_regressor(pose: np.ndarray, twist: np.ndarray, twist_dot: np.ndarray, geom: HexapodGeometry = HEXAPOD,
                      g: float = 9.81, v_eps: float = 1e-3) -> np.ndarray:
    """Regressor A (6 x 19) with leg forces tau = A @ p, p ordered as :data:`HEXAPOD_PARAMETERS`.

    Rigid-body columns: generalised (world force; moment about the platform origin) of each
    parameter, mapped to leg forces through the transposed leg Jacobian (eq. (5)); friction columns:
    tanh(dL/v_eps) and dL of each leg (eq. (6), here acting directly on the legs).
    """
    pose, twist, twist_dot = (np.asarray(x, dtype=float) for x in (pose, twist, twist_dot))
    v, w = twist[:3], twist[3:]
    acc, alpha = twist_dot[:3], twist_dot[3:]
    rot = rotation(pose[3:])
    base, plat = hexapod_anchors(geom)
    ez = np.array([0.0, 0.0, 1.0])
    phi = np.zeros((6, 7))
    phi[:3, 0] = acc + g * ez
    for k in range(3):
        axis = rot[:, k]
        phi[3:, 1 + k] = axis * (axis @ alpha) + np.cross(w, axis) * (axis @ w)
    wrench = np.zeros((6, 6))
    l_dot = np.zeros(6)
    for j in range(6):
        r = rot @ plat[j]
        leg = pose[:3] + r - base[j]
        length = np.linalg.norm(leg)
        u = leg / length
        v_b = v + np.cross(w, r)
        a_b = acc + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
        l_dot[j] = u @ v_b
        u_dot = (v_b - l_dot[j] * u) / length
        forces = {4: a_b + g * ez,
                  5: (a_b - (u @ a_b) * u - 2 * l_dot[j] * u_dot) / length**2,
                  6: g * (ez - u[2] * u) / length}
        for col, f in forces.items():
            phi[:3, col] += f
            phi[3:, col] += np.cross(r, f)
        wrench[:, j] = np.concatenate([u, np.cross(r, u)])
    rigid = np.linalg.solve(wrench, phi)
    return np.hstack([rigid, np.diag(np.tanh(l_dot / v_eps)), np.diag(l_dot)])

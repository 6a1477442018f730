"""Oracle tests of the frame conventions: `core.frames` (body FLU → world ENU, ZYX Euler angles,
R = Rz(ψ)·Ry(θ)·Rx(φ)) and the ENU↔NED / FLU↔FRD conversions of `link.wire` that MAVLink needs.

Reference rotations are built here from elementary matrices, independently of the code under test.
"""

import math

import numpy as np
import pytest

from quadpilot.core import frames
from quadpilot.link import wire

RNG = np.random.default_rng(2024)
# random attitudes away from the Euler singularity at pitch ±90°
ANGLES = np.column_stack(
    [RNG.uniform(-math.pi, math.pi, 64), RNG.uniform(-1.5, 1.5, 64), RNG.uniform(-math.pi, math.pi, 64)]
)


def rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rot(roll, pitch, yaw) -> np.ndarray:
    return frames.euler_to_rotmat(np.array(roll, float), np.array(pitch, float), np.array(yaw, float))


EX, EY, EZ = np.eye(3)
Q = math.pi / 2


@pytest.mark.parametrize(
    "angles, body, world, why",
    [
        ((0, 0, Q), EX, EY, "yaw +90°: the nose (body x) points along world y (north)"),
        ((0, 0, Q), EY, -EX, "yaw +90°: the left side points west"),
        ((Q, 0, 0), EY, EZ, "roll +90° (FLU): the left side points up"),
        ((Q, 0, 0), EZ, -EY, "roll +90°: body up points to world −y (the right side is down)"),
        ((0, Q, 0), EX, -EZ, "pitch +90° (FLU): the nose points down"),
        ((0, Q, 0), EZ, EX, "pitch +90°: body up points forward"),
        ((0, 0, math.pi), EX, -EX, "yaw 180°"),
    ],
)
def test_known_rotations(angles, body, world, why):
    np.testing.assert_allclose(rot(*angles) @ body, world, atol=1e-12, err_msg=why)


def test_euler_to_rotmat_is_rz_ry_rx_in_that_order():
    for roll, pitch, yaw in ANGLES[:16]:
        np.testing.assert_allclose(rot(roll, pitch, yaw), rz(yaw) @ ry(pitch) @ rx(roll), atol=1e-12)
    # the order matters: XYZ gives a different matrix for the same numbers
    assert not np.allclose(rot(0.3, 0.4, 0.5), rx(0.3) @ ry(0.4) @ rz(0.5), atol=1e-3)


def test_rotation_matrices_are_proper_and_orthonormal():
    r = frames.euler_to_rotmat(ANGLES[:, 0], ANGLES[:, 1], ANGLES[:, 2])
    assert r.shape == (64, 3, 3)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)


def test_rotmat_to_euler_inverts_euler_to_rotmat():
    r = frames.euler_to_rotmat(ANGLES[:, 0], ANGLES[:, 1], ANGLES[:, 2])
    roll, pitch, yaw = frames.rotmat_to_euler(r)
    np.testing.assert_allclose(np.column_stack([roll, pitch, yaw]), ANGLES, atol=1e-9)
    # hand value: R = Rz(0.5)·Ry(−0.2)·Rx(0.1) gives back (0.1, −0.2, 0.5)
    out = frames.rotmat_to_euler(rz(0.5) @ ry(-0.2) @ rx(0.1))
    np.testing.assert_allclose(out, (0.1, -0.2, 0.5), atol=1e-12)


def quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def axis_quat(axis, angle):
    return np.array([math.cos(angle / 2), *(math.sin(angle / 2) * np.asarray(axis, float))])


def test_euler_to_quaternion_is_the_hamilton_product_qz_qy_qx():
    for roll, pitch, yaw in ANGLES[:16]:
        expected = quat_mul(quat_mul(axis_quat(EZ, yaw), axis_quat(EY, pitch)), axis_quat(EX, roll))
        got = frames.euler_to_quaternion(np.array(roll), np.array(pitch), np.array(yaw))
        np.testing.assert_allclose(got * np.sign(got[0]), expected * np.sign(expected[0]), atol=1e-12)
        back = frames.quaternion_to_euler(got)
        np.testing.assert_allclose(back, (roll, pitch, yaw), atol=1e-9)
    # hand value: yaw 90° is (cos 45°, 0, 0, sin 45°)
    q = frames.euler_to_quaternion(np.array(0.0), np.array(0.0), np.array(Q))
    np.testing.assert_allclose(q, [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], atol=1e-12)


def test_world_to_body_and_back():
    r = frames.euler_to_rotmat(ANGLES[:, 0], ANGLES[:, 1], ANGLES[:, 2])
    v = RNG.normal(size=(64, 3))
    np.testing.assert_allclose(frames.body_to_world(r, frames.world_to_body(r, v)), v, atol=1e-12)
    np.testing.assert_allclose(frames.world_to_body(r, frames.body_to_world(r, v)), v, atol=1e-12)
    # yaw +90°: north (world y) is straight ahead (body x); the body's forward is north
    r90 = rot(0, 0, Q)[None]
    np.testing.assert_allclose(frames.world_to_body(r90, EY[None]), EX[None], atol=1e-12)
    np.testing.assert_allclose(frames.body_to_world(r90, EX[None]), EY[None], atol=1e-12)
    # rolled +90° (left side up): body +y points up, so world down (−z) is body −y
    np.testing.assert_allclose(frames.world_to_body(rot(Q, 0, 0)[None], -EZ[None]), -EY[None], atol=1e-12)


# --- MAVLink frames (link.wire) ------------------------------------------------------------------


def test_enu_ned_and_flu_frd_vector_conversions():
    # ENU (east, north, up) → NED (north, east, down)
    np.testing.assert_array_equal(wire.enu_to_ned(np.array([1.0, 2.0, 3.0])), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(wire.ned_to_enu(np.array([2.0, 1.0, -3.0])), [1.0, 2.0, 3.0])
    # FLU (forward, left, up) → FRD (forward, right, down)
    np.testing.assert_array_equal(wire.flu_to_frd(np.array([1.0, 2.0, 3.0])), [1.0, -2.0, -3.0])
    np.testing.assert_array_equal(wire.frd_to_flu(np.array([1.0, -2.0, -3.0])), [1.0, 2.0, 3.0])
    v = RNG.normal(size=(8, 3))
    np.testing.assert_allclose(wire.ned_to_enu(wire.enu_to_ned(v)), v, atol=0)
    np.testing.assert_allclose(wire.frd_to_flu(wire.flu_to_frd(v)), v, atol=0)


def test_ned_frd_rotation_maps_the_same_physical_vectors():
    """M = rotmat_enu_flu_to_ned_frd(R) must rotate a body vector written in FRD to the same physical
    vector written in NED: M·flu_to_frd(b) = enu_to_ned(R·b), and stay a proper rotation."""
    for roll, pitch, yaw in ANGLES[:16]:
        r = rot(roll, pitch, yaw)
        m = wire.rotmat_enu_flu_to_ned_frd(r)
        b = RNG.normal(size=3)
        np.testing.assert_allclose(m @ wire.flu_to_frd(b), wire.enu_to_ned(r @ b), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-12)


def test_attitude_in_ned_frd_by_hand():
    """Facing east in ENU (yaw 0) is heading 90° in NED, so yaw_ned = π/2 − yaw_enu. Roll keeps its
    number (FLU +roll lifts the left side, FRD +roll lowers the right side: the same motion); pitch
    changes sign (FLU +pitch is nose down, FRD +pitch nose up)."""
    for roll, pitch, yaw in [(0.0, 0.0, 0.0), (0.1, 0.2, 0.3), (0.3, -0.4, 2.5), (-0.2, 0.1, -1.0)]:
        s = np.zeros(12)
        s[6:9] = roll, pitch, yaw
        r_ned, p_ned, y_ned = wire.attitude_ned_frd(s)
        expected_yaw = math.remainder(math.pi / 2 - yaw, 2 * math.pi)
        np.testing.assert_allclose((r_ned, p_ned, y_ned), (roll, -pitch, expected_yaw), atol=1e-12)


def test_quaternion_on_the_wire_by_hand():
    """Level, facing east (ENU yaw 0): body FRD → NED is a +90° turn about NED down,
    q = (cos 45°, 0, 0, sin 45°); facing north (ENU yaw 90°): the identity."""
    s = np.zeros(12)
    fields = wire.hil_state_quaternion_fields(s, wire.Home(), 0)
    np.testing.assert_allclose(fields["attitude_quaternion"], [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], atol=1e-12)
    s[8] = Q
    fields = wire.hil_state_quaternion_fields(s, wire.Home(), 0)
    np.testing.assert_allclose(fields["attitude_quaternion"], [1.0, 0, 0, 0], atol=1e-12)
    # quaternion ↔ matrix round trip, w ≥ 0
    for roll, pitch, yaw in ANGLES[:16]:
        m = wire.rotmat_enu_flu_to_ned_frd(rot(roll, pitch, yaw))
        q = wire.rotmat_to_quaternion(m)
        assert q[0] >= 0
        np.testing.assert_allclose(wire.quaternion_to_rotmat(q), m, atol=1e-12)

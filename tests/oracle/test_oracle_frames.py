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


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_pitch_of_plus_minus_ninety_degrees_survives_rounding_beyond_one(sign):
    """At pitch ∓90° the sine that arcsin inverts rounds to just beyond ±1 in floating point: the
    quaternion (√½, 0, ±√½, 0) has 2·(w·y − z·x) = ±1.0000000000000002, and the matrix written out
    from it R31 = 2·(x·z − w·y) = ∓1.0000000000000002. Both must give pitch ±90°, not NaN."""
    h = math.sqrt(0.5)
    w, x, y, z = h, 0.0, sign * h, 0.0
    assert abs(2 * (w * y - z * x)) > 1.0  # the rounding this test is about
    _, pitch, _ = frames.quaternion_to_euler(np.array([w, x, y, z]))
    assert float(pitch) == sign * math.pi / 2
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    assert abs(r[2, 0]) > 1.0
    _, pitch, _ = frames.rotmat_to_euler(r)
    assert float(pitch) == sign * math.pi / 2


def test_rotation_matrix_keeps_the_precision_of_its_angles():
    """float32 angles give a float32 matrix; a float64 angle among float32 ones is not rounded to
    float32 in the entries it enters: R31 = −sin θ, R32 = cos θ·sin φ, R21 = sin ψ·cos θ."""
    r32, p32, y32 = np.float32(0.1), np.float32(0.2), np.float32(0.3)
    assert frames.euler_to_rotmat(r32, p32, y32).dtype == np.float32
    roll, pitch, yaw = 0.1 + 1e-9, 0.2 + 1e-9, 0.3 + 1e-9  # not float32 numbers
    cp32 = float(np.cos(p32))  # what a float32 pitch contributes, exactly
    m = frames.euler_to_rotmat(np.float64(roll), p32, y32)
    assert m.dtype == np.float64
    assert float(m[2, 1]) == pytest.approx(cp32 * math.sin(roll), rel=1e-15, abs=0)
    m = frames.euler_to_rotmat(r32, np.float64(pitch), y32)
    assert float(m[2, 0]) == -math.sin(pitch)
    m = frames.euler_to_rotmat(r32, p32, np.float64(yaw))
    assert float(m[1, 0]) == pytest.approx(math.sin(yaw) * cp32, rel=1e-15, abs=0)


# rotations where Shepperd's method must pick its branch with care: half turns (w = 0), ties on the
# diagonal, trace exactly 0 (a third of a turn about (1, 1, 1)), and near half turns
def axis_angle(axis, angle) -> np.ndarray:
    n = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


HARD_ROTATIONS = [
    axis_angle(axis, angle)
    for axis in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1), (1, -2, 0.5))
    for angle in (math.pi, math.pi - 1e-6, 2 * math.pi / 3, math.pi / 2, 1e-9)
] + [np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])]  # trace 0


def test_quaternion_of_hard_rotations_reproduces_the_matrix():
    for r in HARD_ROTATIONS:
        q = wire.rotmat_to_quaternion(r)
        assert q[0] >= 0.0
        assert float(np.linalg.norm(q)) == pytest.approx(1.0, abs=1e-15)
        np.testing.assert_allclose(wire.quaternion_to_rotmat(q), r, rtol=0, atol=1e-12)


def test_scalar_wire_quaternion_equals_the_matrix_path_at_hard_attitudes():
    """`ned_frd_quaternion` (scalar Shepperd) against rotmat_to_quaternion(E·R·F) where the branches
    meet: level headings every 45°, half turns in roll, nose straight up and down."""
    for roll in (0.0, math.pi / 2, math.pi, -math.pi / 2, 2.0):
        for pitch in (0.0, math.pi / 2, -math.pi / 2, 0.7):
            for yaw in np.arange(-4, 5) * math.pi / 4:
                r = frames.euler_to_rotmat(np.array(roll), np.array(pitch), np.array(yaw))
                m = wire.rotmat_enu_flu_to_ned_frd(r)
                q = np.array(wire.ned_frd_quaternion(roll, pitch, yaw))
                assert q[0] >= 0.0 and float(np.linalg.norm(q)) == pytest.approx(1.0, abs=1e-15)
                np.testing.assert_allclose(wire.quaternion_to_rotmat(q), m, rtol=0, atol=1e-12)


def test_wire_rotations_are_computed_in_float64_and_normalised():
    """A float32 rotation (rounded: columns off unit length by ~1e-7) gives the quaternion of its
    float64 values, of unit length to 1e-15; a quaternion of any length gives the rotation of its
    direction, computed in float64 from float32 input too."""
    r = frames.euler_to_rotmat(np.array(0.3), np.array(-0.4), np.array(2.5))
    r32 = r.astype(np.float32)
    q = wire.rotmat_to_quaternion(r32)
    np.testing.assert_allclose(q, wire.rotmat_to_quaternion(r32.astype(np.float64)), rtol=0, atol=1e-15)
    assert float(np.linalg.norm(q)) == pytest.approx(1.0, abs=1e-15)
    q64 = wire.rotmat_to_quaternion(r)
    np.testing.assert_allclose(wire.quaternion_to_rotmat(2.5 * q64), r, rtol=0, atol=1e-12)
    q32 = q64.astype(np.float32)
    m = wire.quaternion_to_rotmat(q32)
    assert m.dtype == np.float64
    # (the norm it divides by is taken of the float32 input, hence 1e-6 and not 1e-15 here)
    np.testing.assert_allclose(m, wire.quaternion_to_rotmat(q32.astype(np.float64)), rtol=0, atol=1e-6)

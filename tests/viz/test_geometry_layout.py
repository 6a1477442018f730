"""The drawn rotors are the vehicle's: `viz.geometry` places them from the vehicle's layout
(`core.params.unit_layout`, output order), PX4's quad-X when none is given."""

import dataclasses
import math

import numpy as np

from quadpilot.core.params import Rotor, unit_layout
from quadpilot.core.vehicle_file import SEED_VEHICLE
from quadpilot.viz.geometry import body_points, rotor_discs

PLUS = dataclasses.replace(
    SEED_VEHICLE,
    name="plus",
    arm=None,
    rotors=[Rotor(0.1, 0.0, "ccw"), Rotor(0.0, 0.1, "cw"), Rotor(-0.1, 0.0, "ccw"), Rotor(0.0, -0.1, "cw")],
)


def test_a_plus_frame_is_drawn_with_its_rotors_in_output_order():
    """Level at yaw 90° (nose north): output 1 (the nose) is north of the centre, output 2 (right,
    FRD y > 0) east, output 3 south, output 4 west; arm 0.2 m drawn."""
    s = np.zeros(12)
    s[0:3] = (1.0, 2.0, 3.0)
    s[8] = math.pi / 2
    pts = body_points(s, 0.2, layout=unit_layout(PLUS))
    want = np.array([(1.0, 2.2, 3.0), (1.2, 2.0, 3.0), (1.0, 1.8, 3.0), (0.8, 2.0, 3.0)])
    np.testing.assert_allclose(pts, want, atol=1e-12)
    discs = rotor_discs(s, 0.2, 0.05, n=8, layout=unit_layout(PLUS))
    np.testing.assert_allclose(discs.mean(axis=1), want, atol=1e-12)


def test_without_a_layout_it_is_px4s_quad_x():
    s = np.zeros(12)
    np.testing.assert_allclose(body_points(s, 0.105), body_points(s, 0.105, layout=unit_layout(SEED_VEHICLE)))
    a = 0.105 / math.sqrt(2)
    np.testing.assert_allclose(body_points(s, 0.105)[0], (a, -a, 0.0), atol=1e-15)  # front-right, FLU

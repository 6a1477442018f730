"""The simulator's scalar arithmetic for its one vehicle gives the bits of the batched NumPy code it
stands in for, so that a flight is the same flight, only faster:

- the step of one drone (`simulator.single_step.SingleStep`) against `core.dynamics.step` on a
  batch of one, for every airframe the simulator can fly: quad-X presets, other rotor layouts and
  output orders, motor lag, idle speed, drag, an external (wind) force, motors off, commands at
  the edges of the clip, and states from level hover to tumbling;
- the crash check (`process.crashed_one`) against `core.reward.crashed`;
- the attitude's rotation (`sensors.rotation`) against `core.frames.euler_to_rotmat`, and the
  accelerometer's shortcut for a vehicle without drag or contact (`Plant.specific_force_flu`)
  against `sensors.specific_force_flu`."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quadpilot.core import dynamics
from quadpilot.core.params import ParamBatch, Rotor
from quadpilot.core.vehicle_file import CRAZYFLIE, PX4_SIH_QUADX, SEED_VEHICLE, load_vehicle_file
from quadpilot.simulator import single_step
from quadpilot.simulator.plant import Plant
from quadpilot.simulator.single_step import SingleStep

HUMMINGBIRD = Path(__file__).parents[1] / "data" / "vehicles" / "rotorpy_hummingbird.toml"


def _frame(name, rotors):
    return dataclasses.replace(SEED_VEHICLE, name=name, arm=None, rotors=[Rotor(*r) for r in rotors])


VEHICLES = {
    "seed": SEED_VEHICLE,
    "crazyflie": CRAZYFLIE,
    "px4_sih_quadx": PX4_SIH_QUADX,
    "hummingbird": load_vehicle_file(HUMMINGBIRD),
    # a "+" frame, and a frame whose centre of mass is off the rotors' centre (coefficients other than ±1)
    "plus": _frame("plus", [(0.105, 0.0, "ccw"), (0.0, 0.105, "cw"), (-0.105, 0.0, "ccw"), (0.0, -0.105, "cw")]),
    "offset": _frame("offset", [(0.08, 0.12, "ccw"), (-0.12, -0.12, "ccw"), (0.08, -0.12, "cw"), (-0.12, 0.12, "cw")]),
    "lag_idle_drag": dataclasses.replace(
        SEED_VEHICLE, name="lag", motor_tau=0.03, omega_min=0.2 * SEED_VEHICLE.omega_max, drag=0.2
    ),
}


def _random_cases(rng, n):
    """States from gentle to wild (tumbling rates, pitch near ±90°, yaw across ±π), commands inside
    and outside [0, 1], rotors anywhere, forces or none, motors on or off."""
    for k in range(n):
        s = np.empty(12)
        s[0:3] = rng.uniform(-50, 50, 3)
        s[3:6] = rng.uniform(-20, 20, 3)
        s[6] = rng.uniform(-np.pi, np.pi)
        s[7] = rng.uniform(-1.55, 1.55) if k % 7 else rng.choice([-1, 1]) * rng.uniform(1.5, 1.5707963)
        s[8] = rng.uniform(-np.pi, np.pi)
        s[9:12] = rng.uniform(-70, 70, 3) if k % 3 == 0 else rng.normal(0, 1, 3)
        rotor = rng.uniform(0, 1, 4)
        command = rng.uniform(-0.2, 1.2, 4) if k % 5 == 0 else rng.uniform(0, 1, 4)
        if k % 13 == 0:  # the edges of NumPy's clip: signed zeros, the bounds, infinities
            command = rng.choice([-0.0, 0.0, 1.0, np.inf, -np.inf, 0.2, np.nextafter(1.0, 2.0)], 4)
        force = rng.normal(0, 2, 3) if k % 2 else None
        armed = k % 11 != 0
        yield s, rotor, command, force, armed


def _batch(p, state, rotor, command, force, armed, dt):
    s, w = dynamics.step(
        state[None],
        rotor[None],
        command[None],
        p,
        dt,
        force=None if force is None else force[None],
        armed=None if armed else np.zeros(1, bool),
    )
    return s[0], w[0]


def test_trigonometry_agrees_on_this_machine():
    """Where it does not, every step goes to core.dynamics (still the same bits, only slower); the
    speed figures assume it does."""
    assert single_step.TRIG_AGREES


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_single_step_equals_the_batched_step_bit_for_bit(name):
    vehicle = VEHICLES[name]
    p = ParamBatch.from_preset(vehicle, 1)
    for dt in (0.01, 0.004):
        one = SingleStep(p, dt)
        rng = np.random.default_rng([7, len(name), round(1 / dt)])
        for state, rotor, command, force, armed in _random_cases(rng, 400):
            got_s, got_w = one.step(state, rotor, command, force, armed)
            want_s, want_w = _batch(p, state, rotor, command, force, armed, dt)
            assert got_s.tobytes() == want_s.tobytes(), (name, state, command, force, armed)
            assert got_w.tobytes() == want_w.tobytes(), (name, rotor, command, armed)


def test_a_flight_of_many_steps_stays_bit_identical():
    """Errors do not hide in one step: 2,000 steps of a hovering, then falling, vehicle with wind."""
    p = ParamBatch.from_preset(SEED_VEHICLE, 1)
    one = SingleStep(p, 0.01)
    s = w = None
    s = a = np.array([0.3, -0.2, 2.0, 0.1, 0.0, -0.1, 0.2, -0.1, 3.0, 0.5, -0.3, 0.2])
    w = b = np.full(4, SEED_VEHICLE.hover_command)
    force = np.array([0.3, -0.1, 0.0])
    for k in range(2000):
        cmd = np.full(4, SEED_VEHICLE.hover_command) * (1.0 + 0.01 * np.sin(k * np.array([0.1, 0.2, 0.3, 0.4])))
        s, w = one.step(s, w, cmd, force, k < 1500)
        a, b = _batch(p, a, b, cmd, force, k < 1500, 0.01)
        assert s.tobytes() == a.tobytes() and w.tobytes() == b.tobytes(), k


def test_non_finite_states_are_left_to_the_batched_step():
    """math.sin raises on ±Inf where np.sin gives NaN: the scalar step declines such a step, and the
    plant takes core.dynamics' own (the same bits as before the scalar step existed)."""
    p = ParamBatch.from_preset(SEED_VEHICLE, 1)
    s = np.zeros(12)
    s[6] = np.inf
    assert SingleStep(p, 0.01).step(s, np.zeros(4), np.full(4, 0.5), None, True) is None
    plant = Plant(SEED_VEHICLE, 0.01)
    plant.state, plant.rotor = s.copy(), np.zeros(4)
    with np.errstate(all="ignore"):
        plant.step(np.full(4, 0.5))
        want = _batch(p, s, np.zeros(4), np.full(4, 0.5), None, True, 0.01)
    assert plant.rotor.tobytes() == want[1].tobytes()
    assert np.isnan(plant.state[6]) and np.isnan(want[0][6])


def test_the_plant_flies_the_single_step():
    plant = Plant(SEED_VEHICLE, 0.01)
    assert isinstance(plant._single, SingleStep)
    with pytest.raises(ValueError, match="one drone"):
        SingleStep(ParamBatch.from_preset(SEED_VEHICLE, 2), 0.01)


def test_the_scalar_crash_check_decides_as_core_reward():
    """`process.crashed_one` against `core.reward.crashed` on states near and across every limit:
    below ground, tilt at 60°, the 5 m flight area to the last bit (where the two sums of squares
    may round apart, `crashed` itself decides), NaN."""
    from quadpilot.core.reward import RewardConfig, crashed
    from quadpilot.simulator.process import crashed_one

    reward = RewardConfig()
    rng = np.random.default_rng(3)
    target = np.array([0.0, 0.0, 2.0])
    cases = []
    for _ in range(3000):
        s = np.zeros(12)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        s[0:3] = target + direction * rng.choice([rng.uniform(0, 6), 5.0, np.nextafter(5.0, 6), np.nextafter(5.0, 4)])
        s[6:8] = rng.choice([0.0, reward.max_tilt, np.nextafter(reward.max_tilt, 2), -reward.max_tilt], 2)
        cases.append(s)
    edge = np.zeros(12)
    edge[0:3] = target + np.array([3.0, 4.0, 0.0])  # exactly 5 m: inside
    nan = np.full(12, np.nan)
    for s in [*cases, edge, nan]:
        want = bool(crashed(s[None], s[None, 0:3] - target, reward)[0])
        assert crashed_one(s, target, reward) == want, s


def test_the_scalar_rotation_is_euler_to_rotmat_bit_for_bit():
    from quadpilot.core.frames import euler_to_rotmat
    from quadpilot.simulator.sensors import rotation

    rng = np.random.default_rng(5)
    for _ in range(5000):
        s = np.zeros(12)
        s[6:9] = rng.uniform(-4, 4, 3)
        assert rotation(s).tobytes() == euler_to_rotmat(s[6], s[7], s[8]).tobytes()
    s[6] = np.nan  # not finite: euler_to_rotmat's own NaNs
    with np.errstate(all="ignore"):
        assert np.isnan(rotation(s)).any()


@pytest.mark.parametrize("drag", [0.0, 0.2])
@pytest.mark.parametrize("landed", [False, True])
def test_the_accelerometer_is_the_sensor_model(drag, landed):
    """Plant.specific_force_flu (a shortcut without drag or contact, a shared rotation otherwise)
    against sensors.specific_force_flu with everything computed afresh."""
    from quadpilot.simulator import sensors

    vehicle = dataclasses.replace(SEED_VEHICLE, drag=drag)
    plant = Plant(vehicle, 0.01, wind=(1.0, -0.5, 0.2))
    rng = np.random.default_rng(9)
    for _ in range(200):
        s = np.zeros(12) if landed else rng.normal(0, 1, 12)
        if landed:
            s[8] = rng.uniform(-3, 3)
        plant.reset(s, rng.uniform(0, 1, 4) if not landed else None)
        want = sensors.specific_force_flu(
            plant.state, plant.thrust_n, vehicle.mass, vehicle.drag, plant.air, plant._contact_acc
        )
        assert plant.specific_force_flu().tobytes() == want.tobytes()
        assert plant.specific_force_flu(sensors.rotation(plant.state)).tobytes() == want.tobytes()

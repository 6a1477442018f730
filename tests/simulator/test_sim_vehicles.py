"""The simulator with the vehicles H1's airframe work added: PX4's SIH quad-X (which has no sensor
model) serves episodes when no noise is asked and refuses noise in one line, and motors off (a
disarmed peer, the ESC timeout) stop the rotors of a vehicle whose armed motors idle at ω_min > 0."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from test_sim import by_type, config, connect, finish, read_step, send, serving

from quadpilot.core.vehicle_file import PX4_SIH_QUADX, SEED_VEHICLE
from quadpilot.simulator import Plant, SimConfig, main_sim_only

SIH_FILE = str(Path(__file__).parents[2] / "src/quadpilot/vehicles/px4_sih_quadx.toml")
LEVEL = (0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # high enough to fall for 1 s
# the seed vehicle with a 50 ms motor lag and motors idling at 30 % of full speed when armed
IDLING = dataclasses.replace(SEED_VEHICLE, name="idling", omega_min=0.3 * SEED_VEHICLE.omega_max, motor_tau=0.05)


def test_the_sih_quad_x_without_noise_has_no_noise_and_flies_an_episode():
    cfg = config(vehicle="px4_sih_quadx", initial_state=LEVEL)
    assert cfg.sensor_noise is None and cfg.gyro_noise_std == 0.0 and cfg.accel_noise_std == 0.0
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        for _ in range(5):
            send(c, np.full(4, PX4_SIH_QUADX.hover_command))
            read_step(c)
        c.close()
        stats = finish(result)
    assert stats.records[0].steps == 5


@pytest.mark.parametrize("vehicle", ["px4_sih_quadx", SIH_FILE])
@pytest.mark.parametrize("flag", ["--imu-noise", "--estimator-noise"])
def test_noise_for_a_vehicle_without_a_sensor_model_is_one_line(capsys, vehicle, flag):
    noise = {"imu_noise": True} if flag == "--imu-noise" else {"estimator_noise": True}
    with pytest.raises(ValueError, match="no sensor model for vehicle 'px4_sih_quadx'"):  # first: else it serves
        SimConfig(vehicle="px4_sih_quadx", **noise)
    assert main_sim_only(["--vehicle", vehicle, flag, "--listen", "tcp:127.0.0.1:0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "no sensor model for vehicle 'px4_sih_quadx' (sensor models exist for crazyflie, seed)" in err[0]


def fall(plant: Plant, steps: int, **kw) -> None:
    for _ in range(steps):
        plant.step(np.zeros(4), **kw)


def test_motors_off_stop_the_rotors_that_an_armed_zero_command_keeps_idling():
    idle = IDLING.omega_min / IDLING.omega_max
    armed, off, inferred = (Plant(IDLING, 0.01) for _ in range(3))
    for p in (armed, off, inferred):
        p.reset(np.array(LEVEL))
    fall(armed, 100, armed=True)
    fall(off, 100, armed=False)
    fall(inferred, 100)  # the simulator's motors-off command: every motor 0
    assert armed.rotor == pytest.approx(np.full(4, idle), rel=1e-4)  # 1 s = 20τ: settled at idle
    assert np.all(off.rotor < 1e-8 * idle)  # spun down through the lag: exp(−20)
    np.testing.assert_array_equal(inferred.rotor, off.rotor)
    np.testing.assert_array_equal(inferred.state, off.state)
    assert off.thrust_n < 1e-12 < armed.thrust_n


def test_without_omega_min_motors_off_and_a_zero_command_are_the_same_step():
    a, b = Plant(SEED_VEHICLE, 0.01), Plant(SEED_VEHICLE, 0.01)
    a.reset(np.array(LEVEL))
    b.reset(np.array(LEVEL))
    fall(a, 50, armed=True)
    fall(b, 50, armed=False)
    np.testing.assert_array_equal(a.state, b.state)
    np.testing.assert_array_equal(a.rotor, b.rotor)


def test_a_disarmed_peer_stops_the_rotors_over_the_wire():
    """Disarmed HIL_ACTUATOR_CONTROLS for 1 s: the vehicle falls freely, its accelerometer reading
    no thrust, where an armed zero command would leave the idle rotors lifting it (k_f·ω_min² each)."""
    cfg = config(airframe=IDLING, initial_state=LEVEL)
    idle_acc = 4 * IDLING.k_f * IDLING.omega_min**2 / IDLING.mass
    assert idle_acc > 1.5  # m/s², what idling rotors would read
    with serving(cfg) as (_, port, result):
        c = connect(port)
        read_step(c)
        for _ in range(100):
            send(c, np.zeros(4), armed=False)
            msgs = by_type(read_step(c))
        c.close()
        finish(result)
    z_acc = -msgs["HIL_SENSOR"].zacc  # FRD z down: specific force up is −zacc
    assert math.isclose(z_acc, 0.0, abs_tol=1e-3), z_acc

"""The px4-raptor distillation's parts: the teacher's action in the contract's convention, the
motor order per vehicle, the batched observation, the configuration's checks, and the checkpoint's
refusals. The whole pipeline (quad-train, quad-export, RLtools' loader, quad-sitl) is
tests/px4/test_trained_policy_tar.py."""

import numpy as np
import pytest
import torch

from quadpilot.core import px4_raptor as pr
from quadpilot.core.params import Rotor, quad_x
from quadpilot.core.vehicle_file import get_preset, resolve_vehicle
from quadpilot.train.cli import main
from quadpilot.train.raptor.distill import (
    DistillConfig,
    contract_commands,
    is_student_checkpoint,
    load_student,
    teacher_labels,
)

HUMMINGBIRD = "tests/data/vehicles/rotorpy_hummingbird.toml"


def test_a_teachers_action_labels_the_command_it_makes_in_the_policys_motor_order():
    # hand-worked: u_hover 0.5; a = 0 → u 0.5 → 0; a = 1 → u 0.5·√2 → 2·0.7071 − 1; a = −1 → 0 → −1;
    # a = 0.44 → u 0.5·1.2 = 0.6 → 0.2. Output i (PX4 quad-X) lands at policy index (0, 2, 3, 1)[i].
    a = np.array([[0.0, 1.0, -1.0, 0.44]])
    got = teacher_labels(a, 0.5, np.array(pr.MOTOR_FROM_POLICY))
    want = np.array([[0.0, 0.0, np.sqrt(2) - 1.0, -1.0]])
    want[0, 1] = 0.2  # output 4 (index 3, a = 0.44) is policy output 1
    np.testing.assert_allclose(got, want, atol=1e-6)
    # and the contract's map back gives the teacher's own commands, output by output
    np.testing.assert_allclose(
        contract_commands(got, np.array(pr.MOTOR_FROM_POLICY)), [[0.5, 0.5 * np.sqrt(2), 0.0, 0.6]], atol=1e-6
    )


def test_the_motor_order_follows_the_rotor_corners():
    assert pr.policy_order(get_preset("px4_sih_quadx")) == pr.MOTOR_FROM_POLICY
    assert pr.policy_order(resolve_vehicle(HUMMINGBIRD)) == (3, 0, 1, 2)  # front-left first, clockwise
    # the executor writes output i from policy output order[i]: the Hummingbird's front-left (its output 1)
    # gets the policy's front-left (Crazyflie output 4)
    np.testing.assert_allclose(pr.motor_commands((1.0, -1.0, -1.0, -1.0), (3, 0, 1, 2)), (0.0, 1.0, 0.0, 0.0))


def test_a_frame_the_contract_cannot_fly_is_refused_in_one_line():
    import dataclasses

    v = get_preset("px4_sih_quadx")
    c = 0.17
    mirrored = dataclasses.replace(
        v, arm=None, rotors=[Rotor(r.x, r.y, "cw" if r.spin == "ccw" else "ccw") for r in quad_x(0.24)]
    )
    with pytest.raises(ValueError, match="spins cw; the px4-raptor contract needs"):
        pr.policy_order(mirrored)
    plus = [Rotor(c, 0.0, "ccw"), Rotor(-c, 0.0, "ccw"), Rotor(0.0, c, "cw"), Rotor(0.0, -c, "cw")]
    plus_frame = dataclasses.replace(v, arm=None, rotors=plus)
    with pytest.raises(ValueError, match="one rotor per corner"):
        pr.policy_order(plus_frame)


def test_the_batched_observation_is_the_contracts_observation_row_by_row():
    rng = np.random.default_rng(3)
    s = rng.normal(size=(64, 12)) * [2, 2, 2, 2, 2, 2, 0.7, 0.7, 3, 2, 2, 2]
    target, heading = rng.normal(size=(64, 3)), rng.uniform(-np.pi, np.pi, 64)
    prev = rng.uniform(-1, 1, (64, 4)).astype(np.float32)
    got = pr.observation_batch(s, target, heading, prev)
    want = np.stack([pr.observation(s[i], target[i], None, heading[i], prev[i]) for i in range(64)])
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("bad", ["iterations=0", "lr=0", "num_envs=-1", "minibatch=0", "max_grad_norm=nan"])
def test_a_bad_setting_is_one_line_and_exit_2(bad, tmp_path, capsys):
    assert main(["--task", "hover", "--contract", "px4-raptor", "--out", str(tmp_path / "r"), "--set", bad]) == 2
    err = capsys.readouterr().err
    assert err.startswith("quad-train: error:") and len(err.strip().splitlines()) == 1
    with pytest.raises(ValueError):
        DistillConfig(
            **{bad.split("=")[0]: float(bad.split("=")[1]) if "." in bad or "nan" in bad else int(bad.split("=")[1])}
        )


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--task", "circle"], "trains hover"),
        (["--task", "hover", "--algo", "sac"], "--algo"),
        (["--task", "hover", "--arch", "lstm"], "--arch"),
        (["--task", "hover", "--resume"], "not resumable"),
        (["--task", "hover", "--randomize", "airframes"], "distilled for one vehicle"),
    ],
)
def test_options_the_contract_cannot_honour_are_refused(argv, says, tmp_path, capsys):
    assert main([*argv, "--contract", "px4-raptor", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1


def test_a_teacher_of_another_vehicle_is_refused(tmp_path, capsys):
    argv = [
        "--task",
        "hover",
        "--contract",
        "px4-raptor",
        "--vehicle",
        HUMMINGBIRD,
        "--teacher",
        "models/hover_px4_sih/policy.pt",
    ]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 2
    assert "flies px4_sih_quadx, not rotorpy_hummingbird" in capsys.readouterr().err


def test_the_checkpoint_loads_with_weights_only_and_other_files_are_refused(tmp_path):
    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.raptor.distill import checkpoint
    from quadpilot.train.raptor.student import RaptorStudent

    teacher = load_policy("models/hover_px4_sih/policy.pt")
    student = RaptorStudent()
    torch.save(checkpoint(student, teacher.env_config, DistillConfig(), "t", {}), tmp_path / "p.pt")
    back, _ = load_student(tmp_path / "p.pt")
    for k, v in student.weights().items():
        np.testing.assert_array_equal(back.weights()[k], v)
    assert is_student_checkpoint(tmp_path / "p.pt") and not is_student_checkpoint("models/hover/policy.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    for name, env in (("noenv.pt", {"task": "hover"}), ("strenv.pt", "x")):
        torch.save(
            {**checkpoint(student, teacher.env_config, DistillConfig(), "t", {}), "env_config": env}, tmp_path / name
        )
        with pytest.raises(ValueError, match=name):
            load_student(tmp_path / name)
    for path, says in (
        (tmp_path / "junk.pt", "not a readable checkpoint"),
        ("models/hover/policy.pt", "not a px4-raptor policy"),
    ):
        with pytest.raises(ValueError, match=says):
            load_student(path)


def test_a_frame_the_contract_cannot_fly_is_refused_before_any_training(tmp_path, capsys):
    import dataclasses

    from quadpilot.core.vehicle_file import vehicle_to_toml

    v = get_preset("px4_sih_quadx")
    c = 0.17
    plus = [Rotor(c, 0.0, "ccw"), Rotor(-c, 0.0, "ccw"), Rotor(0.0, c, "cw"), Rotor(0.0, -c, "cw")]
    (tmp_path / "plus.toml").write_text(vehicle_to_toml(dataclasses.replace(v, name="plus", arm=None, rotors=plus)))
    argv = ["--task", "hover", "--contract", "px4-raptor", "--vehicle", str(tmp_path / "plus.toml")]
    assert main([*argv, "--out", str(tmp_path / "r")]) == 2
    assert "one rotor per corner" in capsys.readouterr().err and not (tmp_path / "r").exists()


def _student_checkpoint(env_config=None) -> dict:
    """A px4-raptor policy.pt's dict, untrained, for the shipped PX4 SIH teacher's environment."""
    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.raptor.distill import checkpoint
    from quadpilot.train.raptor.student import RaptorStudent

    env = load_policy("models/hover_px4_sih/policy.pt").env_config if env_config is None else env_config
    return checkpoint(RaptorStudent(), env, DistillConfig(), "t", {})


@pytest.mark.parametrize("dtype", [torch.bool, torch.int32, torch.int64, torch.complex64])
def test_weights_that_are_not_floating_point_are_refused_not_cast(dtype, tmp_path, capsys):
    from quadpilot.export.cli import main as export

    ckpt = _student_checkpoint()
    ckpt["weights"]["layers/0/weights"] = ckpt["weights"]["layers/0/weights"].to(dtype)
    torch.save(ckpt, tmp_path / "p.pt")
    name = str(dtype).split(".")[1]  # torch.int32 -> int32, as NumPy names it
    with pytest.raises(ValueError, match=f"layers/0/weights holds {name} values; expected floating-point"):
        load_student(tmp_path / "p.pt")
    assert export(["--format", "px4-raptor", str(tmp_path / "p.pt"), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "expected floating-point numbers" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("change", "says"), [({"task": "waypoint"}, "task waypoint at 100 Hz"), ({"dt": 0.02}, "task hover at 50 Hz")]
)
def test_a_student_of_another_task_or_rate_is_refused_by_the_export_in_one_line(change, says, tmp_path, capsys):
    import dataclasses

    from quadpilot.export.cli import main as export
    from quadpilot.train.algorithms import load_policy

    env = dataclasses.replace(load_policy("models/hover_px4_sih/policy.pt").env_config, **change)
    torch.save(_student_checkpoint(env), tmp_path / "p.pt")
    assert export(["--format", "px4-raptor", str(tmp_path / "p.pt"), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert says in err and "flies hover at 100 Hz" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and not (tmp_path / "out").exists()


def test_a_teacher_mismatch_names_the_parameters_that_differ(tmp_path, capsys):
    import dataclasses

    from quadpilot.core.vehicle_file import vehicle_to_toml

    heavier = dataclasses.replace(get_preset("px4_sih_quadx"), mass=1.25)  # the teacher's name, not its mass
    (tmp_path / "heavier.toml").write_text(vehicle_to_toml(heavier))
    argv = ["--task", "hover", "--contract", "px4-raptor", "--vehicle", str(tmp_path / "heavier.toml")]
    assert main([*argv, "--teacher", "models/hover_px4_sih/policy.pt", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "flies another px4_sih_quadx (mass 1 vs 1.25 kg: teacher vs --vehicle)" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    ("extra", "code", "says"),
    [
        (["--set", "lr=0"], 2, "lr = 0.0: expected a number > 0"),
        (["--vehicle", HUMMINGBIRD, "--teacher", "models/hover_px4_sih/policy.pt"], 2, "give the teacher of the same"),
        (["--teacher", "models/circle/policy.pt"], 2, "needs a hover teacher"),
        (["--teacher", "no-such-teacher.pt"], 1, "no such file"),
        (["--vehicle", "VEHICLE_WITHOUT_TEACHER", "--set", "nonsense=1"], 2, "a PPO hyper-parameter"),  # its teacher's
    ],
)
def test_a_refused_command_leaves_no_run_directory_behind(extra, code, says, tmp_path, capsys):
    import dataclasses

    from quadpilot.core.vehicle_file import vehicle_to_toml

    heavy = dataclasses.replace(get_preset("px4_sih_quadx"), name="heavy", mass=1.25)  # no shipped teacher flies it
    (tmp_path / "heavy.toml").write_text(vehicle_to_toml(heavy))
    extra = [str(tmp_path / "heavy.toml") if a == "VEHICLE_WITHOUT_TEACHER" else a for a in extra]
    out = tmp_path / "runs" / "r"
    assert main(["--task", "hover", "--contract", "px4-raptor", *extra, "--out", str(out)]) == code
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "runs").exists()
    out.mkdir(parents=True)  # a folder the user made stays, empty or not
    assert main(["--task", "hover", "--contract", "px4-raptor", *extra, "--out", str(out)]) == code
    assert out.is_dir()


def test_a_distillation_flight_in_which_every_drone_crashes_is_standard_json():
    import json

    from quadpilot.train.algorithms import load_policy
    from quadpilot.train.raptor.distill import fly

    cfg = load_policy("models/hover_px4_sih/policy.pt").env_config

    def one_motor(x, h):  # one motor at full thrust, the others off: every drone spins and crashes
        return np.tile(np.array([1.0, -1.0, -1.0, -1.0], np.float32), (len(x), 1)), h

    figures = fly(one_motor, cfg, 4, np.random.default_rng(0))["figures"]
    assert figures["crash_rate"] == 1.0
    json.dumps(figures, allow_nan=False)  # eval.json's figures: no NaN
    assert figures["mean_error_last_window_m"] is None

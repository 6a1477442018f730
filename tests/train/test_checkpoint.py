"""Checkpoints: a save/load round trip acts identically, a resumed trainer continues bit for bit,
files are plain (weights_only) and written atomically, and bad files fail with a clear message."""

import io
import math

import numpy as np
import pytest
import torch

from quadpilot.atomic_files import atomic_write
from quadpilot.train.algorithms import load_checkpoint, load_for_resume
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo.checkpoint import ppo_from_checkpoint
from quadpilot.train.runs.checkpoint import LATEST, PREVIOUS, save_checkpoint, save_for_resume
from quadpilot.train.runs.checks import SCHEMA, CheckpointError

TINY = PPOConfig(num_envs=16, rollout_steps=16, minibatch_size=64, epochs=2, threads=1, seed=7)


def tiny(task="waypoint") -> PPO:
    return PPO(TINY, make_config(task, episode_steps=24))


def same_weights(a: PPO, b: PPO) -> bool:
    sa, sb = a.model.state_dict(), b.model.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def plain_only(obj, where="ckpt"):
    """Every leaf is a tensor or JSON-able; returns the offending path or None."""
    if obj is None or isinstance(obj, (bool, int, float, str, torch.Tensor)):
        return None
    if isinstance(obj, dict):
        for k, v in obj.items():
            if not isinstance(k, (str, int)):
                return f"{where}[{k!r}] key"
            bad = plain_only(v, f"{where}[{k!r}]")
            if bad:
                return bad
        return None
    if isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            bad = plain_only(v, f"{where}[{i}]")
            if bad:
                return bad
        return None
    return f"{where}: {type(obj).__name__}"


def test_round_trip_acts_identically(tmp_path):
    ppo = tiny()
    ppo.iterate()
    path = save_checkpoint(tmp_path / "policy.pt", ppo, {"note": "round trip"})
    ckpt = load_checkpoint(path)
    restored = ppo_from_checkpoint(ckpt)
    obs = np.random.default_rng(0).normal(size=(64, ppo.env_cfg.layout.dim)).astype(np.float32) * 3
    np.testing.assert_array_equal(restored.act_deterministic(obs), ppo.act_deterministic(obs))
    assert same_weights(ppo, restored)
    assert ckpt["extra"] == {"note": "round trip"}
    assert ckpt["obs_layout"]["name"] == ppo.env_cfg.layout.name


def test_file_is_plain_data_loadable_with_weights_only(tmp_path):
    ppo = tiny()
    ppo.iterate()
    save_checkpoint(tmp_path / "c.pt", ppo, {"metrics": {"x": np.float64(1.5), "n": np.int64(3)}})
    raw = torch.load(tmp_path / "c.pt", weights_only=True)
    assert raw["schema"] == SCHEMA == "quadpilot.checkpoint/1"
    assert plain_only(raw) is None, plain_only(raw)
    assert raw["extra"]["metrics"] == {"x": 1.5, "n": 3}
    assert raw["ppo_config"] == TINY.to_json() and PPOConfig.from_json(raw["ppo_config"]) == TINY
    assert raw["env_config"]["task"] == "waypoint" and raw["env_config"]["vehicle"]["name"] == "seed"
    assert raw["global_step"] == 256 and raw["updates"] == 1
    assert raw["rng"]["env"]["bit_generator"] == "PCG64"
    assert isinstance(raw["rng"]["torch_gen"], torch.Tensor)


def test_extra_refuses_objects_that_would_need_pickle(tmp_path):
    with pytest.raises(TypeError, match="tensors and JSON-able data only"):
        save_checkpoint(tmp_path / "c.pt", tiny(), {"bad": object()})
    assert not list(tmp_path.iterdir())


def test_resumed_training_continues_bit_for_bit(tmp_path):
    straight = tiny()
    for _ in range(3):
        m_straight = straight.iterate()

    first = tiny()
    first.iterate()
    first.iterate()
    save_for_resume(tmp_path, first)
    del first
    ckpt, path, warning = load_for_resume(tmp_path)
    assert path.name == LATEST and warning is None
    resumed = ppo_from_checkpoint(ckpt)
    m_resumed = resumed.iterate()

    assert same_weights(straight, resumed)
    timing = [k for k in m_straight if k.endswith("_s")]  # seconds and steps/s: wall-clock, not maths
    assert {k: v for k, v in m_straight.items() if k not in timing} == pytest.approx(
        {k: v for k, v in m_resumed.items() if k not in timing}, nan_ok=True, rel=0, abs=0
    )
    np.testing.assert_array_equal(straight.obs_rms.mean, resumed.obs_rms.mean)
    np.testing.assert_array_equal(straight.env.batch.state, resumed.env.batch.state)
    assert straight.env.rng.bit_generator.state == resumed.env.rng.bit_generator.state


def test_rotation_keeps_the_previous_checkpoint(tmp_path):
    ppo = tiny("hover")
    ppo.iterate()
    save_for_resume(tmp_path, ppo)
    ppo.iterate()
    save_for_resume(tmp_path, ppo)
    assert load_checkpoint(tmp_path / LATEST)["updates"] == 2
    assert load_checkpoint(tmp_path / PREVIOUS)["updates"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [PREVIOUS, LATEST]  # no temporary files left


def test_corrupt_latest_falls_back_to_previous(tmp_path):
    ppo = tiny("hover")
    ppo.iterate()
    save_for_resume(tmp_path, ppo)
    ppo.iterate()
    save_for_resume(tmp_path, ppo)
    latest = tmp_path / LATEST
    latest.write_bytes(latest.read_bytes()[: latest.stat().st_size // 2])  # a torn write
    ckpt, path, warning = load_for_resume(tmp_path)
    assert path.name == PREVIOUS and ckpt["updates"] == 1
    assert str(latest) in warning and "previous checkpoint" in warning

    latest.unlink()  # killed between the two renames of a save: only the previous one exists
    assert load_for_resume(tmp_path)[0]["updates"] == 1

    (tmp_path / PREVIOUS).write_bytes(b"")
    with pytest.raises(CheckpointError, match=r"no usable checkpoint.*checkpoint\.pt.*checkpoint\.prev\.pt"):
        load_for_resume(tmp_path)


def _torch_bytes(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "unreadable"),
        (b"definitely not a checkpoint\n" * 10, "unreadable"),
        (np.random.default_rng(0).bytes(4096), "unreadable"),
        (_torch_bytes(torch.zeros(3)), "without a 'schema' key"),
        (_torch_bytes({"schema": "quadpilot.checkpoint/0"}), "this version of quadpilot reads"),
        (_torch_bytes({"schema": SCHEMA, "model": {}}), "missing"),
    ],
    ids=["empty", "text", "random", "tensor", "old-schema", "incomplete"],
)
def test_bad_files_raise_checkpoint_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.pt"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match=message) as e:
        load_checkpoint(path)
    assert str(path) in str(e.value)


def test_a_pickled_object_is_refused_not_executed(tmp_path):
    class Payload:
        def __reduce__(self):
            return (print, ("pickle code ran",))

    path = tmp_path / "evil.pt"
    torch.save({"schema": SCHEMA, "x": Payload()}, path)
    with pytest.raises(CheckpointError, match="unreadable"):
        load_checkpoint(path)


def test_missing_file_raises_checkpoint_error(tmp_path):
    with pytest.raises(CheckpointError, match="no such file"):
        load_checkpoint(tmp_path / "nope.pt")


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "f.bin"
    path.write_bytes(b"old")

    def half_then_fail(f):
        f.write(b"new, half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(path, half_then_fail, keep_previous="f.prev.bin")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]


def test_resuming_restores_the_curriculum_radius_in_flight(tmp_path):
    ppo = tiny()
    ppo.env.set_target_radius(2.0)
    ppo.iterate()
    save_checkpoint(tmp_path / "c.pt", ppo)
    restored = ppo_from_checkpoint(load_checkpoint(tmp_path / "c.pt"))
    assert restored.env.batch.target_radius == 2.0
    assert math.isclose(restored.env.batch.target_radius, ppo.env.batch.target_radius)


@pytest.mark.parametrize("normalize_obs", [False, True])
def test_load_policy_acts_like_the_trainer(tmp_path, normalize_obs):
    """The deployable view of a checkpoint (no trainer, no environment) gives the trainer's
    deterministic actions bit for bit, with and without the observation normaliser."""
    import dataclasses

    from quadpilot.train.algorithms import load_policy

    cfg = dataclasses.replace(TINY, normalize_obs=normalize_obs)
    ppo = PPO(cfg, make_config("circle", episode_steps=24))
    ppo.iterate()
    save_checkpoint(tmp_path / "policy.pt", ppo)
    policy = load_policy(tmp_path / "policy.pt")
    assert policy.layout.name == "quadpilot.obs.track/2" and policy.env_config.task == "circle"
    obs = np.random.default_rng(0).normal(size=(200, 21)).astype(np.float32)
    np.testing.assert_array_equal(policy(obs), ppo.act_deterministic(obs))
    with pytest.raises(ValueError, match=r"\(N, 21\)"):
        policy(obs[:, :18])


def test_load_policy_refuses_an_unknown_layout(tmp_path):
    from quadpilot.train.algorithms import trained_policy
    from quadpilot.train.runs.checkpoint import checkpoint_dict

    ckpt = checkpoint_dict(tiny("hover"))
    ckpt["obs_layout"] = {**ckpt["obs_layout"], "name": "quadpilot.obs.hover/999"}
    with pytest.raises(CheckpointError, match="hover/999"):
        trained_policy(ckpt, "x.pt")

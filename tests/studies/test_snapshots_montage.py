"""Policy snapshots during training (quad-train --snapshot-every) and the learning montage drawn
from them (python -m quadpilot.studies.learning_montage), on tiny budgets."""

import json
import math

import numpy as np
import pytest
import torch

from quadpilot.studies.learning_montage import flight_config, fly, pick_snapshots, steps_text
from quadpilot.studies.learning_montage import main as montage
from quadpilot.train.algorithms import load_checkpoint, load_policy
from quadpilot.train.cli import main as train
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPOConfig
from quadpilot.train.ppo.checkpoint import save_untrained_policy
from quadpilot.train.runs.checkpoint import SNAPSHOTS, list_snapshots, snapshot_path

BATCH = 64 * 16  # transitions per update with TINY
TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0"]


def run(out, *args):
    return train(["--task", "hover", "--out", str(out), *TINY, *args])


def same_weights(a, b):
    sa, sb = load_checkpoint(a)["model"], load_checkpoint(b)["model"]
    return all(torch.equal(sa[k], sb[k]) for k in sa)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """5 updates with a snapshot every 2: at 0 steps, updates 2 and 4, and the end (update 5)."""
    out = tmp_path_factory.mktemp("runs") / "run"
    assert run(out, "--total-steps", str(5 * BATCH), "--snapshot-every", "2") == 0
    return out


# --- snapshots ---------------------------------------------------------------------------------


def test_snapshots_are_written_at_the_right_updates_and_load(tiny_run):
    found = list_snapshots(tiny_run)
    assert [s for s, _ in found] == [0, 2 * BATCH, 4 * BATCH, 5 * BATCH]
    assert [p.name for _, p in found] == ["policy-0.pt", "policy-2048.pt", "policy-4096.pt", "policy-5120.pt"]
    assert not [p for p in (tiny_run / SNAPSHOTS).iterdir() if p.name.endswith(".tmp")]
    for steps, path in found:
        assert path == snapshot_path(tiny_run, steps)
        ckpt = load_checkpoint(path)  # weights_only=True, the schema and every required key
        assert ckpt["global_step"] == steps and ckpt["updates"] == steps // BATCH
        assert ckpt["optimizer"] == {} and ckpt["env"] == {}  # deployable, not resumable: small
        assert path.stat().st_size < 100_000
        policy = load_policy(path)
        assert policy.global_step == steps
        action = policy(np.zeros((2, policy.layout.dim), np.float32))
        assert action.shape == (2, 4) and np.isfinite(action).all()
    assert load_checkpoint(found[1][1])["extra"]["metrics"]["update"] == 2
    # the last snapshot is the final policy; the first is the untrained one, and they differ
    assert same_weights(found[-1][1], tiny_run / "policy.pt")
    assert not same_weights(found[0][1], found[-1][1])
    assert json.loads((tiny_run / "config.json").read_text())["snapshot_every"] == 2


def test_snapshots_survive_resume(tmp_path):
    out = tmp_path / "run"
    assert run(out, "--total-steps", str(4 * BATCH), "--snapshot-every", "2") == 0
    before = {p.name: p.read_bytes() for _, p in list_snapshots(out)}
    assert sorted(before) == ["policy-0.pt", "policy-2048.pt", "policy-4096.pt"]
    (out / SNAPSHOTS / ".policy-6144.pt.abc.tmp").write_bytes(b"torn")  # a write a kill interrupted
    assert run(out, "--total-steps", str(6 * BATCH), "--snapshot-every", "2", "--resume") == 0
    after = list_snapshots(out)
    assert [s for s, _ in after] == [0, 2 * BATCH, 4 * BATCH, 6 * BATCH]  # no new untrained snapshot
    assert all(p.read_bytes() == before[p.name] for _, p in after if p.name in before)
    assert same_weights(after[-1][1], out / "policy.pt")
    assert not [p for p in (out / SNAPSHOTS).iterdir() if p.name.endswith(".tmp")]


def test_no_snapshots_by_default_and_the_flag_is_documented(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(out, "--total-steps", str(BATCH)) == 0
    assert not (out / SNAPSHOTS).exists()
    assert train(["--help"]) == 0
    text = capsys.readouterr().out
    assert "--snapshot-every" in text and "snapshots/" in text  # the option and the run-directory listing
    assert train(["--task", "hover", "--algo", "sb3", "--snapshot-every", "2", "--out", str(tmp_path / "s")]) == 2
    assert "--snapshot-every is for our PPO" in capsys.readouterr().err


# --- the montage -------------------------------------------------------------------------------


def test_pick_snapshots_spans_first_to_last():
    snaps = [(k * 100, f"p{k}") for k in range(10)]
    assert pick_snapshots(snaps, 3) == [snaps[0], snaps[4], snaps[9]]  # round(4.5) = 4
    assert pick_snapshots(snaps, 4) == [snaps[0], snaps[3], snaps[6], snaps[9]]
    assert pick_snapshots(snaps, 2) == [snaps[0], snaps[9]]
    assert pick_snapshots(snaps, 1) == [snaps[9]]
    assert pick_snapshots(snaps[:2], 3) == snaps[:2]
    assert pick_snapshots(snaps, 10) == snaps
    assert [steps_text(s) for s in (0, 512, 40_960, 1_007_616)] == ["0 steps", "512 steps", "41k steps", "1.01M steps"]


def test_every_snapshot_flies_from_the_same_start(tiny_run):
    policies = [load_policy(p) for _, p in list_snapshots(tiny_run)]
    cfg = flight_config(policies[-1], seconds=1.0)
    assert cfg.episode_steps == 100
    flights = [fly(p, cfg, seed=3) for p in policies]
    for trace, result in flights:
        assert np.array_equal(trace.states[0], flights[0][0].states[0])
        assert trace.t[0] == 0.0 and trace.duration <= 1.0 + 1e-9
        assert trace.commands.min() >= 0.0 and trace.commands.max() <= 1.0
        if result["crashed_at_s"] is None:
            assert trace.n == 101 and trace.duration == pytest.approx(1.0)
        else:
            assert trace.duration == pytest.approx(result["crashed_at_s"])
    assert not np.array_equal(flights[0][0].states, flights[-1][0].states)  # different policies, different flights
    again, _ = fly(policies[-1], cfg, seed=3)
    assert np.array_equal(again.states, flights[-1][0].states)  # deterministic


def test_montage_command_writes_the_gif(tiny_run, tmp_path, capsys):
    pil = pytest.importorskip("PIL.Image")
    out = tmp_path / "montage.gif"
    fps, seconds = 10, 1.0
    code = montage([str(tiny_run), "-o", str(out), "--fps", str(fps), "--seconds", str(seconds), "--size", "360x160"])
    assert code == 0
    text = capsys.readouterr().out
    assert "3 of 4 snapshots" in text and "untrained · 0 steps" in text and "update 5 · 5k steps" in text
    # the video lasts as long as the longest of the three flights
    policies = [load_policy(p) for _, p in pick_snapshots(list_snapshots(tiny_run), 3)]
    cfg = flight_config(policies[-1], seconds)
    longest = max(fly(p, cfg, seed=0)[0].duration for p in policies)
    frames = []
    with pil.open(out) as im:
        assert im.size == (360, 160)
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB"), dtype=float))
    assert len(frames) == math.floor(longest * fps + 1e-9) + 1
    assert out.stat().st_size < 300_000
    first = frames[0]
    panels = [first[:, k * 120 + 2 : (k + 1) * 120 - 2] for k in range(3)]
    for i, panel in enumerate(panels):
        assert panel.std() > 10 and len(np.unique(panel.reshape(-1, 3), axis=0)) > 8, f"panel {i} looks blank"
    assert min(np.abs(a - b).mean() for a, b in ((panels[0], panels[1]), (panels[1], panels[2]))) > 1.0


def test_montage_of_untrained_snapshots_and_its_errors(tmp_path, capsys):
    """Snapshots need not come from quad-train: policy files in RUN/snapshots/ are enough."""
    run_dir = tmp_path / "made"
    ppo_cfg, env_cfg = PPOConfig(), make_config("hover")
    (run_dir / SNAPSHOTS).mkdir(parents=True)
    for k, gain in enumerate((1.0, 0.3, 0.01)):
        save_untrained_policy(snapshot_path(run_dir, k * 1000), ppo_cfg, env_cfg, seed=k, head_gain=gain)
    out = run_dir / "montage.gif"
    assert montage([str(run_dir), "--fps", "5", "--seconds", "0.4", "--size", "300x140", "--snapshots", "2"]) == 0
    assert "2 of 3 snapshots" in capsys.readouterr().out
    with pytest.importorskip("PIL.Image").open(out) as im:
        assert im.size == (300, 140) and 1 < im.n_frames <= 3

    empty = tmp_path / "empty"
    empty.mkdir()
    for args, message in (
        ([str(empty)], "holds no policy-<steps>.pt; train with quad-train ... --snapshot-every N"),
        ([str(tmp_path / "nowhere")], "is not a directory"),
        ([str(run_dir), "-o", str(tmp_path / "m.png")], "must end in .gif or .mp4"),
        ([str(run_dir), "--size", "big"], "--size must be WIDTHxHEIGHT"),
        ([str(run_dir), "--seconds", "-1"], "--seconds must be a positive number"),
        ([str(run_dir), "--snapshots", "0"], "must be ≥ 1"),
    ):
        assert montage(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err

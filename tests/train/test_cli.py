"""quad-train end to end on tiny budgets: the files of a run, resuming (after a finished run, a
Ctrl-C, a kill -9 and a torn checkpoint), and one-line errors with exit code 2 for bad requests."""

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import torch

from quadpilot.train.algorithms import load_checkpoint, load_for_resume
from quadpilot.train.cli import main
from quadpilot.train.runs.checkpoint import LATEST, PREVIOUS
from quadpilot.train.runs.runlog import COLUMNS, HEADER

BATCH = 64 * 16  # transitions per update with TINY
TINY = ["--num-envs", "64", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "8"]
EVAL_KEYS = {"policy", "global_step", "updates", "task", "episodes", "success_rate", "crash_rate", "mean_return"}


def rows(out):
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


def updates(out):
    return [int(r["update"]) for r in rows(out)]


def run(out, *args, task="hover"):
    return main(["--task", task, "--out", str(out), *TINY, *args])


def same_weights(a, b):
    sa, sb = load_checkpoint(a)["model"], load_checkpoint(b)["model"]
    return all(torch.equal(sa[k], sb[k]) for k in sa)


def test_a_run_writes_every_file(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(out, "--total-steps", "4096") == 0
    names = {p.name for p in out.iterdir()}
    assert {"config.json", "metrics.csv", LATEST, PREVIOUS, "policy.pt", "eval.json", "curves.png"} <= names
    assert not [n for n in names if n.endswith(".tmp")]
    assert (out / "metrics.csv").read_text().splitlines()[0] == HEADER
    assert updates(out) == [1, 2, 3, 4]
    assert [int(r["global_step"]) for r in rows(out)] == [BATCH, 2 * BATCH, 3 * BATCH, 4 * BATCH]
    assert all(r["curriculum_stage"] == "" for r in rows(out))  # hover has no curriculum
    ev = json.loads((out / "eval.json").read_text())
    assert EVAL_KEYS <= set(ev) and ev["episodes"] == 8 and ev["updates"] == 4
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["preset"] == "fast" and cfg["ppo"]["num_envs"] == 64 and cfg["env"]["task"] == "hover"
    assert cfg["command"].startswith("quad-train --task hover")
    policy = load_checkpoint(out / "policy.pt")
    assert policy["updates"] == 4 and policy["extra"]["metrics"]["update"] == 4
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"
    assert "done, 4,096 steps in 4 updates" in capsys.readouterr().out


def test_waypoint_run_logs_the_curriculum(tmp_path):
    out = tmp_path / "wp"
    assert run(out, "--total-steps", "2048", task="waypoint") == 0
    assert [(r["curriculum_stage"], r["target_radius"]) for r in rows(out)] == [("0", "0.5")] * 2
    assert load_checkpoint(out / LATEST)["extra"]["curriculum"]["stage"] == 0
    assert json.loads((out / "eval.json").read_text())["target_radius"] == 0.5


def test_resume_extends_a_finished_run(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(out, "--total-steps", "4096", "--eval-episodes", "0") == 0
    first_rows = rows(out)
    assert run(out, "--total-steps", "8192", "--resume") == 0
    assert "resuming" in capsys.readouterr().out
    assert updates(out) == list(range(1, 9))
    assert rows(out)[:4] == first_rows
    assert [int(r["global_step"]) for r in rows(out)][4:] == [k * BATCH for k in range(5, 9)]
    assert load_checkpoint(out / "policy.pt")["updates"] == 8
    config = json.loads((out / "config.json").read_text())
    assert config["ppo"]["total_steps"] == 8192
    assert len(config["resumes"]) == 1 and config["resumes"][0]["update"] == 4
    assert "--resume" in config["resumes"][0]["command"]


def test_resume_drops_metrics_rows_after_the_checkpoint_and_skips_a_torn_one(tmp_path, capsys):
    out = tmp_path / "run"
    assert run(out, "--total-steps", "3072", "--eval-episodes", "0") == 0
    (out / LATEST).write_bytes(b"torn")  # the newest checkpoint is unreadable: fall back to update 2
    with open(out / "metrics.csv", "a") as f:
        f.write("4096,4,0.1,")  # a row cut off by a kill
    assert run(out, "--total-steps", "4096", "--resume") == 0
    err = capsys.readouterr().err
    assert "warning" in err and "checkpoint.prev.pt" in err
    assert updates(out) == [1, 2, 3, 4]


def test_sigint_saves_a_checkpoint_and_says_how_to_resume(tmp_path, capsys):
    out = tmp_path / "run"
    stop_waiting = threading.Event()
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when the tests run as a background job (CI)

    def interrupt_after_two_updates():
        while not stop_waiting.wait(0.02):
            if (out / "metrics.csv").exists() and len((out / "metrics.csv").read_text().splitlines()) > 2:
                os.kill(os.getpid(), signal.SIGINT)  # like Ctrl-C: delivered to the main thread
                return

    watcher = threading.Thread(target=interrupt_after_two_updates, daemon=True)
    watcher.start()
    try:
        code = run(out, "--total-steps", "100000000")
    finally:
        stop_waiting.set()
        watcher.join()
    assert code == 130
    err = capsys.readouterr().err
    assert "stopped by SIGINT" in err and "--resume" in err
    ckpt = load_checkpoint(out / LATEST)
    assert 1 <= ckpt["updates"] == len(rows(out)) == updates(out)[-1]
    assert not (out / "policy.pt").exists()
    assert signal.getsignal(signal.SIGINT) is before  # handler restored


def test_kill_9_mid_training_then_resume_ends_exactly_like_a_straight_run(tmp_path):
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    args = ["--task", "waypoint", *TINY, "--total-steps", str(20 * BATCH)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "quadpilot.train.cli", *args, "--out", str(killed)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            if (killed / "metrics.csv").exists() and len((killed / "metrics.csv").read_text().splitlines()) > 3:
                break
            time.sleep(0.02)
        assert proc.poll() is None, f"quad-train ended before it could be killed: {proc.stderr.read()}"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    done = load_for_resume(killed)[0]["updates"]
    assert 2 <= done < 20
    assert main([*args, "--out", str(killed), "--resume"]) == 0
    assert updates(killed) == list(range(1, 21))
    assert not [p for p in killed.iterdir() if p.name.endswith(".tmp")]
    # the kill cost nothing but time: the same weights and the same logged numbers as no kill at all
    assert main([*args, "--out", str(straight)]) == 0
    assert same_weights(killed / "policy.pt", straight / "policy.pt")
    for key in ("policy_loss", "value_loss", "ep_return", "success_rate", "curriculum_stage"):
        assert [r[key] for r in rows(killed)] == [r[key] for r in rows(straight)], key


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--task", "hover", "--preset", "nope"], "invalid choice: 'nope'"),
        (["--task", "hover", "--num-envs", "0"], "--num-envs: must be ≥ 1"),
        (["--task", "hover", "--total-steps", "lots"], "expected an integer"),
        (["--task", "orbit"], "invalid choice: 'orbit'"),
        (["--total-steps", "10"], "required: --task"),
        (["--task", "hover", "--bogus"], "unrecognized arguments: --bogus"),
        (["--task", "hover", "--resume"], "no checkpoint.pt"),
    ],
)
def test_bad_requests_exit_2_with_one_line(tmp_path, capsys, args, message):
    out = tmp_path / "fresh"
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("quad-train: error:") and message in err, err
    assert not out.exists()


def test_refuses_a_used_directory_and_a_changed_configuration(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert run(out, "--total-steps", "1024") == 2
    assert "not empty; add --resume" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "mine"

    used = tmp_path / "used"
    assert run(used, "--total-steps", "1024", "--eval-episodes", "0") == 0
    capsys.readouterr()
    assert main(["--task", "hover", "--out", str(used), "--num-envs", "32", "--resume"]) == 2
    assert "--num-envs 32 (checkpoint: 64)" in capsys.readouterr().err
    assert main(["--task", "circle", "--out", str(used), "--resume"]) == 2
    assert "holds a hover run" in capsys.readouterr().err


def test_help_lists_every_option_with_text(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    for opt in ("--task", "--total-steps", "--num-envs", "--seed", "--out", "--resume", "--preset", "--eval-episodes"):
        assert opt in text
    assert "--vehicle" in text and "--checkpoint-every" in text
    assert "Environment steps (transitions) to train for" in text  # from the PPOConfig field docstring


def test_metrics_header_is_fixed():
    """metrics.csv's columns are an interface (the walkthrough, quad-compare and users' notebooks
    read them by name): written out here, so that renaming, dropping or reordering one fails."""
    assert HEADER == (
        "global_step,update,time_s,policy_loss,value_loss,entropy,approx_kl,clip_fraction,"
        "explained_variance,grad_norm,lr,steps_per_s,rollout_s,env_s,inference_s,update_s,ep_return,"
        "ep_length,success_rate,episodes,nonfinite_skipped,curriculum_stage,target_radius,"
        "eval_success_rate,eval_error_m"
    )
    assert HEADER.split(",") == list(COLUMNS)

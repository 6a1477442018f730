"""Hostile input at the command line and in checkpoints: every console script answers a bad flag
with one line and exit 2, a bad file with one line and exit 1, and never a traceback; a run
directory is locked while a run writes to it; quad-export writes exactly the opset asked for; the
simulator process never outlives quad-sitl.

Most invocations here are real processes started from one warm interpreter (`_DRIVER`): it imports
the console scripts' modules and torch once, then forks a child per invocation that runs the entry
point exactly as the console script does (`sys.exit(main())`) with its own stdout, stderr and exit
status. Importing torch costs ~2 s per cold process on this machine, which over ~200 invocations
would be minutes. The child leaves with os._exit once main() has returned (the interpreter's
teardown with torch loaded costs another second and runs none of our code); an exception that
escapes main() still goes through the interpreter's own traceback and exit path. The console
scripts themselves are also run cold, once each (`test_console_scripts_answer_a_bad_flag_cold`).
"""

from __future__ import annotations

import io
import json
import os
import pickle
import signal
import subprocess
import sys
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from quadpilot.export.onnx_export import supported_opsets
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo.checkpoint import policy_checkpoint_dict
from quadpilot.train.runs.checkpoint import LATEST, checkpoint_dict
from quadpilot.train.runs.runlog import LOCK

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
HOVER_PT = ROOT / "models" / "hover" / "policy.pt"
ENTRY = {
    "quad-sitl": "quadpilot.sitl:main",
    "quad-train": "quadpilot.train.cli:main",
    "quad-export": "quadpilot.export.cli:main",
    "quad-demo": "quadpilot.demo:main",
    "quad-compare": "quadpilot.studies.compare:main",
    "montage": "quadpilot.studies.learning_montage:main",
}
# what the commands import lazily (torch._dynamo: on the first torch.optim.Adam), imported once in
# the driver instead of in every child
PRELOAD = [
    *sorted({e.split(":")[0] for e in ENTRY.values()}),
    *("torch", "torch._dynamo", "onnx", "onnxruntime", "gymnasium", "rich.progress", "matplotlib.backends.backend_agg"),
    *(
        "quadpilot.train." + m
        for m in ("ppo", "runs.checkpoint", "envs", "envs.curriculum", "envs.evaluate", "runs.runlog", "sac")
    ),
    *("quadpilot.export.onnx_export", "quadpilot.export.c_export", "quadpilot.simulator", "quadpilot.viz"),
    *("quadpilot.runtime", "quadpilot.autopilot.node", "quadpilot.link.tlog", "quadpilot.core.mission"),
]

_DRIVER = r"""
import gc, importlib, json, os, sys, time

spec = json.load(sys.stdin)
for name in spec["preload"]:
    importlib.import_module(name)
gc.freeze()  # the imported heap stays shared with the children: their collections do not copy it
queue, running, results = list(spec["cases"]), {}, {}
while queue or running:
    while queue and len(running) < spec["workers"]:
        case = queue.pop(0)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # from here on this process is the console script
            os.chdir(case["cwd"])
            for fd, suffix in ((1, "out"), (2, "err")):
                f = os.open(os.path.join(spec["out_dir"], case["id"] + "." + suffix), os.O_WRONLY | os.O_CREAT)
                os.dup2(f, fd)
                os.close(f)
            os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
            module, func = case["entry"].split(":")
            sys.argv = [case["prog"], *case["argv"]]
            try:
                code = getattr(sys.modules[module], func)()
            except SystemExit as e:
                code = e.code
            if code is None:
                code = 0
            elif not isinstance(code, int):
                print(code, file=sys.stderr)
                code = 1
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code & 0xFF)
        running[pid] = (case, time.monotonic())
    pid, status = os.waitpid(-1, os.WNOHANG)
    if pid == 0:
        for p, (case, t0) in list(running.items()):
            if time.monotonic() - t0 > spec["timeout"]:
                os.kill(p, 9)
        time.sleep(0.005)
        continue
    case, t0 = running.pop(pid)
    results[case["id"]] = {"code": os.waitstatus_to_exitcode(status), "seconds": time.monotonic() - t0}
json.dump(results, sys.stdout)
"""


class Case:
    """One invocation: `prog` (a key of ENTRY) with `argv`; `code` the documented exit status;
    `says` a piece of the one stderr line (None: not checked); `lines` how many stderr lines."""

    def __init__(self, group: str, prog: str, argv: list[str], code: int, says: str | None = None, lines: int = 1):
        self.group, self.prog, self.argv, self.code, self.says, self.lines = group, prog, argv, code, says, lines
        self.id = ""
        self.result: dict = {}
        self.err = ""

    def __repr__(self) -> str:
        return f"{self.prog} {' '.join(self.argv)}"

    def problem(self) -> str | None:
        """What is wrong with how the invocation ended, or None."""
        got = self.result.get("code")
        if "Traceback" in self.err:
            return f"traceback: {self.err.strip().splitlines()[-1]}"
        if got != self.code:
            return f"exit {got} (expected {self.code}): {self.err.strip()[-300:]!r}"
        lines = self.err.strip("\n").splitlines()
        if self.lines is not None and len(lines) != self.lines:
            return f"{len(lines)} stderr lines (expected {self.lines}): {self.err[-500:]!r}"
        if self.says is not None and self.says not in self.err:
            return f"stderr does not say {self.says!r}: {self.err.strip()!r}"
        return None


def run_cases(cases: list[Case], tmp: Path, workers: int = 2, timeout: float = 60.0) -> float:
    """Run every case from the warm driver; fills in .result and .err; returns the wall time."""
    out_dir, cwd = tmp / "driver-out", tmp / "cwd"
    out_dir.mkdir()
    cwd.mkdir()
    for k, c in enumerate(cases):
        c.id = f"{c.prog}-{k}"
    spec = {
        "out_dir": str(out_dir),
        "workers": workers,
        "timeout": timeout,
        "preload": PRELOAD,
        "cases": [{"id": c.id, "entry": ENTRY[c.prog], "prog": c.prog, "argv": c.argv, "cwd": str(cwd)} for c in cases],
    }
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-X", "dev", "-c", _DRIVER],
        input=json.dumps(spec),
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads(done.stdout)
    for c in cases:
        c.result = results.get(c.id, {})
        c.err = (out_dir / f"{c.id}.err").read_text(errors="replace")
    return time.monotonic() - t0


# --- the inputs ---------------------------------------------------------------------------------


def _torch_bytes(obj) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf)
    return buf.getvalue()


class _Evil:
    """Unpickling this runs a shell command (the classic pickle attack): it must never run."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _zip_with_data_pkl(good: bytes, payload: bytes) -> bytes:
    """A torch zip file whose data.pkl is replaced by `payload`."""
    src, buf = zipfile.ZipFile(io.BytesIO(good)), io.BytesIO()
    with zipfile.ZipFile(buf, "w") as dst:
        for info in src.infolist():
            data = payload if info.filename.endswith("/data.pkl") else src.read(info.filename)
            dst.writestr(info, data)
    return buf.getvalue()


def _zip_without(good: bytes, suffix: str) -> bytes:
    src, buf = zipfile.ZipFile(io.BytesIO(good)), io.BytesIO()
    with zipfile.ZipFile(buf, "w") as dst:
        for info in src.infolist():
            if not info.filename.endswith(suffix):
                dst.writestr(info, src.read(info.filename))
    return buf.getvalue()


def _key(d, k):
    """`k` as `d` spells it: list indices and the optimizer's parameter numbers are ints."""
    return int(k) if isinstance(d, list) or (isinstance(k, str) and k.isdigit() and int(k) in d) else k


def _edit(base: dict, path: str | tuple, value=None, *, delete: bool = False) -> dict:
    """A deep copy of `base` with the entry at `path` (dotted, or a tuple of keys) set to `value`
    (called with the old value if callable), or deleted."""
    ckpt = pickle.loads(pickle.dumps(base))  # tensors and plain data only: a deep copy
    *parents, last = path.split(".") if isinstance(path, str) else path
    d = ckpt
    for k in parents:
        d = d[_key(d, k)]
    last = _key(d, last)
    if delete:
        del d[last]
    else:
        d[last] = value(d[last]) if callable(value) else value
    return ckpt


def malformed_policies(base: dict, marker: Path) -> dict[str, bytes]:
    """Name → file content of a checkpoint that quad-export must refuse (exit 1, one line)."""
    good = HOVER_PT.read_bytes()
    rng = np.random.default_rng(0)
    w0 = next(k for k in base["model"] if k.endswith("weight"))
    evil_pickle = pickle.dumps(_Evil(marker), protocol=2)
    files = {
        "empty file": b"",
        "truncated to half": good[: len(good) // 2],
        "random bytes": rng.integers(0, 256, 4096, dtype=np.uint8).tobytes(),
        "a zip with other entries": _zip_bytes({"hello.txt": b"hi", "data/0": b"\0" * 8}),
        "a torch zip without its data.pkl": _zip_without(good, "/data.pkl"),
        "a torch zip without a tensor's storage": _zip_without(good, "/data/0"),
        "a plain pickle that runs a command": evil_pickle,
        "a torch zip whose pickle runs a command": _zip_with_data_pkl(good, evil_pickle),
        # protocol 4 makes torch warn on stderr before it refuses: still one line from us
        "a protocol-4 pickle that runs a command": pickle.dumps(_Evil(marker), protocol=4),
        "a torch zip whose protocol-4 pickle runs a command": _zip_with_data_pkl(
            good, pickle.dumps(_Evil(marker), protocol=4)
        ),
        "a JSON file": json.dumps({"schema": "quadpilot.checkpoint/1"}).encode(),
        "an ONNX file": (ROOT / "models" / "hover" / "policy.onnx").read_bytes(),
        "a list": _torch_bytes([1, 2, 3]),
        "a tensor": _torch_bytes(torch.zeros(3)),
        "no schema": _torch_bytes({"model": {}}),
        "another schema version": _torch_bytes(_edit(base, "schema", "quadpilot.checkpoint/2")),
        "a schema that is a number": _torch_bytes(_edit(base, "schema", 1)),
        "an unknown algorithm": _torch_bytes(_edit(base, "algo", "dqn")),
        "an algorithm that is a list": _torch_bytes(_edit(base, "algo", ["ppo"])),
        "no model": _torch_bytes(_edit(base, "model", delete=True)),
        "ppo_config a string": _torch_bytes(_edit(base, "ppo_config", "fast")),
        "huge hidden layers": _torch_bytes(_edit(base, "ppo_config.actor_hidden", [100_000, 100_000])),
        "a 2**40-wide layer": _torch_bytes(_edit(base, "ppo_config.actor_hidden", [2**40])),
        "a huge LSTM": _torch_bytes(_edit(_edit(base, "ppo_config.arch", "lstm"), "ppo_config.lstm_hidden", 10**7)),
        "a huge observation history": _torch_bytes(_edit(base, "ppo_config.obs_history", 10**6)),
        "num_envs a string": _torch_bytes(_edit(base, "ppo_config.num_envs", "64")),
        "an unknown ppo_config field": _torch_bytes(_edit(base, "ppo_config.evil", 1)),
        "an unknown activation": _torch_bytes(_edit(base, "ppo_config.activation", "gelu")),
        "an unknown architecture": _torch_bytes(_edit(base, "ppo_config.arch", "transformer")),
        "a NaN learning rate": _torch_bytes(_edit(base, "ppo_config.lr", float("nan"))),
        "an unknown task": _torch_bytes(_edit(base, "env_config.task", "orbit")),
        "a vehicle that is a number": _torch_bytes(_edit(base, "env_config.vehicle", 12)),
        "a negative mass": _torch_bytes(_edit(base, "env_config.vehicle.mass", -1.0)),
        "a mass that is a string": _torch_bytes(_edit(base, "env_config.vehicle.mass", "heavy")),
        "a home of two numbers": _torch_bytes(_edit(base, "env_config.home", [0.0, 0.0])),
        "a NaN control period": _torch_bytes(_edit(base, "env_config.dt", float("nan"))),
        "a float16 simulation": _torch_bytes(_edit(base, "env_config.dtype", "float16")),
        "an unknown reward weight": _torch_bytes(_edit(base, "env_config.reward", {"evil": 1.0})),
        "an unknown observation layout": _torch_bytes(_edit(base, "obs_layout", {"name": "quadpilot.obs.evil/9"})),
        "obs_layout a string": _torch_bytes(_edit(base, "obs_layout", "hover")),
        "the track layout on a hover env": _torch_bytes(_edit(base, "obs_layout.name", "quadpilot.obs.track/1")),
        "model a list": _torch_bytes(_edit(base, "model", [1, 2])),
        "a weight missing": _torch_bytes(_edit(base, ("model", w0), delete=True)),
        "a weight of the wrong shape": _torch_bytes(_edit(base, ("model", w0), torch.zeros(3, 3))),
        "NaN weights": _torch_bytes(_edit(base, ("model", w0), lambda t: torch.full_like(t, float("nan")))),
        "integer weights": _torch_bytes(_edit(base, ("model", w0), lambda t: torch.zeros(t.shape, dtype=torch.int64))),
        "an unexpected weight": _torch_bytes(_edit(base, ("model", "evil.weight"), torch.zeros(2))),
        "a weight that is a string": _torch_bytes(_edit(base, ("model", w0), "weights")),
        "obs_rms without var": _torch_bytes(_edit(base, "obs_rms.var", delete=True)),
        "obs_rms of the wrong length": _torch_bytes(_edit(base, "obs_rms.mean", torch.zeros(5, dtype=torch.float64))),
        "a negative variance": _torch_bytes(_edit(base, "obs_rms.var", lambda t: -torch.ones_like(t))),
        "a clip that is a string": _torch_bytes(_edit(base, "obs_rms.clip", "ten")),
        "a negative step count": _torch_bytes(_edit(base, "global_step", -5)),
        "a step count that is a string": _torch_bytes(_edit(base, "global_step", "many")),
        "extra a list": _torch_bytes(_edit(base, "extra", [1])),
        "a curriculum of garbage": _torch_bytes(_edit(base, "extra.curriculum", {"config": {"radii": "x"}})),
        "a SAC file without its critics": _torch_bytes(_edit(base, "algo", "sac")),
    }
    return files


def _zip_bytes(entries: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in entries.items():
            z.writestr(name, data)
    return buf.getvalue()


TINY = PPOConfig(num_envs=8, rollout_steps=16, minibatch_size=64, epochs=1, total_steps=128, threads=1)


def resumable_checkpoint() -> dict:
    """checkpoint.pt of a tiny hover run after one update (optimizer moments filled in)."""
    torch.set_num_threads(1)
    ppo = PPO(TINY, make_config("hover"))
    ppo.iterate()
    return checkpoint_dict(ppo, {"preset": "fast", "elapsed_s": 0.1})


def malformed_resumes(base: dict) -> dict[str, dict | bytes]:
    """Name → a checkpoint.pt that quad-train --resume must refuse (exit 1, one line)."""
    opt_state = next(iter(base["optimizer"]["state"]))
    return {
        "torn bytes": b"torn",
        "the observation of the wrong shape": _edit(base, "trainer.obs", torch.zeros(3, 18)),
        "an environment array of the wrong shape": _edit(base, "env.state", torch.zeros(2, 12)),
        "an environment array missing": _edit(base, "env.phase", delete=True),
        "an environment flag that is a string": _edit(base, "env.started", "yes"),
        "an Adam moment of the wrong shape": _edit(base, f"optimizer.state.{opt_state}.exp_avg", torch.zeros(7)),
        "NaN Adam moments": _edit(
            base, f"optimizer.state.{opt_state}.exp_avg", lambda t: torch.full_like(t, float("nan"))
        ),
        "an extra parameter group": _edit(base, "optimizer.param_groups", lambda g: [*g, {**g[0], "params": [99]}]),
        "optimizer a list": _edit(base, "optimizer", []),
        "an unknown bit generator": _edit(base, "rng.env.bit_generator", "Evil"),
        "a torch RNG state of the wrong length": _edit(base, "rng.torch_gen", torch.zeros(3, dtype=torch.uint8)),
        "episode returns that are strings": _edit(base, "trainer.ep_returns", ["x"]),
        "a negative non-finite streak": _edit(base, "trainer.nonfinite_streak", -1),
        "an update count that is a string": _edit(base, "updates", "3"),
        "a deployable policy only": policy_checkpoint_dict(
            PPO(TINY, make_config("hover")).model, TINY, make_config("hover")
        ),
    }


def bad_flag_cases(d: Path) -> list[Case]:
    """The fuzz table: bad flags of every command (exit 2) and bad files (exit 1)."""
    hover, adir, afile = str(d / "hover.pt"), str(d / "adir"), str(d / "afile")
    t: list[Case] = []

    def add(prog, argv, code=2, says=None):
        t.append(Case("fuzz", prog, argv, code, says))

    for argv in (
        ["--bogus"],
        ["--episodes"],
        ["--episodes", "x"],
        ["--episodes", "0"],
        ["--episodes", "-1"],
        ["--episodes", "99999999999999999999"],
        ["--duration", "nan"],
        ["--duration", "inf"],
        ["--duration", "-1"],
        ["--duration", "1e308"],
        ["--seed", "-1"],
        ["--backend", "foo"],
        ["--task", "orbit"],
        ["--gcs", ""],
        ["--gcs", "nowhere"],
        ["--listen", "garbage"],
        ["--listen", "tcp:127.0.0.1:99999"],
        ["--connect", "tcp:127.0.0.1:4560"],
        ["--node-only"],
        ["--node-only", "--connect", "garbage"],
        ["--node-only", "--connect", "tcp:127.0.0.1:4560", "--wind", "1,0,0"],
        ["--json", adir],
        ["--json", str(d / "missing" / "x.json")],
        ["--json", "/sys/quadpilot.json"],
        ["--json", f"{afile}/x.json"],
        ["--json", ""],
        ["--plot", str(d / "p.txt")],
        ["--video", str(d / "v.avi")],
        ["--tlog", adir],
        ["--tlog", "/sys/quadpilot.tlog"],
        ["--key", str(d / "nokey")],
        ["--key", adir],
        ["--wind", "1,2"],
        ["--wind", "a,b,c"],
        ["--wind", "nan,0,0"],
        ["--wind", "1e400,0,0"],
        ["--mass-scale", "0"],
        ["--mass-scale", "-1"],
        ["--drag", "nan"],
        ["--gust", "inf"],
        ["--spin-us", "nan"],
        ["--sim-only", "--spin-us", "x"],
        ["--vehicle", "nope"],
        ["--motor-tau=-0.1"],
        ["--wïnd", "1,0,0"],
        [str(d / "missing.onnx")],
        [adir],
        [""],
        ["--sim-only", "--bogus"],
        ["--sim-only", "--listen", "bad"],
        ["--sim-only", "--rate", "0"],
        ["--realtime", "--lockstep"],
    ):
        add("quad-sitl", argv)
    add("quad-sitl", [str(d / "garbage.onnx")], 1, "garbage.onnx")
    add("quad-sitl", ["--key", str(d / "short.key")], 1, "short.key")
    for argv in (
        ["--bogus"],
        ["--num-envs", "0"],
        ["--num-envs", "-5"],
        ["--num-envs", "x"],
        ["--num-envs", "1000000000000"],
        ["--steps", "-1"],
        ["--steps", "1e3"],
        ["--steps", "10000000000000"],
        ["--seed", "-1"],
    ):
        add("quad-demo", argv)
    h = ["--task", "hover", "--out"]
    for argv in (
        ["--bogus"],
        ["--task"],
        ["--task", ""],
        ["--task", "hövér"],
        [*h, str(d / "t1"), "--num-envs", "0"],
        [*h, str(d / "t1"), "--num-envs", "1000000000000"],
        [*h, str(d / "t1"), "--num-envs", "1e3"],
        [*h, str(d / "t1"), "--total-steps", "-5"],
        [*h, str(d / "t1"), "--threads", "1000000"],
        [*h, str(d / "t1"), "--eval-episodes", "-1"],
        [*h, str(d / "t1"), "--checkpoint-every", "0"],
        [*h, str(d / "t1"), "--motor-tau", "nan"],
        [*h, str(d / "t1"), "--motor-tau", "inf"],
        [*h, "/sys/quadpilot-run"],
        [*h, afile],
        [*h, f"{afile}/sub"],
        [*h, ""],
        [*h, str(d / "t1"), "--set", "tau=0.1"],
        [*h, str(d / "t1"), "--algo", "sac", "--set", "foo"],
        [*h, str(d / "t1"), "--algo", "sac", "--set", "tau=abc"],
        [*h, str(d / "t1"), "--algo", "sac", "--set", "actor_hidden=100000000"],
        [*h, str(d / "t1"), "--preset", "nope"],
        [*h, str(d / "t1"), "--randomize", "nope"],
        [*h, str(d / "t1"), "--obs-history", "1000000"],
        [*h, str(d / "t1"), "--minibatch-size", "1000000000000"],
        [*h, str(d / "t1"), "--num-envs", "65536", "--rollout-steps", "65536"],
        [*h, str(d / "t1"), "--seed", "99999999999999999999999"],
        [*h, str(d / "nothere"), "--resume"],
        [*h, afile, "--resume"],
    ):
        add("quad-train", argv)
    add("quad-train", [*h, str(d / "torn-run"), "--resume"], 1, "checkpoint.pt")
    for argv in (
        [],
        ["--bogus"],
        [str(d / "missing.pt")],
        [adir],
        [""],
        [hover, "--parity-samples", "0"],
        [hover, "--parity-samples", "1000000000000"],
        [hover, "--parity-samples", "x"],
        [hover, "--format", "rust"],
        [hover, "-o", adir],
        [hover, "-o", str(d / "missing" / "x.onnx")],
        [hover, "-o", "/sys/quadpilot.onnx"],
        [hover, "-o", f"{afile}/x.onnx"],
        [hover, "-o", ""],
        [hover, "--format", "c", "-o", afile],
    ):
        add("quad-export", argv)
    add("quad-export", [str(d / "garbage.pt")], 1, "garbage.pt")
    add("quad-export", [afile], 1, "afile")
    c = ["run", "--out", str(d / "sweep-new")]
    for argv in (
        [],
        ["run"],
        ["bogus"],
        [*c, "--seeds", "x"],
        [*c, "--seeds", ""],
        [*c, "--seeds", "1,1"],
        [*c, "--seeds=-1"],
        [*c, "--algos", "foo"],
        [*c, "--threads", "0"],
        [*c, "--workers", "1000000000"],
        [*c, "--eval-every", "0"],
        [*c, "--engine", "foo"],
        ["run", "--out", "/sys/quadpilot-sweep"],
        ["run", "--out", afile],
        ["report"],
        ["report", str(d / "nowhere")],
    ):
        add("quad-compare", argv)
    add("quad-compare", ["report", str(d / "sweep"), "--doc", str(d / "c.md"), "--figures", str(d / "fig")], 1)
    for argv in (
        [],
        [str(d / "nowhere")],
        [adir],
        [adir, "-o", str(d / "m.png")],
        [adir, "-o", str(d / "missing" / "m.gif")],
        [adir, "--size", "big"],
        [adir, "--size", "100000x100000"],
        [adir, "--seconds=-1"],
        [adir, "--seconds", "nan"],
        [adir, "--seconds", "1e300"],
        [adir, "--fps", "0"],
        [adir, "--steps", "x"],
        [adir, "--snapshots", "0"],
    ):
        add("montage", argv)
    return t


def negative_value_cases(d: Path) -> list[Case]:
    """Values that start with '-' are values: accepted where valid, refused for what they say."""
    fly = ["--episodes", "1", "--duration", "0.2", "--gcs", "none"]
    return [
        Case("negative", "quad-sitl", ["--wind=-0.9,0,0", *fly, "--json", str(d / "w1.json")], 0, lines=0),
        Case("negative", "quad-sitl", ["--wind", "-0.9,0,0", *fly, "--json", str(d / "w2.json")], 0, lines=0),
        Case("negative", "quad-sitl", ["--sim-only", "--wind", "-0.9,0,0", "--rate", "0"], 2, "--rate"),
        Case("negative", "quad-sitl", ["--mass-scale", "-1"], 2, "expected a finite number > 0"),
        Case("negative", "quad-sitl", ["--spin-us", "-500"], 2, "expected a number from 0 to 1,000,000"),
        Case("negative", "quad-train", ["--task", "hover", "--out", str(d / "neg"), "--motor-tau", "-0.1"], 2, "≥ 0"),
        Case("negative", "quad-export", [str(d / "hover.pt"), "--opset", "-1"], 2, "expected 18"),
        Case("negative", "quad-demo", ["--seed", "-1"], 2, "expected 0 to"),
    ]


def opset_cases(d: Path) -> list[Case]:
    ok = supported_opsets()
    refused = [ok.start - 1, ok.stop, 99, 0, 7]
    says = f"expected {ok.start} to {ok.stop - 1}"
    cases = [Case("opset", "quad-export", [str(d / "hover.pt"), "--opset", str(v)], 2, says) for v in refused]
    for v in (ok.stop - 1,):  # the default, ok.start, is what every test in tests/export writes
        out = str(d / f"opset{v}.onnx")
        cases.append(Case("opset", "quad-export", [str(d / "hover.pt"), "-o", out, "--opset", str(v)], 0, lines=0))
        cases[-1].onnx, cases[-1].opset = out, v
    return cases


@pytest.fixture(scope="module")
def driven(tmp_path_factory):
    """Every subprocess case of this file, run once from the warm driver: {group: [Case]}."""
    d = tmp_path_factory.mktemp("cli-input")
    # a copy: quad-export's default output is beside its checkpoint, and no case may write in models/
    (d / "hover.pt").write_bytes(HOVER_PT.read_bytes())
    (d / "adir").mkdir()
    (d / "afile").write_text("x")
    (d / "garbage.pt").write_bytes(os.urandom(300))
    (d / "garbage.onnx").write_bytes(b"\0" * 100)
    (d / "short.key").write_bytes(b"123")
    (d / "torn-run").mkdir()
    (d / "torn-run" / LATEST).write_bytes(b"torn")
    (d / "sweep").mkdir()
    (d / "sweep" / "sweep.json").write_text("{not json")
    marker = d / "pickle-ran"
    base = torch.load(HOVER_PT, weights_only=True)
    cases = bad_flag_cases(d) + negative_value_cases(d) + opset_cases(d)
    for k, (name, data) in enumerate(malformed_policies(base, marker).items()):
        path = d / "policies" / f"{k:02d}.pt"
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(data)
        case = Case("policy", "quad-export", [str(path), "-o", str(d / f"p{k}.onnx")], 1, str(path))
        case.name = name
        cases.append(case)
    resumable = resumable_checkpoint()
    for k, (name, ckpt) in enumerate({"valid (control)": resumable, **malformed_resumes(resumable)}.items()):
        run = d / "resume" / f"run{k:02d}"
        run.mkdir(parents=True)
        (run / LATEST).write_bytes(ckpt if isinstance(ckpt, bytes) else _torch_bytes(ckpt))
        argv = ["--task", "hover", "--out", str(run), "--resume", "--total-steps", "128", "--eval-episodes", "0"]
        case = Case("resume", "quad-train", argv, 0 if k == 0 else 1, None if k == 0 else str(run / LATEST))
        case.lines = None if k == 0 else 1
        case.name = name
        cases.append(case)
    seconds = run_cases(cases, d)
    groups: dict[str, list[Case]] = {}
    for c in cases:
        groups.setdefault(c.group, []).append(c)
    slowest = sorted(cases, key=lambda c: -c.result.get("seconds", 0))[:5]
    print(f"{len(cases)} invocations in {seconds:.1f} s; slowest:", [(c, c.result.get("seconds")) for c in slowest])
    return groups, marker


def _problems(cases: list[Case]) -> list[str]:
    return [f"{c!r} ({getattr(c, 'name', '')}): {p}" for c in cases if (p := c.problem()) is not None]


# --- the tests ----------------------------------------------------------------------------------


def test_every_command_answers_bad_input_in_one_line(driven):
    """Unknown flags, missing values, wrong types, NaN/inf/negative/huge numbers, empty strings,
    unicode, paths that are directories, missing, unwritable or through a file, for quad-sitl,
    quad-demo, quad-train, quad-export, quad-compare and the montage: one stderr line, exit 2 for
    a flag and 1 for a file, no traceback, and nothing that allocates terabytes or runs forever."""
    cases = driven[0]["fuzz"]
    assert len(cases) >= 100
    assert not _problems(cases), "\n".join(_problems(cases))


def test_quad_export_refuses_each_malformed_checkpoint_in_one_line(driven):
    """Truncated, random, foreign and hostile files, and valid torch files holding wrong types,
    shapes, missing keys, NaN weights, huge dimensions or another schema: exit 1, one line naming
    the file, no traceback."""
    cases = driven[0]["policy"]
    assert len(cases) >= 35
    assert not _problems(cases), "\n".join(_problems(cases))


def test_a_checkpoint_never_runs_the_code_it_holds(driven):
    """Four files whose pickle calls os.system were refused (above) and the command never ran."""
    groups, marker = driven
    assert {
        "a plain pickle that runs a command",
        "a torch zip whose pickle runs a command",
        "a protocol-4 pickle that runs a command",
        "a torch zip whose protocol-4 pickle runs a command",
    } <= {c.name for c in groups["policy"]}
    assert not marker.exists()


def test_resume_refuses_a_malformed_checkpoint_in_one_line(driven):
    """quad-train --resume on a checkpoint.pt with torn bytes, or entries of the wrong shape, type
    or structure for the trainer its configuration builds: exit 1, one line naming the file. The
    unmodified checkpoint resumes (exit 0), so each refusal is the edit's doing."""
    control, *cases = driven[0]["resume"]
    assert control.problem() is None, control.problem()
    assert len(cases) >= 12
    assert not _problems(cases), "\n".join(_problems(cases))


def test_export_writes_exactly_the_requested_opset_and_refuses_others(driven):
    """--opset outside what the exporter writes exactly (and the runtime checks) is a bad flag that
    names the accepted range; inside it, the written file declares the requested opset."""
    cases = driven[0]["opset"]
    assert not _problems(cases), "\n".join(_problems(cases))
    written = [c for c in cases if c.code == 0]
    assert written
    for c in written:
        model = onnx.load(c.onnx)
        assert {o.domain: o.version for o in model.opset_import}[""] == c.opset


def test_negative_numbers_are_flag_values(driven):
    """--wind=-0.9,0,0 and --wind -0.9,0,0 fly; a negative value elsewhere is refused for what it
    says, not taken for an unknown option (and the simulator flags reach the simulator process)."""
    cases = driven[0]["negative"]
    assert not _problems(cases), "\n".join(_problems(cases))
    for c in cases[:2]:
        summary = json.loads(Path(c.argv[c.argv.index("--json") + 1]).read_text())
        assert summary["episodes"] == 1


def test_console_scripts_answer_a_bad_flag_cold():
    """Each console script from the virtual environment, cold, with an unknown flag."""
    commands = [[str(BIN / name), "--no-such-flag"] for name in ENTRY if name != "montage"]
    for study in ("learning_montage", "robustness", "sac_compare"):
        commands.append([sys.executable, "-X", "dev", "-m", f"quadpilot.studies.{study}", "--no-such-flag"])
    with ThreadPoolExecutor(3) as pool:
        done = list(pool.map(lambda cmd: subprocess.run(cmd, capture_output=True, text=True, timeout=120), commands))
    for cmd, r in zip(commands, done, strict=True):
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, (cmd, r.stderr)


# --- a run directory is locked while a run writes to it ---------------------------------------


def test_a_second_run_in_a_locked_run_directory_is_refused_and_changes_nothing(tmp_path, capfd):
    """A run holds its directory's lock; a second quad-train there, fresh or --resume, gets one
    line and exit 1 and touches none of the running one's files; kill -9 frees the lock, so
    --resume works after it."""
    from quadpilot.train.cli import main

    out = tmp_path / "run"
    tiny = ["--num-envs", "8", "--rollout-steps", "16", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0"]
    args = ["--task", "hover", "--out", str(out), *tiny]
    proc = subprocess.Popen(
        [sys.executable, "-m", "quadpilot.train.cli", *args, "--total-steps", "100000000"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 90
        while not ((out / LATEST).exists() and len((out / "metrics.csv").read_text().splitlines()) > 2):
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else "slow"
            time.sleep(0.05)
        config = (out / "config.json").read_bytes()
        capfd.readouterr()
        for extra in (["--resume"], []):
            rows = len((out / "metrics.csv").read_text().splitlines())
            assert main([*args, *extra, "--total-steps", "256"]) == 1
            err = capfd.readouterr().err
            assert err.count("\n") == 1 and f"in use by another run (pid {proc.pid})" in err, err
            assert (out / "config.json").read_bytes() == config  # a resume would have recorded itself
            assert len((out / "metrics.csv").read_text().splitlines()) >= rows  # a resume would have cut it
        assert proc.poll() is None
        assert (out / LOCK).read_text().strip() == str(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        proc.kill()
        proc.wait()
    assert main([*args, "--resume", "--total-steps", "128"]) == 0  # the kernel dropped the lock with the process
    assert (out / "policy.pt").exists()


# --- the simulator never outlives quad-sitl ---------------------------------------------------


def _simulators_on(listen: str) -> list[int]:
    """Pids of the simulator processes (python -m quadpilot.simulator) told to listen on `listen`."""
    found = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                args = (p / "cmdline").read_bytes().decode(errors="replace").split("\0")
            except OSError:
                continue
            if "quadpilot.simulator" in args and listen in args:
                found.append(int(p.name))
    return found


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; PR_SET_PDEATHSIG is Linux's")
def test_the_simulator_never_outlives_quad_sitl(tmp_path):
    """A bad output path is refused before the simulator starts; SIGTERM mid-flight ends quad-sitl
    through its cleanup (exit 143) with the simulator stopped; and a parent killed with -9 while its
    simulator waits for a connection (the simulator never writes, so no broken pipe ends it) takes
    the simulator with it (PR_SET_PDEATHSIG)."""
    listen = f"tcp:127.0.0.1:{_free_port()}"
    cmd = [sys.executable, "-X", "dev", "-m", "quadpilot.sitl", "--listen", listen, "--gcs", "none"]
    done = subprocess.run([*cmd, "--tlog", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "--tlog" in done.stderr, done.stderr
    assert not _simulators_on(listen)

    def ends_with_its_simulator(argv: list[str], listen: str, sig: int, expected: int) -> None:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            while not _simulators_on(listen):
                assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
                time.sleep(0.05)
            time.sleep(0.5)  # flying, or waiting for a connection
            proc.send_signal(sig)
            assert proc.wait(20) == expected, proc.stderr.read()
            deadline = time.monotonic() + 10
            while _simulators_on(listen) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert not _simulators_on(listen), f"the simulator outlived its parent after signal {sig}"
        finally:
            proc.kill()
            proc.wait()
            for pid in _simulators_on(listen):
                os.kill(pid, signal.SIGKILL)

    flying = f"tcp:127.0.0.1:{_free_port()}"
    fly = [*cmd[:5], "--listen", flying, "--gcs", "none", "--realtime", "--episodes", "100", "--duration", "60"]
    waiting = f"tcp:127.0.0.1:{_free_port()}"
    parent = (
        "import sys, time\n"
        "from quadpilot.sitl.simulator_process import SimulatorProcess\n"
        "sim = SimulatorProcess([sys.executable, '-m', 'quadpilot.simulator', '--sim-only', '--listen', "
        f"'{waiting}'])\n"
        "assert sim.wait_listening(60)[0]\n"
        "time.sleep(120)\n"
    )
    runs = [
        (fly, flying, signal.SIGTERM, 128 + signal.SIGTERM),
        ([sys.executable, "-c", parent], waiting, signal.SIGKILL, -signal.SIGKILL),
    ]
    with ThreadPoolExecutor(2) as pool:
        for f in [pool.submit(ends_with_its_simulator, *run) for run in runs]:
            f.result()

"""Every path flag of every console script, against every way the OS can refuse a path: one line on
stderr, the documented exit code (docs/security.md), never a traceback.

The path flags (quad-demo has none): quad-sitl POLICY, --key, --vehicle, --json, --plot, --video,
--tlog, --trace (--node-only) and --sim-only --json; quad-export CHECKPOINT and -o (an ONNX file, or
with --format c a directory); quad-train --out (a new run, or the run --resume reads) and --vehicle;
quad-compare run --out, report SWEEP, --doc and --figures.

The OS errors: ENAMETOOLONG (a 300-byte name), ENOTDIR (a path through a file), ELOOP (a path
through a symbolic link to itself) and EISDIR (a directory where a file is expected) are made for
real. EACCES cannot be (the tests run as root in CI, and root reads and writes whatever the mode
bits say), nor EROFS and ENOSPC without mounting a file system: those three are raised by a mock of
the opening (`open`, `os.open`, `os.mkdir`) or, for ENOSPC, of the write, for paths under the one
given. Expected exit codes: 2 for a flag whose path the OS refuses before any work (it does not
exist, is of the wrong kind, or cannot be written: the output probe), 1 for a file that exists but
cannot be read and for an output that could not be written at the end (ENOSPC), and 1 for
--vehicle whatever the reason (its file reader, `core.vehicle_file`, says why).

Each case runs the command's entry point in this process (the mocks must reach it); an exception
that leaves it is a traceback."""

from __future__ import annotations

import builtins
import errno
import io
import os
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quadpilot.runtime.cbackend import DIGEST_NAME, find_compiler
from quadpilot.sitl import SHIPPED_HOVER

ROOT = Path(__file__).resolve().parents[2]
HOVER_PT = ROOT / "models" / "hover" / "policy.pt"
FLY = ["--episodes", "1", "--duration", "0.3", "--gcs", "none"]


def _entry(prog: str):
    if prog == "quad-sitl":
        from quadpilot.sitl import main
    elif prog == "quad-export":
        from quadpilot.export.cli import main
    elif prog == "quad-train":
        from quadpilot.train.cli import main
    else:
        from quadpilot.studies.compare import main
    return main


@dataclass
class Ctx:
    """Where a case runs: its directory `d` (with `afile`, `adir`, `loop`, a copy of the hover
    checkpoint and a sweep) and the port of a simulator (--node-only) or for one (--sim-only)."""

    d: Path
    port: int = 9


@dataclass(frozen=True)
class Flag:
    prog: str
    name: str
    kind: str
    """in-file, in-dir, out-file or out-dir."""
    argv: object
    """(path: str, ctx: Ctx) → the invocation."""
    always: int | None = None
    """The exit code whatever the error (--vehicle: its reader's 1)."""

    @property
    def id(self) -> str:
        return f"{self.prog} {self.name}"


TRAIN = ["--task", "hover", "--total-steps", "64", "--num-envs", "8", "--eval-episodes", "0"]


def _report(c: Ctx, sweep=None, doc=None, figures=None) -> list[str]:
    return [
        "report",
        sweep or str(c.d / "sweep"),
        "--doc",
        doc or str(c.d / "c.md"),
        "--figures",
        figures or str(c.d / "fig"),
    ]


FLAGS = [
    Flag("quad-sitl", "POLICY", "in-file", lambda p, c: [p, *FLY]),
    Flag("quad-sitl", "--key", "in-file", lambda p, c: ["--key", p, *FLY]),
    Flag("quad-sitl", "--vehicle", "in-file", lambda p, c: ["--vehicle", p + ".toml", *FLY], always=1),
    Flag("quad-sitl", "--json", "out-file", lambda p, c: [*FLY, "--json", p]),
    Flag("quad-sitl", "--plot", "out-file", lambda p, c: [*FLY, "--plot", p + ".png"]),
    Flag("quad-sitl", "--video", "out-file", lambda p, c: [*FLY, "--video", p + ".gif"]),
    Flag("quad-sitl", "--tlog", "out-file", lambda p, c: [*FLY, "--tlog", p]),
    Flag("quad-sitl", "--trace", "out-file", lambda p, c: [*NODE, f"tcp:127.0.0.1:{c.port}", "--trace", p]),
    Flag("quad-sitl", "--sim-only --json", "out-file", lambda p, c: [*SIM, f"tcp:127.0.0.1:{c.port}", "--json", p]),
    Flag("quad-export", "CHECKPOINT", "in-file", lambda p, c: [p, "-o", str(c.d / "out.onnx")]),
    Flag("quad-export", "-o", "out-file", lambda p, c: [str(c.d / "hover.pt"), *PARITY, "-o", p]),
    Flag(
        "quad-export",
        "--format c -o",
        "out-dir",
        lambda p, c: [str(c.d / "hover.pt"), *PARITY, "--format", "c", "-o", p],
    ),
    Flag("quad-train", "--out", "out-dir", lambda p, c: [*TRAIN, "--out", p]),
    Flag("quad-train", "--out --resume", "in-dir", lambda p, c: [*TRAIN, "--out", p, "--resume"]),
    Flag(
        "quad-train",
        "--vehicle",
        "in-file",
        lambda p, c: [*TRAIN, "--out", str(c.d / "r"), "--vehicle", p + ".toml"],
        always=1,
    ),
    Flag("quad-compare", "run --out", "out-dir", lambda p, c: ["run", "--seeds", "0", "--out", p]),
    Flag("quad-compare", "report SWEEP", "in-dir", lambda p, c: _report(c, sweep=p)),
    Flag("quad-compare", "report --doc", "out-file", lambda p, c: _report(c, doc=p)),
    Flag("quad-compare", "report --figures", "out-dir", lambda p, c: _report(c, figures=p)),
]
NODE = ["--node-only", "--duration", "0.3", "--gcs", "none", "--connect"]
SIM = ["--sim-only", "--episodes", "1", "--lockstep-timeout", "1", "--listen"]
PARITY = ["--parity-samples", "2"]


# --- the errors ------------------------------------------------------------------------------------


class _Full:
    """A file whose writes fail with ENOSPC (everything else is the real file's)."""

    def __init__(self, f) -> None:
        self._f = f

    def write(self, *a, **kw):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), getattr(self._f, "name", None))

    writelines = write

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()

    def __iter__(self):
        return iter(self._f)


def inject(monkeypatch, under: Path, code: int, at: str) -> None:
    """Paths under `under` fail with `code`: at "open" (open, os.open, os.mkdir), or at "write"."""
    real_open, real_os_open, real_mkdir = builtins.open, os.open, os.mkdir
    prefix = str(under)

    def hit(p) -> bool:
        return isinstance(p, str | bytes | os.PathLike) and os.path.abspath(os.fsdecode(p)).startswith(prefix)

    def refuse(p):
        return OSError(code, os.strerror(code), os.fsdecode(p))

    def fake_open(file, mode="r", *a, **kw):
        if hit(file):
            if at == "open":
                raise refuse(file)
            if any(c in mode for c in "wxa+"):
                return _Full(real_open(file, mode, *a, **kw))
        return real_open(file, mode, *a, **kw)

    def fake_os_open(path, flags, mode=0o777, *, dir_fd=None):
        if at == "open" and hit(path):
            raise refuse(path)
        return real_os_open(path, flags, mode, dir_fd=dir_fd)

    def fake_mkdir(path, mode=0o777, *, dir_fd=None):
        if at == "open" and hit(path):
            raise refuse(path)
        return real_mkdir(path, mode, dir_fd=dir_fd)

    monkeypatch.setattr(builtins, "open", fake_open)
    monkeypatch.setattr(io, "open", fake_open)
    monkeypatch.setattr(os, "open", fake_os_open)
    monkeypatch.setattr(os, "mkdir", fake_mkdir)


SUFFIX = {"--vehicle": ".toml", "--plot": ".png", "--video": ".gif"}


def real_path(name: str, flag: Flag, c: Ctx) -> str | None:
    """The path that makes the OS raise `name` for this flag, or None where it does not apply."""
    if name == "ENAMETOOLONG":
        return str(c.d / ("n" * 300))
    if name == "ENOTDIR":
        return str(c.d / "afile" / "x")
    if name == "ELOOP":
        return str(c.d / "loop" / "x")
    # EISDIR: a directory where a file is expected (and a file where a directory is)
    if flag.kind.endswith("dir"):
        return str(c.d / "afile")
    return str(c.d / "adir")  # adir.toml, adir.png and adir.gif are directories too


def expected(name: str, flag: Flag) -> int | None:
    """The documented exit code, None where the error does not apply to the flag."""
    reading = flag.kind.startswith("in")
    if name in ("EROFS", "ENOSPC") and reading:
        return None  # nothing is written there
    if flag.always is not None:
        return flag.always
    if name == "EACCES" and flag.id == "quad-train --out --resume":
        return 2  # the run directory is written too, its lock first: a directory that cannot be written
    if name == "EACCES":
        return 1 if reading else 2  # a file that exists but cannot be read; an output the probe refuses
    if name == "ENOSPC":
        return 1  # the probe passed; the write at the end fails
    return 2


REAL = ("ENAMETOOLONG", "ENOTDIR", "ELOOP", "EISDIR")
MOCKED = ("EACCES", "EROFS", "ENOSPC")
CASES = [
    pytest.param(flag, name, id=f"{flag.id} {name}")
    for flag in FLAGS
    for name in (*REAL, *MOCKED)
    if expected(name, flag) is not None
]

READABLE = {  # flag → the readable input (under acc/) that the EACCES mock makes unreadable
    "quad-sitl POLICY": "policy.onnx",
    "quad-sitl --key": "key",
    "quad-sitl --vehicle": "v",
    "quad-export CHECKPOINT": "hover.pt",
    "quad-train --out --resume": "run",
    "quad-train --vehicle": "v",
    "quad-compare report SWEEP": "sweep",
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ctx(tmp_path: Path) -> Ctx:
    d = tmp_path
    (d / "afile").write_text("x")
    for name in ("adir", "adir.toml", "adir.png", "adir.gif", "sweep", "ro", "full"):
        (d / name).mkdir()
    (d / "loop").symlink_to(d / "loop")
    (d / "hover.pt").write_bytes(HOVER_PT.read_bytes())
    acc = d / "acc"
    (acc / "run").mkdir(parents=True)
    (acc / "run" / "checkpoint.pt").write_bytes(HOVER_PT.read_bytes())
    (acc / "sweep").mkdir()
    (acc / "sweep" / "sweep.json").write_text("{}")
    (acc / "policy.onnx").write_bytes(SHIPPED_HOVER.read_bytes())
    (acc / "key").write_bytes(bytes(range(32)))
    (acc / "v.toml").write_bytes((ROOT / "src" / "quadpilot" / "vehicles" / "seed.toml").read_bytes())
    (acc / "hover.pt").write_bytes(HOVER_PT.read_bytes())
    return Ctx(d)


def _sweep(d: Path) -> None:
    """A finished sweep, as tests/studies/test_compare.py writes one (its `fake_run`)."""
    import importlib.util
    import json

    spec = importlib.util.spec_from_file_location("compare_tests", ROOT / "tests" / "studies" / "test_compare.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    for seed in (0, 1):
        mod.fake_run(d / "sweep" / f"ppo-seed{seed}", "ppo", seed, 4)
        mod.fake_run(d / "sweep" / f"sb3-seed{seed}", "sb3", seed, 6)
    sweep = {"task": "hover", "preset": "fast", "seeds": [0, 1], "eval_every": 2, "threads": 1, "workers": 2}
    sweep |= {"engine": "process", "nice": 10, "command": "quad-compare run", "machine": {"cpu": "x", "cores": 2}}
    (d / "sweep" / "sweep.json").write_text(json.dumps({**sweep, "started": "2026-01-01T00:00:00+00:00"}))


def _connect_once(port: int, done: threading.Event) -> None:
    """A peer for --sim-only: connects, says nothing, hangs up (the episode ends, the stats are written)."""
    while not done.is_set():
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1):
                time.sleep(0.2)
            return
        except OSError:
            time.sleep(0.05)


@pytest.mark.parametrize(("flag", "name"), CASES)
def test_every_path_flag_refuses_every_os_error_in_one_line(flag, name, tmp_path, monkeypatch, capsys):
    from quadpilot.sitl.simulator_process import start_simulator

    c = _ctx(tmp_path)
    want = expected(name, flag)
    extra: list = []
    if name in REAL:
        path = real_path(name, flag, c)
    elif name == "EACCES" and flag.kind.startswith("in"):
        path = str(c.d / "acc" / READABLE[flag.id])
        inject(monkeypatch, c.d / "acc", errno.EACCES, "open")
    elif name in ("EACCES", "EROFS"):
        path = str(c.d / "ro" / "out")
        inject(monkeypatch, c.d / "ro", getattr(errno, name), "open")
    else:  # ENOSPC: the work is done, the write at the end fails
        path = str(c.d / "full" / "out")
        if flag.id == "quad-sitl --trace":
            sim = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", "tcp:127.0.0.1:0"]
            proc, address = start_simulator([*sim, "--episodes", "1"])
            assert proc is not None, address
            extra.append(proc)
            c.port = int(address.rsplit(":", 1)[1])
        elif flag.id == "quad-sitl --sim-only --json":
            c.port, done = _free_port(), threading.Event()
            peer = threading.Thread(target=_connect_once, args=(c.port, done), daemon=True)
            peer.start()
            extra.append(done)
        elif flag.id == "quad-compare run --out":
            from quadpilot.studies import compare

            monkeypatch.setattr(compare, "run_one", lambda spec, *a, **kw: {"algo": spec.algo, "seed": spec.seed})
        elif flag.prog == "quad-compare":
            _sweep(c.d)
        inject(monkeypatch, c.d / "full", errno.ENOSPC, "write")
    argv = flag.argv(path, c)
    try:
        code = _entry(flag.prog)(argv)
    except BaseException as e:  # what would have been a traceback
        pytest.fail(f"{flag.prog} {argv}: {type(e).__name__}: {e}")
    finally:
        monkeypatch.undo()
        for x in extra:
            if isinstance(x, threading.Event):
                x.set()
            else:
                x.kill()
                x.wait(5)
    err = capsys.readouterr().err
    lines = err.strip("\n").splitlines()
    assert "Traceback" not in err, err
    assert code == want and len(lines) == 1, f"exit {code} (expected {want}), stderr {err[-600:]!r}"
    if name == "EISDIR":  # the path, and what it is: a directory where a file is expected, or the other way
        said = "not a directory" if flag.kind.endswith("dir") else "is a directory"
        assert path in lines[0] and said in lines[0], lines[0]
        return
    # the line says what was wrong: the OS's reason, or the path (its start: names 300 bytes long)
    reason = os.strerror(getattr(errno, name))
    assert reason in lines[0] or path[:60] in lines[0], lines[0]


# --- the C backend's cache: a planted digest file ----------------------------------------------------

needs_cc = pytest.mark.skipif(find_compiler() is None, reason="the c backend needs a C compiler (apt-get install gcc)")


@pytest.fixture
def cached_hover(monkeypatch, tmp_path):
    """The hover kernel built into a private cache of this test's: (its cache directory, its code)."""
    from quadpilot.ccode.generate import generate, initializers
    from quadpilot.modelfile.model import read_model
    from quadpilot.runtime.cbackend import build_library

    monkeypatch.setenv("QUADPILOT_CACHE_DIR", str(tmp_path / "cache"))
    model, info = read_model(SHIPPED_HOVER)
    code = generate(info, initializers(model))
    return build_library(code).parent, code


@needs_cc
@settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],  # one cache; each example rewrites its digest
)
@given(planted=st.binary(max_size=300) | st.text(max_size=80).map(lambda t: t.encode("utf-8", "surrogatepass")))
def test_a_planted_digest_of_any_bytes_is_refused_without_an_exception(cached_hover, planted):
    """Whatever bytes lie where the library's SHA-256 is recorded (non-ASCII, NUL, the right digest
    with a byte more), the cached library is used only if they are its digest (hmac.compare_digest
    of str raised TypeError on non-ASCII: a traceback instead of a rebuild)."""
    import hashlib

    from quadpilot.runtime.cbackend import LIBRARY_NAME, _cached

    target, code = cached_hover
    true = hashlib.sha256((target / LIBRARY_NAME).read_bytes()).hexdigest().encode()
    (target / DIGEST_NAME).write_bytes(planted)
    assert _cached(target, code) == (planted.strip() == true)
    (target / DIGEST_NAME).write_bytes(planted + "é".encode() + true)
    assert _cached(target, code) is False


@needs_cc
def test_quad_sitl_rebuilds_over_a_non_ascii_digest_and_flies(cached_hover, capsys):
    from quadpilot.sitl import main

    target, _ = cached_hover
    (target / DIGEST_NAME).write_text("é" * 64, encoding="utf-8")
    code = main([str(SHIPPED_HOVER), "--backend", "c", *FLY])
    err = capsys.readouterr().err
    assert code == 0 and err == "", err
    assert len((target / DIGEST_NAME).read_text(encoding="ascii").strip()) == 64  # rebuilt, digest recorded

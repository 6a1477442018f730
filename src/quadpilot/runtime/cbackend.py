"""The `c` backend: the file's network as generated C (`ccode.generate`), compiled once, called
through ctypes.

    policy = load_policy("models/hover/policy.onnx", backend="c")

`load_policy` checks the file's contract as for the other backends; this module then generates
policy.c/policy.h from the file's network and metadata (`ccode.generate`, the same generator
`quad-export --format c` writes), compiles them with the system C compiler into a shared library
and loads it with ctypes; `load_policy` replays the golden vectors through it before returning.

Compiler: `$CC` if set (it may carry arguments, e.g. "ccache gcc"), else the first of cc, gcc,
clang on PATH. None found, or a compile that fails, raises `CCompilerError`: a RuntimeError (the
machine lacks something) that is also a ValueError, so that callers which report a bad `backend`
argument (also a ValueError) report this the same way; quad-sitl prints it in one line.

Cache: the library is built once per distinct generated source, compiler and flags, under
`$QUADPILOT_CACHE_DIR` or `$XDG_CACHE_HOME/quadpilot` (default `~/.cache/quadpilot`), in
`c/<key>/`, the key a SHA-256 of the generator, the generated header and source, the compiler's
identity, the flags and the machine; the source is kept beside the library for inspection. The build
goes to a temporary name first and is renamed into place, so concurrent processes never load a
half-written library.

A shared library runs code as it is loaded (constructors), before any golden vector is checked, so
the cache is a trust boundary (docs/architecture.md, "Trust boundaries"). Rules:
- The cache root, `c/` and the key directory are directories (not symlinks) owned by this user and
  writable by no one else; they are created 0700. If one of them is group- or world-writable or
  belongs to someone else, the cache is not used: the library is built in a fresh private temporary
  directory (`tempfile.mkdtemp`, 0700).
- A cached library is loaded only if the SHA-256 of its bytes equals the one recorded beside it
  (`libquadpilot_policy.so.sha256`, written by the build that made it, last) and the source beside
  it is the one just generated; otherwise it is rebuilt. So a library planted under the key, or one
  left half-written, is never loaded.
If the cache cannot be written, a private temporary directory is used. POSIX only (a `.so` loaded
with dlopen; macOS works the same way; Windows is not supported).
"""

from __future__ import annotations

import ctypes
import hashlib
import hmac
import os
import platform
import shlex
import shutil
import stat
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from quadpilot.ccode import generate as cgen
from quadpilot.modelfile.contract import NUM_MOTORS, ModelInfo
from quadpilot.modelfile.network import Network, network_from_model

from .policy import Policy

COMPILE_FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared")
"""The runtime's build: C99 at -O2 (what the kernel was written for; no -ffast-math, no
-march=native, so the cached library runs on any machine of the same architecture)."""
COMPILE_TIMEOUT_S = 120.0
LIBRARY_NAME = "libquadpilot_policy.so"
DIGEST_NAME = LIBRARY_NAME + ".sha256"
"""Beside the library: the SHA-256 (hex) of its bytes, recorded by the build that made it."""


class CCompilerError(RuntimeError, ValueError):
    """The `c` backend cannot run here: no C compiler, or the compiler failed (message says which)."""


def find_compiler() -> list[str] | None:
    """The compiler command: `$CC` split like a shell would, else cc, gcc or clang from PATH."""
    env = os.environ.get("CC", "").strip()
    if env:
        cmd = shlex.split(env)
        return cmd if shutil.which(cmd[0]) else None
    for name in ("cc", "gcc", "clang"):
        found = shutil.which(name)
        if found:
            return [found]
    return None


def cache_root() -> Path:
    """Where compiled kernels are kept (see the module doc)."""
    env = os.environ.get("QUADPILOT_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "quadpilot"


def _compiler_identity(cmd: list[str]) -> str:
    """Path, size and mtime of the compiler binary: a compiler upgrade changes the cache key."""
    exe = Path(shutil.which(cmd[0]) or cmd[0]).resolve()
    try:
        st = exe.stat()
        return f"{exe}:{st.st_size}:{st.st_mtime_ns}:{' '.join(cmd[1:])}"
    except OSError:
        return " ".join(cmd)


def _private(path: Path, directory: bool = True) -> bool:
    """`path` is a directory (or a regular file), not a symlink, owned by this user and writable by
    no one else."""
    try:
        st = os.lstat(path)
    except OSError:
        return False
    kind_ok = stat.S_ISDIR(st.st_mode) if directory else stat.S_ISREG(st.st_mode)
    return kind_ok and st.st_uid == os.geteuid() and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def cache_dir(key: str) -> Path | None:
    """The private cache directory for `key` (created 0700), or None if the cache cannot be used:
    not writable, or some directory of it not private (see the module doc)."""
    root = cache_root()
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    for target in (root, root / "c", root / "c" / key):
        try:
            target.mkdir(mode=0o700)
        except FileExistsError:
            pass
        except OSError:
            return None
        if not _private(target):
            return None
    return target


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _cached(target: Path, code: cgen.CCode) -> bool:
    """A library under `target` that this code may load: its bytes have the SHA-256 recorded beside
    it and the source beside it is `code`'s (see the module doc)."""
    lib, digest, source = target / LIBRARY_NAME, target / DIGEST_NAME, target / cgen.SOURCE_NAME
    if not (_private(lib, directory=False) and _private(digest, directory=False)):
        return False
    try:
        if source.read_text(encoding="ascii", errors="replace") != code.source:
            return False
        with open(digest, "rb") as f:  # bytes: whatever was planted there (non-ASCII too) compares
            recorded = f.read(256).strip()
        return hmac.compare_digest(recorded, _sha256_file(lib).encode("ascii"))
    except OSError:
        return False


def build_library(code: cgen.CCode, compiler: list[str] | None = None, flags=COMPILE_FLAGS) -> Path:
    """Compile `code` into a shared library (cached, see the module doc); returns its path.

    Raises CCompilerError if there is no compiler or it fails."""
    cmd = compiler or find_compiler()
    if cmd is None:
        raise CCompilerError(
            "the c backend needs a C compiler (set CC, or install cc/gcc/clang, e.g. `apt-get install gcc`); "
            "none was found on PATH. The numpy and onnxruntime backends need none."
        )
    key = hashlib.sha256(
        "\0".join(
            (cgen.GENERATOR, code.header, code.source, _compiler_identity(cmd), " ".join(flags), platform.machine())
        ).encode()
    ).hexdigest()[:32]
    target = cache_dir(key)
    if target is None:
        target = Path(tempfile.mkdtemp(prefix="quadpilot-c-"))  # 0700, ours alone
    lib = target / LIBRARY_NAME
    if _cached(target, code):
        return lib
    with tempfile.TemporaryDirectory(prefix=".build-", dir=target) as tmp:
        tmp = Path(tmp)
        (tmp / cgen.HEADER_NAME).write_text(code.header, encoding="ascii")
        (tmp / cgen.SOURCE_NAME).write_text(code.source, encoding="ascii")
        argv = [*cmd, *flags, "-o", LIBRARY_NAME, cgen.SOURCE_NAME, "-lm"]
        try:
            done = subprocess.run(argv, cwd=tmp, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise CCompilerError(f"the c backend could not run the C compiler {' '.join(argv)}: {e}") from None
        if done.returncode != 0 or not (tmp / LIBRARY_NAME).is_file():
            out = (done.stderr or done.stdout).strip().splitlines()
            raise CCompilerError(
                f"the C compiler failed on the generated policy.c ({' '.join(argv)}, exit {done.returncode}): "
                + " | ".join(out[:8])
            )
        (tmp / DIGEST_NAME).write_text(_sha256_file(tmp / LIBRARY_NAME) + "\n", encoding="ascii")
        for name in (cgen.HEADER_NAME, cgen.SOURCE_NAME, LIBRARY_NAME, DIGEST_NAME):
            os.chmod(tmp / name, 0o600)  # whatever the umask: only this user reads or writes them
        # the digest last: a library is trusted only once the digest of its bytes is beside it
        for name in (cgen.HEADER_NAME, cgen.SOURCE_NAME, LIBRARY_NAME, DIGEST_NAME):
            os.replace(tmp / name, target / name)
    return lib


class CPolicy(Policy):
    """The generated C kernel, batch-1, through ctypes with preallocated float32 buffers.

    `code` is the generated source (what was compiled), `library` the shared library's path."""

    backend = "c"

    def __init__(self, info: ModelInfo, code: cgen.CCode, library: str | os.PathLike) -> None:
        super().__init__(info)
        self.code = code
        self.library = Path(library)
        try:
            self._lib = ctypes.CDLL(str(self.library))
            fn = getattr(self._lib, cgen.STEP if info.recurrent else cgen.ENTRY)
        except (OSError, AttributeError) as e:
            raise CCompilerError(f"the compiled policy {self.library} cannot be loaded: {e}") from None
        self._obs = np.zeros(self.obs_dim, np.float32)
        self._out = np.zeros(NUM_MOTORS, np.float32)
        ptr = ctypes.c_void_p
        if info.recurrent:
            self._h = np.zeros(info.hidden, np.float32)
            self._c = np.zeros(info.hidden, np.float32)
            buffers = (self._obs, self._h, self._c, self._out)
        else:
            buffers = (self._obs, self._out)
        fn.argtypes = [ptr] * len(buffers)
        fn.restype = None
        self.kernel = fn
        """The ctypes function itself, (pointers to float32 buffers) → None."""
        self.kernel_args = tuple(ptr(b.ctypes.data) for b in buffers)
        """Pointers to this policy's own buffers: `kernel(*kernel_args)` runs one step on them."""
        args = self.kernel_args
        self._call = (lambda: fn(args[0], args[1])) if len(args) == 2 else (lambda: fn(*args))

    @classmethod
    def from_model(cls, info: ModelInfo, weights: dict[str, np.ndarray]) -> CPolicy:
        """Generate, compile (or find in the cache) and load the kernel for a checked file."""
        return cls.from_network(info, network_from_model(info, weights))

    @classmethod
    def from_network(cls, info: ModelInfo, net: Network) -> CPolicy:
        """`from_model` for the file's network read already (`network.network_from_model`)."""
        code = cgen.generate_network(info, net)
        return cls(info, code, build_library(code))

    def act_unchecked(self, x: np.ndarray) -> np.ndarray:
        self._obs[...] = x
        self._call()
        return self._out.copy()

    def reset(self) -> None:
        if self.info.recurrent:
            self._h.fill(0.0)
            self._c.fill(0.0)

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(h, c) copies for a recurrent policy, else None."""
        if not self.info.recurrent:
            return None
        return self._h.copy(), self._c.copy()

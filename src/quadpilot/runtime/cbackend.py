"""The `c` backend: the file's network as generated C (`cgen`), compiled once, called through ctypes.

    policy = load_policy("models/hover/policy.onnx", backend="c")

`load_policy` checks the file's contract as for the other backends; this module then generates
policy.c/policy.h from the file's initializers and metadata (`cgen.generate`, the same generator
`quad-export --format c` writes), compiles them with the system C compiler into a shared library
and loads it with ctypes; `load_policy` replays the golden vectors through it before returning.

Compiler: `$CC` if set (it may carry arguments, e.g. "ccache gcc"), else the first of cc, gcc,
clang on PATH. None found, or a compile that fails, raises `CCompilerError`: a RuntimeError (the
machine lacks something) that is also a ValueError, so that callers which report a bad `backend`
argument (also a ValueError) report this the same way; quad-sitl prints it in one line.

Cache: the library is built once per distinct generated source, compiler and flags, under
`$QUADPILOT_CACHE_DIR` or `$XDG_CACHE_HOME/quadpilot` (default `~/.cache/quadpilot`), in
`c/<key>/` with the source beside it for inspection; the build goes to a temporary name first and
is renamed into place, so concurrent processes never load a half-written library. A cached library
is reused only if the source stored beside it is the one just generated (and the golden vectors
then check what it computes). If the cache cannot be written, a private temporary directory is
used. POSIX only (a `.so` loaded with dlopen; macOS works the same way; Windows is not supported).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from . import cgen
from .backends import Policy
from .model import NUM_MOTORS, ModelInfo

COMPILE_FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared")
"""The runtime's build: C99 at -O2 (what the kernel was written for; no -ffast-math, no
-march=native, so the cached library runs on any machine of the same architecture)."""
COMPILE_TIMEOUT_S = 120.0
LIBRARY_NAME = "libquadpilot_policy.so"


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
    try:
        root = cache_root() / "c"
        root.mkdir(parents=True, exist_ok=True, mode=0o700)
        target = root / key
        target.mkdir(exist_ok=True, mode=0o700)
    except OSError:
        target = Path(tempfile.mkdtemp(prefix="quadpilot-c-"))
    lib = target / LIBRARY_NAME
    source = target / cgen.SOURCE_NAME
    if lib.is_file() and source.is_file() and source.read_text(encoding="ascii", errors="replace") == code.source:
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
        for name in (cgen.HEADER_NAME, cgen.SOURCE_NAME, LIBRARY_NAME):
            os.replace(tmp / name, target / name)  # the library last: a present .so has its source
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
        code = cgen.generate(info, weights)
        return cls(info, code, build_library(code))

    def _act(self, x: np.ndarray) -> np.ndarray:
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

"""The `policy.tar` PX4's mc_raptor module loads: an RLtools checkpoint, written and read in NumPy.

PX4's `mc_raptor` (src/modules/mc_raptor) loads `raptor/policy.tar` from PX4's storage directory
(`/fs/microsd/raptor/policy.tar` on hardware) with RLtools' tar reader into a policy whose type is
fixed when the firmware is compiled, by `blob/policy.h`: the RAPTOR foundation policy's shape, a
dense layer (22 -> 16, ReLU), a GRU (16 hidden) and a dense layer (16 -> 4, identity), 2,084
parameters. A file of any other shape cannot load. At start it replays the checkpoint's stored
example (2 sequences x 5 steps, `Raptor::test_policy`) and refuses the file when the mean absolute
difference is not below 1e-5 or an input/output is NaN. docs/px4.md says what was proven here.

The weights are a plain dict of float32 arrays named after RLtools' groups under `actor/`
(the tar path without `actor/` and `/parameters`), in the layout of blob/policy.h:

    ========================  =========  ===========================================
    name                      shape      RLtools
    ========================  =========  ===========================================
    layers/0/weights          (16, 22)   dense, row = output unit
    layers/0/biases           (16,)      dense
    layers/1/weights_input    (48, 16)   GRU, rows r | z | n (16 each)
    layers/1/biases_input     (48,)      GRU
    layers/1/weights_hidden   (48, 16)   GRU, rows r | z | n
    layers/1/biases_hidden    (48,)      GRU
    layers/1/initial_hidden_state (16,)  GRU, the state after a reset
    layers/2/weights          (4, 16)    dense
    layers/2/biases           (4,)       dense
    ========================  =========  ===========================================

The example is `example_in` (500, 2, 22) and `example_out` (500, 2, 4) float32, sequence-major
as blob/policy.h declares it (mc_raptor seeks into it with those strides).

The archive holds exactly the members RLtools' tar writer makes for this model
(persist/backends/tar and the layers' persist.h), in its order, with its header values (mode 0644,
uid/gid 1000, user/group, mtime 0): the same input gives the same bytes, the bytes RLtools' own
writer writes (tests/px4 compares them; PX4's shipped blob/policy.tar is one, docs/px4.md).

`read_policy_tar` treats the file as untrusted: it never extracts to disk, refuses a file over
`MAX_FILE_BYTES`, anything but the exact member names (no duplicates, no links, no long-name or
pax headers RLtools would read differently), any metadata but the exact text for the expected
shape and dtype, any non-finite value, and it replays the WHOLE stored example with runtime/gru.py's step
(mc_raptor's check replays 2 x 5 steps). A changed low-order byte of a weight moves the outputs by
less than 1e-8 (docs/px4.md) and passes any replay; the SHA-256 beside the file
(`policy.tar.sha256`) catches it.
Each refusal is a `PolicyTarError` (a ValueError) in one line.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
import tarfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quadpilot import atomic_files
from quadpilot.core.px4_raptor import ACTION_DIM, OBS_DIM

from .gru import GRU_KEYS, GruStep, sequences

EXAMPLE_STEPS = 500
EXAMPLE_BATCH = 2
# mc_raptor's own check (mc_raptor.hpp, TEST_BATCH_SIZE_ACTUAL and TEST_SEQUENCE_LENGTH_ACTUAL) and bar
PX4_TEST_BATCH = 2
PX4_TEST_STEPS = 5
PX4_TEST_EPSILON = 1e-5
# our replay: every stored output, the largest absolute difference
REPLAY_TOLERANCE = 1e-5
MAX_FILE_BYTES = 1 << 20  # the file is about 130 kB
# mc_raptor reads actor/meta into a 256-byte buffer and copies at most 99 characters of the name
ACTOR_META_MAX_BYTES = 256
CHECKPOINT_NAME = re.compile(r"[A-Za-z0-9_.+/-][A-Za-z0-9_.+/ -]{0,98}")

WEIGHT_SHAPES: dict[str, tuple[int, ...]] = GRU_KEYS
N_PARAMETERS = sum(math.prod(s) for s in WEIGHT_SHAPES.values())
EXAMPLE_SHAPES = {
    "input": (EXAMPLE_STEPS, EXAMPLE_BATCH, OBS_DIM),
    "output": (EXAMPLE_STEPS, EXAMPLE_BATCH, ACTION_DIM),
}
# the layers' own metadata, as RLtools' dense and GRU persist.h write it
LAYER_META = {
    "actor/layers/0/meta": b"activation_function: RELU\ntype: dense\n",
    "actor/layers/1/meta": b"type: gru\n",
    "actor/layers/2/meta": b"activation_function: IDENTITY\ntype: dense\n",
}
ACTOR_META = "actor/meta"


class PolicyTarError(ValueError):
    """A policy.tar that cannot be written or flown; the message is one line."""


def _tensor_meta(shape: tuple[int, ...]) -> bytes:
    """RLtools' tar metadata of a float32 tensor (persist/backends/tar/operations_generic.h, save)."""
    dims = "".join(f"dim_{i}: {d}\n" for i, d in enumerate(shape))
    return f"type: tensor\ndtype: float32\nnum_dims: {len(shape)}\n{dims}".encode()


def _layout() -> list[tuple[str, str, tuple[int, ...] | None]]:
    """(member name, what it holds, shape of a data member) in RLtools' writing order."""
    out: list[tuple[str, str, tuple[int, ...] | None]] = [(ACTOR_META, "actor", None)]
    for layer in ("0", "1", "2"):
        for name, shape in WEIGHT_SHAPES.items():
            if name.split("/")[1] == layer:
                base = f"actor/{name}/parameters"
                out += [(f"{base}/meta", name, shape), (f"{base}/data", name, shape)]
        out.append((f"actor/layers/{layer}/meta", "layer", None))
    for which, shape in EXAMPLE_SHAPES.items():
        out += [(f"example/{which}/meta", which, shape), (f"example/{which}/data", which, shape)]
    return out


LAYOUT = _layout()
MEMBER_NAMES = [m for m, _, _ in LAYOUT]


# --- checks shared by the writer and the reader ---------------------------------------------------


def _check_array(what: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != shape:
        raise PolicyTarError(f"{what}: shape {arr.shape}, expected {shape} (blob/policy.h)")
    if arr.dtype.kind not in "fiu":
        raise PolicyTarError(f"{what}: dtype {arr.dtype}, expected float32")
    out = arr.astype("<f4")
    if not np.all(np.isfinite(out)):
        raise PolicyTarError(f"{what}: a value is not finite as float32 (NaN or inf), expected finite numbers")
    return out


def check_weights(weights: dict[str, object]) -> dict[str, np.ndarray]:
    """The weights as float32 arrays, exactly the names and shapes of `WEIGHT_SHAPES`, all finite."""
    if not isinstance(weights, dict):
        raise PolicyTarError(f"weights: a {type(weights).__name__}, expected a dict of named arrays")
    unknown = sorted(set(weights) - set(WEIGHT_SHAPES), key=str)
    missing = [n for n in WEIGHT_SHAPES if n not in weights]
    if unknown or missing:
        raise PolicyTarError(f"weights: unknown {unknown}, missing {missing}; expected exactly {list(WEIGHT_SHAPES)}")
    return {n: _check_array(f"weight {n}", weights[n], s) for n, s in WEIGHT_SHAPES.items()}


def replay_difference(weights: dict[str, np.ndarray], example_in: np.ndarray, example_out: np.ndarray) -> float:
    """Largest absolute difference between the stored example output and the runtime's GRU step
    (runtime/gru.py, the one forward), every step (NaN when the forward overflows: weights from a
    hostile file may be huge)."""
    with np.errstate(over="ignore", invalid="ignore"):
        ours = sequences(GruStep(weights), example_in).astype(np.float64)
        return float(np.max(np.abs(ours - example_out)))


# --- writing ---------------------------------------------------------------------------------------


def policy_tar_bytes(
    weights: dict[str, object],
    example_in: object,
    example_out: object,
    checkpoint_name: str = "quadpilot",
) -> bytes:
    """The bytes of policy.tar; the same input gives the same bytes. The example must replay."""
    w = check_weights(weights)
    ex_in = _check_array("example input", example_in, EXAMPLE_SHAPES["input"])
    ex_out = _check_array("example output", example_out, EXAMPLE_SHAPES["output"])
    if not isinstance(checkpoint_name, str) or not CHECKPOINT_NAME.fullmatch(checkpoint_name):
        raise PolicyTarError(
            f"checkpoint name {checkpoint_name!r}: expected 1-99 characters of letters, digits, '_.+/- '"
        )
    diff = replay_difference(w, ex_in, ex_out)
    if not diff <= REPLAY_TOLERANCE:
        raise PolicyTarError(
            f"the example output is not these weights' output (largest difference {diff:.3g}, "
            f"expected <= {REPLAY_TOLERANCE:g}): mc_raptor would refuse the file"
        )
    contents: dict[str, bytes] = {ACTOR_META: f"checkpoint_name: {checkpoint_name}\ntype: sequential\n".encode()}
    contents.update(LAYER_META)
    arrays = {**w, "input": ex_in, "output": ex_out}
    for member, what, shape in LAYOUT:
        if shape is not None:
            arr = arrays[what]
            contents[member] = _tensor_meta(shape) if member.endswith("/meta") else arr.tobytes()
    buf = io.BytesIO()
    headers = []
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for member in MEMBER_NAMES:
            info = tarfile.TarInfo(member)
            info.size, info.mode, info.mtime = len(contents[member]), 0o644, 0
            info.uid = info.gid = 1000
            info.uname, info.gname = "user", "group"
            headers.append(tar.offset)
            tar.addfile(info, io.BytesIO(contents[member]))
        end = tar.offset
    # RLtools' writer (persist/backends/tar write_entry and finalize) writes the checksum as seven
    # octal digits and a NUL where tarfile writes six, a NUL and a space (the same number), and ends
    # the archive with two zero blocks where tarfile pads on to a 10240-byte record. With these two
    # changes the bytes are RLtools' own (tests/px4).
    data = bytearray(buf.getvalue()[: end + 2 * tarfile.BLOCKSIZE])
    for at in headers:
        data[at + 148 : at + 156] = b"%07o\0" % int(data[at + 148 : at + 154], 8)
    return bytes(data)


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_path(path: str | Path) -> Path:
    """Where the SHA-256 of `path` is written: beside it, `policy.tar.sha256`."""
    p = Path(path)
    return p.with_name(p.name + ".sha256")


def write_policy_tar(
    path: str | Path,
    weights: dict[str, object],
    example_in: object,
    example_out: object,
    checkpoint_name: str = "quadpilot",
) -> str:
    """Write policy.tar atomically and its SHA-256 beside it (`sha256sum -c` reads it); returns the hex."""
    return write_policy_tar_bytes(path, policy_tar_bytes(weights, example_in, example_out, checkpoint_name))


def write_policy_tar_bytes(path: str | Path, data: bytes) -> str:
    """Write the bytes `policy_tar_bytes` made (checked there) as `write_policy_tar` does; returns the hex."""
    digest = sha256_hex(data)
    atomic_files.atomic_write(path, lambda f: f.write(data))
    line = f"{digest}  {Path(path).name}\n".encode()
    atomic_files.atomic_write(sha256_path(path), lambda f: f.write(line))
    return digest


# --- reading (untrusted) ---------------------------------------------------------------------------


def is_policy_tar(path: str | Path) -> bool:
    """Whether the file starts as an RLtools checkpoint does (a ustar header of `actor/meta`): what a
    program that reads other files can tell its user in one line. Reads one block; checks nothing
    else (`read_policy_tar` does)."""
    try:
        with open(path, "rb") as f:
            head = f.read(tarfile.BLOCKSIZE)
    except OSError:
        return False
    return (
        len(head) == tarfile.BLOCKSIZE and head[257:262] == b"ustar" and head[:100].rstrip(b"\0") == ACTOR_META.encode()
    )


@dataclass(frozen=True)
class PolicyTar:
    """A policy.tar that passed every check."""

    weights: dict[str, np.ndarray]
    example_in: np.ndarray
    example_out: np.ndarray
    checkpoint_name: str
    sha256: str
    replay_max_difference: float  # over all 500 x 2 x 4 stored outputs


def _read_actor_meta(raw: bytes) -> str:
    if len(raw) > ACTOR_META_MAX_BYTES:
        raise PolicyTarError(
            f"{ACTOR_META}: {len(raw)} bytes, expected at most {ACTOR_META_MAX_BYTES} (mc_raptor's buffer)"
        )
    text = raw.decode("ascii", errors="replace")
    m = re.fullmatch(r"checkpoint_name: (.*)\ntype: sequential\n", text)
    if m is None or not CHECKPOINT_NAME.fullmatch(m.group(1)):
        raise PolicyTarError(
            f"{ACTOR_META}: {text[:60]!r}, expected 'checkpoint_name: <1-99 of letters, digits, _.+/- >' "
            "then 'type: sequential'"
        )
    return m.group(1)


def parse_policy_tar(data: bytes) -> PolicyTar:
    """Check the bytes of a policy.tar (see the module docstring) and return what it holds."""
    if len(data) > MAX_FILE_BYTES:
        raise PolicyTarError(f"{len(data)} bytes, expected at most {MAX_FILE_BYTES} for this policy type")
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as tar:
            members = tar.getmembers()
            seen: dict[str, bytes] = {}
            for m in members:
                if m.name not in MEMBER_NAMES:
                    raise PolicyTarError(
                        f"unexpected member {m.name[:80]!r}, expected only the {len(MEMBER_NAMES)} "
                        "of mc_raptor's policy type"
                    )
                if m.name in seen:
                    raise PolicyTarError(f"member {m.name!r} twice, expected once (RLtools reads the first)")
                header = data[m.offset : m.offset + tarfile.BLOCKSIZE]
                if not m.isreg() or m.pax_headers or m.offset_data != m.offset + tarfile.BLOCKSIZE:
                    raise PolicyTarError(f"member {m.name!r} is not a plain ustar file, expected a header and data")
                if header[257:262] != b"ustar" or header[:100].rstrip(b"\0") != m.name.encode():
                    raise PolicyTarError(f"member {m.name!r}: not a ustar header with the name in place (RLtools')")
                if m.size > MAX_FILE_BYTES:
                    raise PolicyTarError(f"member {m.name!r}: {m.size} bytes, expected fewer")
                f = tar.extractfile(m)
                seen[m.name] = f.read() if f is not None else b""
                if len(seen[m.name]) != m.size:
                    raise PolicyTarError(f"member {m.name!r} is cut short: the file is truncated")
    except tarfile.TarError as e:
        raise PolicyTarError(f"not a readable tar archive ({e}); expected RLtools' policy.tar") from None
    missing = [n for n in MEMBER_NAMES if n not in seen]
    if missing:
        raise PolicyTarError(
            f"missing member {missing[0]!r} ({len(missing)} missing): truncated, or not mc_raptor's policy type"
        )
    name = _read_actor_meta(seen[ACTOR_META])
    arrays: dict[str, np.ndarray] = {}
    for member, what, shape in LAYOUT:
        raw = seen[member]
        if shape is None:
            if member != ACTOR_META and raw != LAYER_META[member]:
                raise PolicyTarError(f"{member}: {raw[:60]!r}, expected {LAYER_META[member]!r} (blob/policy.h's layer)")
        elif member.endswith("/meta"):
            if raw != _tensor_meta(shape):
                raise PolicyTarError(f"{member}: {raw[:80]!r}, expected float32 of shape {shape} (blob/policy.h)")
        else:
            if len(raw) != 4 * math.prod(shape):
                raise PolicyTarError(f"{member}: {len(raw)} bytes, expected {4 * math.prod(shape)} (float32 {shape})")
            arr = np.frombuffer(raw, dtype="<f4").reshape(shape).copy()
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0]
                at = tuple(int(i) for i in bad)
                raise PolicyTarError(f"{member}: value at {at} is not finite, expected finite numbers")
            arrays[what] = arr
    weights = {n: arrays[n] for n in WEIGHT_SHAPES}
    diff = replay_difference(weights, arrays["input"], arrays["output"])
    if not diff <= REPLAY_TOLERANCE:
        raise PolicyTarError(
            f"the stored example does not replay: largest difference {diff:.3g} over all "
            f"{EXAMPLE_STEPS} x {EXAMPLE_BATCH} steps, expected <= {REPLAY_TOLERANCE:g} (damaged weights or example)"
        )
    return PolicyTar(weights, arrays["input"], arrays["output"], name, sha256_hex(data), diff)


def read_policy_tar(path: str | Path, expected_sha256: str | None = None) -> PolicyTar:
    """Read and check policy.tar. The SHA-256 is checked against `expected_sha256` when given, else
    against `policy.tar.sha256` beside the file when there is one."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as e:
        raise PolicyTarError(f"{p}: cannot read ({e.strerror})") from None
    if expected_sha256 is None and (
        sha256_path(p).exists() or sha256_path(p).is_symlink()
    ):  # a directory there: refused
        expected_sha256 = _read_sha256_file(sha256_path(p))
    if expected_sha256 is not None and sha256_hex(data) != expected_sha256:
        found = sha256_hex(data)
        raise PolicyTarError(f"{p}: SHA-256 {found[:16]}..., expected {expected_sha256[:16]}... (file changed)")
    try:
        return parse_policy_tar(data)
    except PolicyTarError as e:
        raise PolicyTarError(f"{p}: {e}") from None


def _read_sha256_file(path: Path) -> str:
    try:
        text = path.read_bytes()[:200].decode("ascii", errors="replace")
    except OSError as e:
        raise PolicyTarError(f"{path}: cannot read ({e.strerror})") from None
    m = re.match(r"([0-9a-f]{64})\s", text)
    if m is None:
        raise PolicyTarError(f"{path}: expected '<64 lowercase hex digits>  policy.tar'")
    return m.group(1)

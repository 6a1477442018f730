"""Test material for policy.tar: the RAPTOR foundation policy's weights (PyPI `foundation-policy`),
damaged copies of a file, an observation sequence, and mc_raptor's executor timing in Python."""

from __future__ import annotations

import io
import tarfile

import numpy as np

from quadpilot.runtime import rltools_tar as rt
from quadpilot.runtime.gru import GruStep, sequences

FOUNDATION_NAME = "logs/2025-04-19_16-16-17"  # the checkpoint name in the package and in PX4's blob
GYRO_PER_NATIVE = 4  # IMU_GYRO_RATEMAX 400 Hz / 100 Hz training (mc_raptor's force_sync_native)


def foundation():
    """(weights, example_in, example_out) read from the foundation-policy package's own checkpoint."""
    import h5py
    import importlib_resources

    path = importlib_resources.files("foundation_policy").joinpath("blob", "checkpoint.h5")
    with h5py.File(path, "r") as f:
        layers = f["actor/layers"]
        weights = {}
        for name, shape in rt.WEIGHT_SHAPES.items():
            _, layer, param = name.split("/")
            # the package stores dense biases as (1, n) matrices; blob/policy.h as (n,) tensors
            weights[name] = np.asarray(layers[layer][param]["parameters"][()], dtype=np.float32).reshape(shape)
        return weights, f["example/input"][()], f["example/output"][()]


def members(data: bytes) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers()}


def retar(contents: dict[str, bytes]) -> bytes:
    """A tar with these members in this order (for files our writer would never write)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for name, raw in contents.items():
            info = tarfile.TarInfo(name)
            info.size = len(raw)
            tar.addfile(info, io.BytesIO(raw))
    return buf.getvalue()


def data_offset(data: bytes, name: str) -> int:
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:") as tar:
        return tar.getmember(name).offset_data


def patch_float(data: bytes, member: str, index: int, value: float) -> bytes:
    """The file with float32 number `index` of `member` set to `value` (headers untouched)."""
    at = data_offset(data, member) + 4 * index
    return data[:at] + np.float32(value).tobytes() + data[at + 4 :]


def flip_low_byte(data: bytes, member: str, index: int) -> bytes:
    """The file with the lowest-order byte of float32 number `index` of `member` changed."""
    at = data_offset(data, member) + 4 * index
    return data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1 :]


def example_index(step: int, batch: int, k: int, dim: int) -> int:
    return (step * rt.EXAMPLE_BATCH + batch) * dim + k


def wider_first_layer(data: bytes) -> bytes:
    """The same file with a 32-unit first layer: a policy of another shape than blob/policy.h's."""
    c = members(data)
    wide = np.zeros((32, rt.OBS_DIM), dtype="<f4")
    c["actor/layers/0/weights/parameters/meta"] = rt._tensor_meta((32, rt.OBS_DIM))
    c["actor/layers/0/weights/parameters/data"] = wide.tobytes()
    return retar(c)


def observations(n: int = 2000, seed: int = 0) -> np.ndarray:
    """n gyro updates (2.5 ms apart) of a gentle flight around a hover point, as mc_raptor's
    observe() hands them to the executor: position 3, quaternion w x y z, velocity 3, body rates 3
    (FLU). Smooth motion with rate noise; made here, not recorded from a vehicle."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / (100 * GYRO_PER_NATIVE)
    t = np.arange(n) * dt
    pos = np.stack([0.2 * np.sin(1.3 * t), 0.15 * np.cos(0.7 * t) - 0.15, 0.1 * np.sin(2.1 * t)], 1)
    vel = np.gradient(pos, dt, axis=0)
    rpy = np.stack([0.2 * np.sin(2 * t), 0.15 * np.sin(1.1 * t + 0.5), 0.5 * np.sin(0.3 * t)], 1)
    c, s = np.cos(rpy / 2), np.sin(rpy / 2)
    q = np.stack(
        [
            c[:, 0] * c[:, 1] * c[:, 2] + s[:, 0] * s[:, 1] * s[:, 2],
            s[:, 0] * c[:, 1] * c[:, 2] - c[:, 0] * s[:, 1] * s[:, 2],
            c[:, 0] * s[:, 1] * c[:, 2] + s[:, 0] * c[:, 1] * s[:, 2],
            c[:, 0] * c[:, 1] * s[:, 2] - s[:, 0] * s[:, 1] * c[:, 2],
        ],
        1,
    )
    rates = np.gradient(rpy, dt, axis=0) + 0.05 * rng.standard_normal((n, 3))
    return np.concatenate([pos, q, vel, rates], 1).astype("<f4")


def _rotation(q: np.ndarray) -> np.ndarray:
    """RLtools' L2F observe(): the quaternion's rotation matrix, row-major, in float32."""
    w, x, y, z = (np.float32(v) for v in q)
    one, two = np.float32(1), np.float32(2)
    return np.array(
        [
            one - two * y * y - two * z * z, two * x * y - two * w * z, two * x * z + two * w * y,
            two * x * y + two * w * z, one - two * x * x - two * z * z, two * y * z - two * w * x,
            two * x * z - two * w * y, two * y * z + two * w * x, one - two * x * x - two * y * y,
        ],
        dtype=np.float32,
    )  # fmt: skip


def fly_like_mc_raptor(step, obs: np.ndarray) -> np.ndarray:
    """Actions (n, 4) for the observations as RLtools' L2F executor gives them in mc_raptor: every
    gyro update controls (FORCE_SYNC_INTERMEDIATE); every 4th, from the first, advances the GRU state
    (native), the others run from the last native state and drop theirs (intermediate); the action
    history is the mean of the previous actions since the last native step (action history 1);
    actions clipped to [-1, 1]; the previous action fed back as mc_raptor's observe() does.
    `step(x, advance)` runs the policy on one 22-input and returns the unclipped action."""
    prev = np.zeros(rt.ACTION_DIM, np.float32)
    history = prev.copy()
    since = 0
    out = np.empty((len(obs), rt.ACTION_DIM), np.float32)
    for k, o in enumerate(obs):
        history = prev.copy() if since == 0 else ((history * np.float32(since) + prev) / np.float32(since + 1))
        x = np.concatenate([o[0:3], _rotation(o[3:7]), o[7:10], o[10:13], history]).astype(np.float32)
        native = k % GYRO_PER_NATIVE == 0
        prev = np.clip(step(x, native), -1, 1).astype(np.float32)
        since = 0 if native else since + 1
        out[k] = prev
    return out


def forward(weights, xs):
    """Outputs (T, B, 4) of the runtime's GRU step on inputs (T, B, 22), each sequence from a reset."""
    return sequences(GruStep(weights), xs)


def our_stepper(weights):
    gru_step = GruStep(weights)
    state = {"h": gru_step.initial_state.copy()}

    def step(x, advance):
        action, h = gru_step(np.ascontiguousarray(x, np.float32), state["h"])
        if advance:
            state["h"] = h
        return action

    return step


def foundation_stepper():
    """The same through foundation-policy's own inference (its GRU keeps one state: an intermediate
    step puts the state back after running)."""
    import foundation_policy

    policy = foundation_policy.Raptor()
    policy.reset()
    gru = policy.layers[1]

    def step(x, advance):
        before = None if gru.state is None else gru.state.copy()
        action = policy.evaluate_step(x[None, :].astype(np.float64))[0]
        if not advance:
            gru.state = before if before is not None else None
        return action

    return step


def _bias_moved(data: bytes) -> bytes:
    member = "actor/layers/2/biases/parameters/data"
    at = data_offset(data, member)
    return patch_float(data, member, 0, float(np.frombuffer(data[at : at + 4], "<f4")[0]) + 2e-5)


# ways to damage a good policy.tar, each a function of its bytes
DAMAGE = {
    "a weight changed": lambda d: patch_float(d, "actor/layers/1/weights_hidden/parameters/data", 7, 0.9),
    "another shape": wider_first_layer,
    "NaN in the first example input steps": lambda d: patch_float(
        d, "example/input/data", example_index(2, 1, 4, rt.OBS_DIM), np.nan
    ),
    "NaN in the first example output steps": lambda d: patch_float(
        d, "example/output/data", example_index(2, 1, 1, rt.ACTION_DIM), np.nan
    ),
    "truncated in the weights": lambda d: d[:6000],
    "truncated in the example input": lambda d: d[: data_offset(d, "example/input/data") + 40_000],
    "an output bias moved by 2e-5": _bias_moved,
    "NaN at example step 300": lambda d: patch_float(
        d, "example/input/data", example_index(300, 0, 5, rt.OBS_DIM), np.nan
    ),
    "example output changed at step 300": lambda d: patch_float(
        d, "example/output/data", example_index(300, 1, 2, rt.ACTION_DIM), 0.25
    ),
    "truncated in the example output": lambda d: d[: data_offset(d, "example/output/data") + 4_000],
    "a weight's low-order byte changed": lambda d: flip_low_byte(d, "actor/layers/0/weights/parameters/data", 3),
    "an empty file": lambda d: b"",
    "shorter than a tar header": lambda d: d[:100],
}

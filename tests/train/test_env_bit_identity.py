"""The environments compute, bit for bit, what they computed when PINNED was last recomputed.

Each case steps `QuadVectorEnv` (or `QuadEnv`, or runs `evaluate`) for a few hundred steps with
seeded actions and hashes everything that comes out: observations, rewards, terminated, truncated,
every info array, and at the end the batch's arrays a checkpoint saves, the environment's and the
sensor noise's RNG states and the randomised plant. The cases cover the three tasks, both
observation versions, float32 and float64, domain randomisation (default and pushes), sensor noise,
motor lag, an idle rotor speed, an asymmetric rotor layout, substeps, the three start rotor speeds,
a curriculum change, an odd batch size (SIMD loop tails) and episodes short enough that drones
reset every few steps.

PINNED is what this file's `main()` prints (`python tests/train/test_env_bit_identity.py`). It was
first computed on the code before the allocation-free step (quadpilot 8e01231), to show that step
changed no bit. It was recomputed at quadpilot b446ba2, after deliberate changes had made it stale:
the parasitic drag (904bea3: c_dx, c_dy, c_dz) and the rotor aerodynamics (497624a: k_d, k_z, k_h,
k_flap) added vehicle parameters, hashed with the plant, in every case but evaluate, while the
outputs stayed as before; the motor lag's thrust averaged along the lag (13cc0e7) changed the cases
with motor lag (motor_lag_rest, px4_sih, the randomised ones, single_env, *_everything); an
evaluation of crashed episodes giving null instead of NaN (fb119ef) changed evaluate. The pins now
stand for the code of that commit, not for the code before the allocation-free step; a change meant
to keep every bit must leave them as they are.

Results of sin, cos, exp and sqrt may differ between CPUs (NumPy dispatches SIMD kernels per
instruction set) and NumPy versions, and `evaluate`'s products run in NumPy's BLAS, whose kernels
OpenBLAS picks per CPU or from OPENBLAS_CORETYPE. So the digests are compared only where they were
computed (MADE_WITH: NumPy version, best SIMD target, and an OpenBLAS core among those checked to
give these digests); elsewhere the test skips. The shipped models and the pinned training weights
of tests/train/test_spine.py depend on these same numbers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys

import numpy as np
import pytest

from quadpilot.core.params import Rotor
from quadpilot.core.vehicle_file import SEED_VEHICLE
from quadpilot.train.envs import QuadEnv, QuadVectorEnv, make_config
from quadpilot.train.envs.evaluate import evaluate

# the OpenBLAS core (OPENBLAS_CORETYPE, or what OpenBLAS detects without it): the digests were
# computed with Haswell (the CI machine's OPENBLAS_CORETYPE) and are the same with SkylakeX (what
# OpenBLAS detects on that machine)
MADE_WITH = {"numpy": "2.4.6", "simd": "AVX512_ICL", "blas_core": ("Haswell", "SkylakeX")}

# start exactly at home, commanded to hold the start heading: zero actions then hover and succeed
STILL = {"init_pos_radius": 0.0, "init_vel": 0.0, "init_tilt_deg": 0.0, "heading_offset_deg": 0.0}
LAG = dataclasses.replace(SEED_VEHICLE, motor_tau=0.02)
IDLE = dataclasses.replace(SEED_VEHICLE, omega_min=150.0, drag=0.05)
ASYMMETRIC = dataclasses.replace(
    SEED_VEHICLE,
    arm=None,
    rotors=(Rotor(0.12, 0.10, "ccw"), Rotor(-0.10, -0.13, "ccw"), Rotor(0.11, -0.12, "cw"), Rotor(-0.12, 0.09, "cw")),
)

# waypoint's reward as it was when the digests were pinned (its heading Gaussian was narrowed since:
# a change of what is paid, not of how the environment computes it)
WAYPOINT_REWARD_BEFORE = {"tilt_weight": 50.0, "heading_sigma": 0.5}
# hover's likewise (narrowed to 0.25 as waypoint's, for training through delay)
HOVER_REWARD_BEFORE = {"heading_sigma": 0.5}


def _as_pinned(kw: dict) -> dict:
    """make_config keywords with the reward the digests were pinned with."""
    return {"reward": HOVER_REWARD_BEFORE, **kw} if kw.get("task") == "hover" else kw


# name: (num_envs, steps, action kind, make_config keywords)
#   action kinds: "wild" uniform in [−1.2, 1.2] (clipped: crashes, frequent resets), "calm" normal
#   with σ 0.05 (long episodes: truncation, success windows, pushes), "zero", "wild64" as wild in float64
CASES: dict[str, tuple[int, int, str, dict]] = {
    "hover": (64, 300, "wild", {"task": "hover"}),
    "hover_calm_short": (67, 300, "calm", {"task": "hover", "episode_steps": 60}),
    "hover_v1": (64, 300, "calm", {"task": "hover", "obs_version": 1, "heading_offset_deg": 0.0}),
    "hover_still_success": (16, 260, "zero", {"task": "hover", "episode_steps": 250, **STILL}),
    "waypoint": (
        64,
        300,
        "calm",
        {"task": "waypoint", "target_radius": 2.0, "episode_steps": 80, "reward": WAYPOINT_REWARD_BEFORE},
    ),
    "circle": (64, 300, "calm", {"task": "circle", "episode_steps": 90}),
    "circle_v1_wild": (37, 300, "wild", {"task": "circle", "obs_version": 1}),
    "randomize_default": (64, 300, "calm", {"task": "hover", "randomization": "default", "episode_steps": 70}),
    "randomize_pushes": (64, 300, "calm", {"task": "hover", "randomization": "pushes", "episode_steps": 100}),
    "sensor_noise": (64, 300, "calm", {"task": "hover", "sensor_noise": "seed", "episode_steps": 70}),
    "motor_lag_rest": (64, 300, "wild", {"task": "hover", "vehicle": LAG, "init_rotor": "rest"}),
    "idle_drag_random_rotor": (
        33,
        300,
        "calm",
        {"task": "waypoint", "vehicle": IDLE, "init_rotor": "random", "reward": WAYPOINT_REWARD_BEFORE},
    ),
    "asymmetric": (64, 200, "calm", {"task": "hover", "vehicle": ASYMMETRIC, "episode_steps": 50}),
    "px4_sih": (40, 200, "calm", {"task": "hover", "vehicle": "px4_sih_quadx", "episode_steps": 50}),
    "crazyflie_noise": (64, 200, "calm", {"task": "circle", "vehicle": "crazyflie", "sensor_noise": "crazyflie"}),
    "float64": (64, 300, "wild64", {"task": "hover", "dtype": "float64"}),
    "float64_calm": (
        64,
        300,
        "calm",
        {"task": "waypoint", "dtype": "float64", "episode_steps": 60, "reward": WAYPOINT_REWARD_BEFORE},
    ),
    "float64_everything": (
        45,
        300,
        "calm",
        {
            "task": "circle",
            "dtype": "float64",
            "randomization": "pushes",
            "sensor_noise": "seed",
            "substeps": 2,
            "episode_steps": 80,
        },
    ),
    "float32_everything": (
        64,
        300,
        "calm",
        {"task": "hover", "randomization": "pushes", "sensor_noise": "seed", "substeps": 3, "episode_steps": 60},
    ),
    "one_drone": (1, 300, "wild", {"task": "hover"}),
}

PINNED: dict[str, str] = {
    "asymmetric": "97291123eb5feeac794c349174352c5a22919089cbd090fe38aa7dda047bec02",
    "circle": "caf49b6be3389eb3c2399c42bd1e4be105522d7efd458fbca0db27820c093295",
    "circle_v1_wild": "8ae5f6fce33152d319ddadfe34bf9f6d5c9a28e19a1c5b0452cd5fe921d77149",
    "crazyflie_noise": "11737e3871ee34013a49b994702ad2371529dfce434d7a899c5bdc90255eba5b",
    "evaluate": "28a44ccf0a9a92cd19771aad19a7f0ce5de0f1b6d1d3ea5f2dee9dbd620dd90e",
    "float32_everything": "1a34bb319d2c684569bc60e7d4f932a98ab4d96e63e74192d64c66c1d66eba86",
    "float64": "fd6f37f890f8c25f8a7a6bec3e6b33331fee4a7ed3fe667ca03f5b16fb9fe6f6",
    "float64_calm": "a81c5d3ab3e4a7233768eb25d2179b823a63f0cd3cb1be421c2e5a4538034dfd",
    "float64_everything": "243d86d33a392f22c2501cc47b71640cd5d341a3dcded79dcc9128874bbf7cc0",
    "hover": "0125b04023a0441b596e9a12ad983418054773754d51c49b97d9c41d0d3d569c",
    "hover_calm_short": "7b5dcf20f28be7da519e477719cf72baccbb9710628acf0177063a75da4e2def",
    "hover_still_success": "003860c2dec017bc60488c0a5faa1253c039d2722665bba07d6c7ec4fb804b90",
    "hover_v1": "4f0461511238f90e80af8f3c9f28fde856892126813d406a16fa2e728c867f37",
    "idle_drag_random_rotor": "0ffad7c4ceae3842e3d66ca2ec110f6c63ebe05b2b77801162a2883981a84ba9",
    "motor_lag_rest": "abd66b7b2ef9ccf8d80976c5f674f604c591810c418cc92c95253860dc9f0692",
    "one_drone": "c02647f805d1e56962b597f004245746aa596acdb10fe1461d0985c0095038e4",
    "px4_sih": "1a3269a907e72ba23cd32f7f1da6c03e70ce5f03842d43f8cae1066cb069d8cc",
    "randomize_default": "05a509865d060beae30c49d532aad5929d05b96708d247bf06b41099fabc778b",
    "randomize_pushes": "76e947e08e2957b0da29592b7c6bbff8e6cfb2a5cbdad1fca9c47d9596f16eeb",
    "sensor_noise": "54f79ab3071dd65f95518c7a78c791311e0bc5e67170c3b0b997aabacc9f160c",
    "single_env": "ca77bbad2028492145e9bbcf9f9ba94ef4f1331c783e0a61652acf5bf15492ee",
    "waypoint": "e5dd1ab4aed5c79b1c7b7fa10db21cbb22282d248c8755054a855b6613b496a7",
}


class Digest:
    """sha256 over arrays (dtype, shape and bytes) and plain values, in the order fed."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()

    def add(self, name: str, value) -> None:
        self.h.update(name.encode())
        if isinstance(value, dict):
            for k in sorted(value):
                self.add(f"{name}.{k}", value[k])
        elif isinstance(value, np.ndarray) or isinstance(value, np.generic):
            a = np.ascontiguousarray(value)
            self.h.update(f"{a.dtype.str}{a.shape}".encode())
            self.h.update(a.tobytes())
        else:
            self.h.update(json.dumps(value, sort_keys=True, default=str).encode())

    def hexdigest(self) -> str:
        return self.h.hexdigest()


def _actions(kind: str, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    if kind == "wild":
        return rng.uniform(-1.2, 1.2, shape).astype(np.float32)
    if kind == "wild64":
        return rng.uniform(-1.2, 1.2, shape)
    if kind == "calm":
        return (0.05 * rng.standard_normal(shape)).astype(np.float32)
    return np.zeros(shape, np.float32)


def _batch_state(d: Digest, batch) -> None:
    for name in (
        "state",
        "rotor",
        "target",
        "target_vel",
        "phase",
        "steps",
        "ep_return",
        "err_sum",
        "obs",
        "heading",
        "yaw_rate_sum",
        "heading_err_sum",
    ):
        d.add(f"batch.{name}", getattr(batch, name))
    d.add("params", {f.name: getattr(batch.params, f.name) for f in dataclasses.fields(batch.params)})
    if batch.noise is not None:
        d.add("noise", batch.noise.state_dict())
    if batch.randomizer is not None:
        d.add("randomizer", batch.randomizer.state_dict())


def vector_digest(name: str) -> str:
    n, steps, kind, kw = CASES[name]
    env = QuadVectorEnv(n, **_as_pinned(kw))
    d = Digest()
    obs, info = env.reset(seed=7)
    d.add("reset", {"obs": obs, "info": info})
    rng = np.random.default_rng(11)
    for t in range(steps):
        if name == "waypoint" and t == 150:
            env.set_target_radius(0.7)  # the curriculum moves on mid-run
        out = env.step(_actions(kind, rng, (n, 4)))
        d.add(f"step{t}", dict(zip(("obs", "reward", "terminated", "truncated", "infos"), out, strict=True)))
    _batch_state(d, env.batch)
    d.add("rng", env.rng.bit_generator.state)
    return d.hexdigest()


def single_digest() -> str:
    """QuadEnv (one drone, the same QuadBatch) through its own resets."""
    env = QuadEnv("circle", sensor_noise="seed", randomization="default")
    d = Digest()
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=5)
    d.add("reset", {"obs": obs, "info": info})
    for t in range(400):
        obs, reward, term, trunc, info = env.step(_actions("wild" if t % 100 < 50 else "calm", rng, (4,)))
        d.add(f"step{t}", {"obs": obs, "reward": reward, "term": term, "trunc": trunc, "info": info})
        if term or trunc:
            obs, info = env.reset()
            d.add(f"reset{t}", {"obs": obs, "info": info})
    _batch_state(d, env.batch)
    return d.hexdigest()


def evaluate_digest() -> str:
    """`train.envs.evaluate` on QuadBatch.step's outputs: a zero policy and a small linear one."""
    d = Digest()
    w = np.random.default_rng(9).normal(0.0, 0.05, (21, 4)).astype(np.float32)
    for task, policy in (
        ("hover", lambda obs: np.zeros((obs.shape[0], 4), np.float32)),
        ("circle", lambda obs: np.tanh(obs @ w[: obs.shape[1]])),
        ("waypoint", lambda obs: np.tanh(obs @ w[: obs.shape[1]])),
    ):
        reward = {"reward": WAYPOINT_REWARD_BEFORE} if task == "waypoint" else _as_pinned({"task": task})
        reward.pop("task", None)
        cfg = make_config(task, sensor_noise="seed" if task == "circle" else None, **reward)
        d.add(task, evaluate(policy, cfg, episodes=9, seed=4))
    return d.hexdigest()


DIGESTS = {
    **{name: (lambda name=name: vector_digest(name)) for name in CASES},
    "single_env": single_digest,
    "evaluate": evaluate_digest,
}


def blas_core() -> str | None:
    """The core whose kernels NumPy's OpenBLAS runs (set by OPENBLAS_CORETYPE, or detected)."""
    from threadpoolctl import threadpool_info

    return next((i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"), None)


def machine() -> dict:
    from numpy._core import _multiarray_umath as m

    best = [t for t in m.__cpu_dispatch__ if m.__cpu_features__.get(t)]
    return {"numpy": np.__version__, "simd": best[-1] if best else "none", "blas_core": blas_core()}


def made_here() -> bool:
    here = machine()
    return all(here[k] in v if isinstance(v, tuple) else here[k] == v for k, v in MADE_WITH.items())


@pytest.mark.parametrize("name", sorted(DIGESTS))
def test_outputs_hash_as_pinned(name):
    if not made_here():
        pytest.skip(f"digests pinned with {MADE_WITH}; this machine has {machine()}")
    assert DIGESTS[name]() == PINNED[name]


def main() -> None:
    """Print PINNED for the code in the working tree (run once on the code the pins stand for)."""
    print("PINNED: dict[str, str] = {")
    for name in sorted(DIGESTS):
        print(f'    "{name}": "{DIGESTS[name]()}",')
    print("}")


if __name__ == "__main__":
    sys.exit(main())

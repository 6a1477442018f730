"""The environments compute, bit for bit, what they computed before the allocation-free step.

Each case steps `QuadVectorEnv` (or `QuadEnv`, or runs `evaluate`) for a few hundred steps with
seeded actions and hashes everything that comes out: observations, rewards, terminated, truncated,
every info array, and at the end the batch's arrays a checkpoint saves, the environment's and the
sensor noise's RNG states and the randomised plant. The cases cover the three tasks, both
observation versions, float32 and float64, domain randomisation (default and pushes), sensor noise,
motor lag, an idle rotor speed, an asymmetric rotor layout, substeps, the three start rotor speeds,
a curriculum change, an odd batch size (SIMD loop tails) and episodes short enough that drones
reset every few steps.

PINNED was computed by this file's `main()` on the code before the allocation-free step (quadpilot
8e01231 with its working tree of that time; `python tests/train/test_env_bit_identity.py`). Results
of sin, cos, exp and sqrt may differ between CPUs (NumPy dispatches SIMD kernels per instruction
set) and NumPy versions, so the digests are compared only where they were computed (MADE_WITH);
elsewhere the test skips. The shipped models and the pinned training weights of
tests/train/test_spine.py depend on these same numbers.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys

import numpy as np
import pytest

from quadpilot.core.params import SEED_VEHICLE, Rotor
from quadpilot.train.envs import QuadEnv, QuadVectorEnv, make_config
from quadpilot.train.evaluate import evaluate

MADE_WITH = {"numpy": "2.4.6", "simd": "AVX512_ICL"}

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
    "asymmetric": "904266bfb8449c6196acb09e7b57977e5cefffd2afcb785806a77ebcbc70843e",
    "circle": "b6c49fc0620bf1880396f3c10f4f932fbe6737300a7a881d9b4ffc43ce88cd5d",
    "circle_v1_wild": "20245e68f109f629b2fbd67487f48c9cf24c42f1033ef737448197bf117f1ae0",
    "crazyflie_noise": "74f357a071cce32f3c76458259394d70afb9f00ae91f098830e1707638ac40db",
    "evaluate": "a26d7afee04a00c5eb527d5d89412a6427a077f51d92bdb164a165100b8b0d23",
    "float32_everything": "c4ad70dd4f1de2b08cf8f1db7307a161e48a179fa35931c9869fecf978b78f2a",
    "float64": "06db2a70228d541fdc8538bcd7dba83c3428d0922254fa3073e093ef647577ed",
    "float64_calm": "d6cd279b7c3a1f8a857687d7ca97d0b739e7a8fb5bebcfc767dbb9fffa5d0993",
    "float64_everything": "4735ac2109f21c2971fdf46150005b0f54e7069dd8666b84cf55e6d9d2638b4e",
    "hover": "c8de9225ef70ad5b917a7719fd6bebe788fface601c4c9c398a1fe4a120f1ecb",
    "hover_calm_short": "42537c92bec319dd6ef7cf93d3f7a64e0a2b9b07f3c1ce402347ccad33ccd82e",
    "hover_still_success": "da2866709dcae8dc167bde1876502cdd42eb3d4bd85ceb19c5b2b4af31484955",
    "hover_v1": "3745429de1eb05da6e5dc9279247ad9857585ce31616a0b3ab36bdcfe0386bca",
    "idle_drag_random_rotor": "7a3fd7fd3a8e7fb9da8ee16178a3084c369b98828f2388f1f5ee2ee29654568b",
    "motor_lag_rest": "94aea38cfbc029fa1e77cc6108ea246bd96028007c016c3085b929663402ad3a",
    "one_drone": "48da0e26742e76eb9c068e7787328eededca329ecc1eb18ceb2e814191462b61",
    "px4_sih": "321f9c084e9fdeb674d1a58b12df1b1c2b7b64fb101e5853a4adf12dc08451dd",
    "randomize_default": "acf1de162f21718340d27e96029e53576754efda25ae4858c41826fbe24fbcb0",
    "randomize_pushes": "153503680f5477055f318300ffdda921836ed4854bd551411007d49035cc1529",
    "sensor_noise": "458a1582593b8ec821996a81edb4f4eb05d6d540dbb63a9685ce5bcf1ba4fce3",
    "single_env": "abed2a4434aad9f2c12755b53605d2b8c2df397812842dfcff19aeb5cb5b54bc",
    "waypoint": "6d42667b415f13677a5d1bb229d4e4e9c5971faa40c1efb4fd0545fd6158fc63",
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
    env = QuadVectorEnv(n, **kw)
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
    d.add("rng", env._rng.bit_generator.state)
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
    """`train.evaluate` on QuadBatch.step's outputs: a zero policy and a small linear one."""
    d = Digest()
    w = np.random.default_rng(9).normal(0.0, 0.05, (21, 4)).astype(np.float32)
    for task, policy in (
        ("hover", lambda obs: np.zeros((obs.shape[0], 4), np.float32)),
        ("circle", lambda obs: np.tanh(obs @ w[: obs.shape[1]])),
        ("waypoint", lambda obs: np.tanh(obs @ w[: obs.shape[1]])),
    ):
        reward = {"reward": WAYPOINT_REWARD_BEFORE} if task == "waypoint" else {}
        cfg = make_config(task, sensor_noise="seed" if task == "circle" else None, **reward)
        d.add(task, evaluate(policy, cfg, episodes=9, seed=4))
    return d.hexdigest()


DIGESTS = {
    **{name: (lambda name=name: vector_digest(name)) for name in CASES},
    "single_env": single_digest,
    "evaluate": evaluate_digest,
}


def made_here() -> bool:
    from numpy._core import _multiarray_umath as m

    best = [t for t in m.__cpu_dispatch__ if m.__cpu_features__.get(t)]
    return {"numpy": np.__version__, "simd": best[-1] if best else "none"} == MADE_WITH


@pytest.mark.parametrize("name", sorted(DIGESTS))
def test_outputs_hash_as_before_the_allocation_free_step(name):
    if not made_here():
        pytest.skip(f"digests pinned with {MADE_WITH}; this machine differs")
    assert DIGESTS[name]() == PINNED[name]


def main() -> None:
    """Print PINNED for the code in the working tree (run once on the code the pins stand for)."""
    print("PINNED: dict[str, str] = {")
    for name in sorted(DIGESTS):
        print(f'    "{name}": "{DIGESTS[name]()}",')
    print("}")


if __name__ == "__main__":
    sys.exit(main())

"""Environment speed in drone-steps per second, all measured in one run (docs/architecture.md, style rule 10).

    (a) `quadpilot.core.dynamics.step` on N drones, float32 and float64;
    (b) `QuadVectorEnv` (hover) on N drones: action mapping, dynamics, observation, reward,
        termination and masked same-step autoreset;
    (b') the same vector env as commit bb5efb7 had it (`benchmarks/baseline.py`: that commit's
        source, run in a child process once per session, timed the same way), so that the report's
        ratio today ÷ baseline comes from one run on one machine;
    (c) the baseline of the speed targets: one `gymnasium.make("quadpilot/Hover-v0")` env stepped
        in a Python loop, resetting when an episode ends.

Run (the project's addopts disable benchmarks, so enable them here):

    .venv/bin/python -m pytest benchmarks/test_env_speed.py --benchmark-enable --benchmark-only \
        --benchmark-json=/tmp/bench.json -p no:cacheprovider
    .venv/bin/python benchmarks/report.py /tmp/bench.json

Every round times a block of `STEPS_PER_ROUND` calls, so the figures are per drone-step and, within
a benchmark group (one N), round times compare directly; the N = 1 group holds the baseline too.
Rounds are fixed per N, which keeps the suite well under a minute on two cores. Actions are drawn
once, before timing, uniform in [−1, 1] (what an untrained policy sends), so episodes end often and
the autoreset path is part of what (b) and (c) time; the share of steps that ended an episode is
recorded as `episode_end_fraction`. (b) also records what a step leaves allocated: minor page faults
per step over the timed rounds, and, over `STEPS_PER_ROUND` more steps under tracemalloc, the
growth of traced memory and the largest rise within a step beyond the arrays it returns. Without
--benchmark-enable every case runs one block, a smoke test (the baseline child one round per N).
"""

from __future__ import annotations

import json
import resource
import tracemalloc

import gymnasium as gym
import numpy as np
import pytest

import quadpilot.train  # noqa: F401  (registers quadpilot/Hover-v0)
from baseline import BASELINE_COMMIT, baseline_src, run_python
from quadpilot.core import dynamics
from quadpilot.core.params import ParamBatch
from quadpilot.core.vehicle_file import SEED_VEHICLE
from quadpilot.train.envs import QuadVectorEnv

NS = (1, 64, 1024, 4096)
STEPS_PER_ROUND = 50
ROUNDS = {1: 200, 64: 200, 1024: 60, 4096: 30}
WARMUP_ROUNDS = 2
START = np.array([0.0, 0.0, 2.0])  # m, the hover env's home


def _group(n: int) -> str:
    """All cases stepping N drones share a group, so their round times compare directly."""
    return f"N={n:>4} drones x {STEPS_PER_ROUND} steps per round"


def _minor_faults() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def _run(benchmark, block, n: int, args: tuple = ()) -> int:
    """Time `block(*args)` (STEPS_PER_ROUND calls) for ROUNDS[n] rounds; return the minor page
    faults seen over the whole benchmark, warm-up included."""
    benchmark.group = _group(n)
    f0 = _minor_faults()
    benchmark.pedantic(block, args=args, rounds=ROUNDS[n], warmup_rounds=WARMUP_ROUNDS, iterations=1)
    return _minor_faults() - f0


def _record(benchmark, results: list, kind: str, n: int, dtype: str, faults: int, **extra) -> None:
    """extra_info: kind, n, dtype, steps_per_round, drone_steps_per_s (from the fastest round),
    drone_steps_per_s_median, page_faults_per_step, and `extra`."""
    info = benchmark.extra_info
    info.update(kind=kind, n=n, dtype=dtype, steps_per_round=STEPS_PER_ROUND, **extra)
    stats = benchmark.stats
    if stats is None:  # benchmarks disabled: the block ran once
        return
    per_round = n * STEPS_PER_ROUND
    info["drone_steps_per_s"] = per_round / stats.stats.min
    info["drone_steps_per_s_median"] = per_round / stats.stats.median
    info["page_faults_per_step"] = faults / ((ROUNDS[n] + WARMUP_ROUNDS) * STEPS_PER_ROUND)
    results.append(dict(info))


def _random_actions(shape: tuple[int, ...], seed: int = 1) -> list[np.ndarray]:
    """STEPS_PER_ROUND float32 action arrays uniform in [−1, 1], drawn before any timing."""
    rng = np.random.default_rng(seed)
    return list(rng.uniform(-1.0, 1.0, (STEPS_PER_ROUND, *shape)).astype(np.float32))


def _start_states(n: int, dtype, seed: int = 0) -> np.ndarray:
    """(n, 12) starts like the hover env's: within 1 m of home, ±0.5 m/s, ±20° roll and pitch,
    any yaw, no rotation."""
    rng = np.random.default_rng(seed)
    s = np.zeros((n, dynamics.STATE_DIM))
    v = rng.normal(size=(n, 3))
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    s[:, 0:3] = START + v * rng.random((n, 1)) ** (1.0 / 3.0)
    s[:, 3:6] = rng.uniform(-0.5, 0.5, (n, 3))
    s[:, 6:8] = rng.uniform(-np.radians(20.0), np.radians(20.0), (n, 2))
    s[:, 8] = rng.uniform(-np.pi, np.pi, n)
    return s.astype(dtype)


@pytest.mark.parametrize("n", NS, ids=[f"N{n}" for n in NS])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_dynamics_step(benchmark, speed_results, n, dtype):
    """(a) the raw batched dynamics step. Every round starts from the same states (step does not
    modify its inputs) and holds a command within ±1 % thrust of hover trim, so attitudes stay
    moderate for the 0.5 s a round simulates."""
    params = ParamBatch.from_preset(SEED_VEHICLE, n, dtype=np.dtype(dtype))
    state0 = _start_states(n, dtype)
    u_hover = dynamics.hover_command(params)[:, None]
    rng = np.random.default_rng(2)
    command = (u_hover * np.sqrt(1.0 + rng.uniform(-0.01, 0.01, (n, 4)))).astype(dtype)
    rotor0 = np.repeat(u_hover, 4, axis=1).astype(dtype)
    step = dynamics.step

    def block(state, rotor):
        for _ in range(STEPS_PER_ROUND):
            state, rotor = step(state, rotor, command, params)
        return state

    faults = _run(benchmark, block, n, args=(state0, rotor0))
    final = block(state0, rotor0)
    assert final.dtype == np.dtype(dtype) and np.isfinite(final).all()
    _record(benchmark, speed_results, "dynamics", n, dtype, faults)


@pytest.mark.parametrize("n", NS, ids=[f"N{n}" for n in NS])
def test_vector_env_step(benchmark, speed_results, n):
    """(b) `QuadVectorEnv.step` on N drones, hover task, default config (float32 state)."""
    env = QuadVectorEnv(n, task="hover")
    env.reset(seed=0)
    actions = _random_actions((n, 4))

    def block():
        for a in actions:
            env.step(a)

    faults = _run(benchmark, block, n)
    ended = 0
    for a in actions:  # untimed: how often the timed path went through autoreset
        _, _, term, trunc, _ = env.step(a)
        ended += int(np.count_nonzero(term | trunc))
    growth, beyond = _traced(env, actions)
    env.close()
    _record(
        benchmark,
        speed_results,
        "vector_env",
        n,
        env.cfg.dtype,
        faults,
        episode_end_fraction=ended / (n * STEPS_PER_ROUND),
        traced_growth_bytes_per_step=growth,
        traced_peak_beyond_results_bytes=beyond,
    )


def _traced(env, actions) -> tuple[float, int]:
    """(traced memory growth per step, the largest rise of traced memory within a step beyond the
    arrays the step returns) over one block of steps under tracemalloc, after one block of warm-up."""
    tracemalloc.start()
    try:
        start, beyond = tracemalloc.get_traced_memory()[0], 0
        for a in actions:
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            obs, reward, term, trunc, infos = env.step(a)
            results = [obs, reward, term, trunc, *(v for k, v in infos.items() if k != "episode")]
            results += list(infos.get("episode", {}).values())
            beyond = max(beyond, tracemalloc.get_traced_memory()[1] - before - sum(r.nbytes for r in results))
            del obs, reward, term, trunc, infos, results
        growth = (tracemalloc.get_traced_memory()[0] - start) / len(actions)
    finally:
        tracemalloc.stop()
    return growth, beyond


_BASELINE = pytest.StashKey[dict]()

# Times the vector env of the code on the import path (the baseline commit's, see run_python) as
# test_vector_env_step times today's: the same actions, rounds and warm-up per N; prints JSON.
_BASELINE_CHILD = """
import json, resource, sys, time
import numpy as np
from quadpilot.train.envs import QuadVectorEnv
spec = json.loads(sys.argv[1])
out = {}
for n, rounds in spec["rounds"].items():
    n = int(n)
    env = QuadVectorEnv(n, task="hover")
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    actions = list(rng.uniform(-1.0, 1.0, (spec["steps"], n, 4)).astype(np.float32))
    times = []
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for r in range(spec["warmup"] + rounds):
        t = time.perf_counter()
        for a in actions:
            env.step(a)
        t = time.perf_counter() - t
        if r >= spec["warmup"]:
            times.append(t)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0
    out[n] = {"round_s": times, "faults_per_step": faults / ((spec["warmup"] + rounds) * spec["steps"])}
print(json.dumps(out))
"""


def _baseline_rounds(config, enabled: bool) -> dict:
    """The baseline's round times per N, measured once per session (one round per N when the
    benchmarks are disabled: a smoke test)."""
    key = (_BASELINE, enabled)
    cache = config.stash.setdefault(_BASELINE, {})
    if key not in cache:
        rounds = {n: ROUNDS[n] if enabled else 1 for n in NS}
        spec = {"rounds": rounds, "steps": STEPS_PER_ROUND, "warmup": WARMUP_ROUNDS if enabled else 0}
        out = run_python(_BASELINE_CHILD, baseline_src(), json.dumps(spec))
        cache[key] = {int(n): v for n, v in json.loads(out.splitlines()[-1]).items()}
    return cache[key]


@pytest.mark.parametrize("n", NS, ids=[f"N{n}" for n in NS])
def test_vector_env_step_baseline(benchmark, speed_results, request, n):
    """(b') the vector env of commit bb5efb7, timed in a child process with that commit's source.
    Its round times come from the child; the benchmark fixture times nothing here (it only places
    the case in the run), so the report reads `round_s` instead of pytest-benchmark's statistics."""
    benchmark.group = _group(n)
    measured = _baseline_rounds(request.config, not benchmark.disabled)[n]
    benchmark.pedantic(lambda: None, rounds=1, iterations=1)
    times = np.asarray(measured["round_s"])
    info = benchmark.extra_info
    info.update(
        kind="vector_env_baseline",
        n=n,
        dtype="float32",
        steps_per_round=STEPS_PER_ROUND,
        commit=BASELINE_COMMIT,
        round_s={"min": float(times.min()), "median": float(np.median(times)), "mean": float(times.mean())},
    )
    if benchmark.disabled:
        return
    per_round = n * STEPS_PER_ROUND
    info["drone_steps_per_s"] = per_round / times.min()
    info["drone_steps_per_s_median"] = per_round / np.median(times)
    info["page_faults_per_step"] = measured["faults_per_step"]
    speed_results.append(dict(info))


def test_single_env_loop(benchmark, speed_results):
    """(c) baseline: one `gymnasium.make` env (with its default wrappers) stepped from Python,
    reset whenever an episode ends."""
    env = gym.make("quadpilot/Hover-v0")
    env.reset(seed=0)
    actions = _random_actions((4,))
    ends = [0]

    def block():
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                ends[0] += 1
                env.reset()

    faults = _run(benchmark, block, 1)
    calls = (ROUNDS[1] + WARMUP_ROUNDS) * STEPS_PER_ROUND if benchmark.stats is not None else STEPS_PER_ROUND
    dtype = env.unwrapped.cfg.dtype
    wrappers = repr(env)
    env.close()
    _record(
        benchmark,
        speed_results,
        "single_env",
        1,
        dtype,
        faults,
        episode_end_fraction=ends[0] / calls,
        env=wrappers,
    )

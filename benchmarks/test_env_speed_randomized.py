"""What domain randomisation costs the vector environment, measured in one run against
the same environment without it (docs/architecture.md, style rule 10).

    QuadVectorEnv("hover") on N drones (128: the training default; 4096), randomization None,
    "params" (mass, inertia, k_f, k_m, motor lag: a new ParamBatch and re-derived constants at
    every reset, the lag path every step), "default" (+ wind: drag and an external force every
    step) and "pushes" (+ a push window check every step).

Run:

    .venv/bin/python -m pytest benchmarks/test_env_speed_randomized.py --benchmark-enable \\
        --benchmark-only -p no:cacheprovider

Actions are uniform in [−1, 1], drawn before timing (as in test_env_speed.py), so episodes end
often and the per-reset resampling is timed at its worst; `episode_end_fraction` records how
often. The median round is the fairer figure here (rounds differ in how many drones reset).
"""

from __future__ import annotations

import numpy as np
import pytest

from quadpilot.train.envs import QuadVectorEnv

STEPS_PER_ROUND = 50
NS = (128, 4096)
ROUNDS = {128: 100, 4096: 30}
MODES = (None, "params", "default", "pushes")


@pytest.mark.parametrize("n", NS, ids=[f"N{n}" for n in NS])
@pytest.mark.parametrize("mode", MODES, ids=[str(m) for m in MODES])
def test_vector_env_step_randomized(benchmark, speed_results, n, mode):
    env = QuadVectorEnv(n, task="hover", randomization=mode)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    actions = list(rng.uniform(-1.0, 1.0, (STEPS_PER_ROUND, n, 4)).astype(np.float32))

    def block():
        for a in actions:
            env.step(a)

    benchmark.group = f"N={n:>4} drones x {STEPS_PER_ROUND} steps per round, randomisation"
    benchmark.pedantic(block, rounds=ROUNDS[n], warmup_rounds=2, iterations=1)
    ended = 0
    for a in actions:  # untimed: how often the timed path went through autoreset
        _, _, term, trunc, _ = env.step(a)
        ended += int(np.count_nonzero(term | trunc))
    info = benchmark.extra_info
    info.update(kind=f"dr:{mode}", n=n, dtype=env.cfg.dtype, episode_end_fraction=ended / (n * STEPS_PER_ROUND))
    if benchmark.stats is None:  # benchmarks disabled: the block ran once
        return
    per_round = n * STEPS_PER_ROUND
    info["drone_steps_per_s"] = per_round / benchmark.stats.stats.min
    info["drone_steps_per_s_median"] = per_round / benchmark.stats.stats.median
    info["page_faults_per_step"] = float("nan")
    speed_results.append(dict(info))

"""Learning tests: each trains from a fixed seed on a small budget and asserts a number that only a
learner gets, so a flipped objective or an LSTM state that is not carried from step to step fails
here even where the unit tests of the maths still pass.

- PPO (the `fast` preset, what `quad-train --task hover` runs) reaches the hover success bar
  (`core.mission`'s definition through `train.envs.evaluate`, the bar `quad-train` records) within 70
  updates, 0.57 M steps (README: first at 0.49 M for each of 3 seeds, evaluating every 10 updates).
- Recurrent PPO (`arch="lstm"`) learns a task that needs memory, and the MLP with the same budget
  cannot: a cue shown only in the first observation of an episode decides the right action for the
  rest of it (`CueEnv`).
- SAC improves the evaluation return of its deterministic policy on a 3-D point mass it must bring
  to the origin (`PointMassEnv`). SAC on hover did not do it in a minute: it runs ~750 steps/s here
  (docs/comparison.md), and measured on seed 0 its evaluation return at 20k steps was where the
  untrained policy's was (15.5 against 15.2; 41 s of training under load).

The two small environments are vectorised like `QuadVectorEnv`: `reset(seed=)` → (obs, {}),
`step(actions (N, 4))` → (obs, reward, terminated, truncated, infos) with same-step autoreset and
`final_obs` / `_final_obs` / `episode` / `_episode` in `infos` when episodes end, which is all the
PPO and SAC rollouts read. They emit observations of the hover layout's width, zero-padded, so the
trainers' networks are built as for hover; they replace the trainer's environment after it is built.

Torch threads: the CLI runs PPO with 2 (PPOConfig.threads). These tests use 1: on this 2-core
machine shared with other work, 2 threads made single hover iterations take 0.4-9 s against
0.36-0.43 s with 1 (oversubscription), and at a load average of 2 both cost ~0.5 s per update. The
thread count and torch's global generator are put back after each test.

Measured spreads (seeds 0-4) and run times are next to each threshold; the whole file took 39-45 s
on the 2 cores shared with other work (load average ~2), plain and under `nice -n 10`.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quadpilot.train.envs import make_config
from quadpilot.train.envs.evaluate import evaluate
from quadpilot.train.ppo import PPO, PRESETS, PPOConfig
from quadpilot.train.runs.loop import SUCCESS_BAR
from quadpilot.train.sac import SAC, SACConfig

SEED = 0
OBS_DIM = make_config("hover").layout.dim


@pytest.fixture(autouse=True)
def _restore_torch_globals():
    """PPO and SAC set torch's thread count and seed its global generator; later tests get back
    what they had."""
    n, rng = torch.get_num_threads(), torch.get_rng_state()
    yield
    torch.set_num_threads(n)
    torch.set_rng_state(rng)


# --- PPO on hover ---------------------------------------------------------------------------

HOVER_MAX_UPDATES = 70  # × 8,192 = 573,440 steps
HOVER_EVAL_FROM, HOVER_EVAL_EVERY = 40, 5


def hover_updates_to_bar(seed: int) -> int | None:
    """Train the `fast` preset on hover without delay (its learning-rate schedule run over 1 M steps,
    the preset's before quad-train's default timing made it 3 M) and evaluate the deterministic policy
    on 100 episodes every HOVER_EVAL_EVERY updates from HOVER_EVAL_FROM on, as quad-train's periodic
    evaluation does (it records the first evaluation at SUCCESS_BAR as `first_success`). Returns the
    update of that first evaluation, None if none reached the bar within HOVER_MAX_UPDATES."""
    ppo = PPO(
        PPOConfig(**{**PRESETS["fast"], "total_steps": 1_000_000, "seed": seed, "threads": 1}), make_config("hover")
    )
    while ppo.updates < HOVER_MAX_UPDATES:
        ppo.iterate()
        if ppo.updates >= HOVER_EVAL_FROM and ppo.updates % HOVER_EVAL_EVERY == 0:
            if evaluate(ppo.act_deterministic, ppo.env_cfg, episodes=100)["success_rate"] >= SUCCESS_BAR:
                return ppo.updates
    return None


def test_ppo_reaches_the_hover_success_bar_within_573k_steps():
    # seeds 0-4 with the preset's NumPy update and 8 epochs, first evaluation at ≥ 95 %: update 60, 40,
    # 50, 55, 55 (327,680-491,520 steps; 6-12 s each); threshold update 70 (573,440 steps). The
    # evaluations in between can dip (with the torch update and 10 epochs, seed 3: 100 % at 55 and 60,
    # 60 % at 65), which is why the test takes the first, as quad-train does, not the one at a fixed step.
    updates = hover_updates_to_bar(SEED)
    assert updates is not None, f"PPO hover never reached {SUCCESS_BAR:.0%} success in {HOVER_MAX_UPDATES} updates"


# --- recurrent PPO on a memory task ---------------------------------------------------------


class CueEnv:
    """N copies of a memory task. At an episode's first step the observation shows a cue c = ±1
    (component 0, with a start flag in component 1); every later observation is all zeros. Each step
    pays −(a₀ − c)², a₀ the first action component clipped to [−1, 1], and the episode terminates
    after `length` steps. A memoryless policy sees the same zeros after the first step whatever the
    cue, so it can be right for at most one cue value there; remembering the cue earns every step.
    `balanced`: cues alternate +1, −1 by index (for evaluation) instead of being drawn."""

    def __init__(self, n: int, length: int = 16, balanced: bool = False) -> None:
        self.num_envs, self.length, self.balanced = n, length, balanced
        self.rng = np.random.default_rng(0)
        self.cue = np.zeros(n, np.float32)
        self.t = np.zeros(n, np.int64)
        self.ret = np.zeros(n)

    def _start(self, idx: np.ndarray) -> None:
        if self.balanced:
            self.cue[idx] = np.where(idx % 2 == 0, 1.0, -1.0)
        else:
            self.cue[idx] = self.rng.choice(np.array([-1.0, 1.0], np.float32), idx.size)
        self.t[idx] = 0
        self.ret[idx] = 0.0

    def _obs(self) -> np.ndarray:
        obs = np.zeros((self.num_envs, OBS_DIM), np.float32)
        first = self.t == 0
        obs[:, 0] = np.where(first, self.cue, 0.0)
        obs[:, 1] = first
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._start(np.arange(self.num_envs))
        return self._obs(), {}

    def step(self, actions):
        a0 = np.clip(np.asarray(actions, np.float64)[:, 0], -1.0, 1.0)
        reward = -((a0 - self.cue) ** 2)
        self.ret += reward
        self.t += 1
        term = self.t >= self.length
        trunc = np.zeros(self.num_envs, bool)
        obs, infos = self._obs(), {}
        if term.any():
            infos = {
                "final_obs": obs,
                "_final_obs": term,
                "episode": {"r": self.ret.copy(), "l": self.t.copy(), "success": np.zeros(self.num_envs, bool)},
                "_episode": term,
            }
            self._start(np.flatnonzero(term))
            obs = self._obs()
        return obs, reward.astype(np.float32), term, trunc, infos


# the fast preset otherwise (Adam lr 1e-3 annealed over the budget, rewards × 0.05, 64 LSTM units) with the
# 10 epochs it ran when the spread below was measured; a rollout is two 16-step episodes per drone, a
# minibatch 16 sequences of 32 steps
CUE_UPDATES = 20  # × 64 drones × 32 steps = 40,960 steps
CUE_PPO = {
    **{"num_envs": 64, "rollout_steps": 32, "minibatch_size": 512, "epochs": 10},
    "total_steps": CUE_UPDATES * 64 * 32,
}


def cue_hit_rate(arch: str, seed: int, episodes: int = 200) -> float:
    """Train PPO (`arch` mlp or lstm) on CueEnv for CUE_UPDATES updates; return the fraction of the
    steps after the cue at which the deterministic action is within 0.5 of the cue, over `episodes`
    evaluation episodes with balanced cues."""
    ppo = PPO(PPOConfig(arch=arch, seed=seed, threads=1, **CUE_PPO), make_config("hover"))
    ppo.env = CueEnv(ppo.cfg.num_envs)
    ppo.reseed(seed)
    for _ in range(CUE_UPDATES):
        ppo.iterate()
    env = CueEnv(episodes, balanced=True)
    obs, _ = env.reset()
    actor = ppo.act_deterministic
    state = actor.initial_state(episodes)
    hits = []
    for t in range(env.length):
        cue = env.cue.copy()
        if actor.stateful:
            action, state = actor.step(obs, state)
        else:
            action = actor(obs)
        if t > 0:
            hits.append(np.abs(action[:, 0] - cue) < 0.5)
        obs, *_ = env.step(action)
    return float(np.mean(hits))


def test_recurrent_ppo_remembers_a_cue_that_an_mlp_cannot():
    lstm = cue_hit_rate("lstm", SEED)
    mlp = cue_hit_rate("mlp", SEED)
    # seeds 0-4 after 40,960 steps: LSTM 100, 100, 100, 100, 100 %; threshold 90 %. 8-16 s for both runs.
    assert lstm >= 0.9, f"the LSTM policy matched the cue at {lstm:.0%} of the steps after it"
    # seeds 0-4: MLP 0, 0, 0, 0, 0 % (it learns a₀ ≈ 0, the best memoryless answer under −(a₀ − c)²);
    # above 50 % would mean the environment leaks the cue and the LSTM result proves nothing
    assert mlp <= 0.5, f"the MLP policy matched the cue at {mlp:.0%}: the task does not need memory"


# --- SAC on a point mass --------------------------------------------------------------------


class PointMassEnv:
    """N point masses in 3-D, each to be brought to the origin and held there. Observation:
    position (components 0-2) and velocity (3-5); action components 0-2 command an acceleration of
    up to `acc` m/s² per axis (component 3 is ignored); reward −|position| per step. Starts at rest,
    uniform in the cube ±1 m; episodes are truncated after `length` steps of `dt` s."""

    dt, acc, length = 0.1, 2.0, 50

    def __init__(self, n: int) -> None:
        self.num_envs = n
        self.rng = np.random.default_rng(0)
        self.pos = np.zeros((n, 3))
        self.vel = np.zeros((n, 3))
        self.t = np.zeros(n, np.int64)
        self.ret = np.zeros(n)

    def _start(self, idx: np.ndarray) -> None:
        self.pos[idx] = self.rng.uniform(-1.0, 1.0, (idx.size, 3))
        self.vel[idx] = 0.0
        self.t[idx] = 0
        self.ret[idx] = 0.0

    def _obs(self) -> np.ndarray:
        obs = np.zeros((self.num_envs, OBS_DIM), np.float32)
        obs[:, 0:3], obs[:, 3:6] = self.pos, self.vel
        return obs

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._start(np.arange(self.num_envs))
        return self._obs(), {}

    def step(self, actions):
        a = np.clip(np.asarray(actions, np.float64)[:, :3], -1.0, 1.0)
        self.vel += self.acc * a * self.dt
        self.pos += self.vel * self.dt
        reward = -np.linalg.norm(self.pos, axis=1)
        self.ret += reward
        self.t += 1
        term = np.zeros(self.num_envs, bool)
        trunc = self.t >= self.length
        obs, infos = self._obs(), {}
        if trunc.any():
            infos = {
                "final_obs": obs,
                "_final_obs": trunc,
                "episode": {"r": self.ret.copy(), "l": self.t.copy(), "success": np.zeros(self.num_envs, bool)},
                "_episode": trunc,
            }
            self._start(np.flatnonzero(trunc))
            obs = self._obs()
        return obs, reward.astype(np.float32), term, trunc, infos


# 8 drones × 100 vector steps per iteration, 2 gradient steps per vector step (update-to-data 1/4,
# as SACConfig's default), the first 1,000 transitions random
SAC_ITERATIONS = 10  # 8,000 steps, 1,750 gradient steps
SAC_CONFIG = {"num_envs": 8, "rollout_steps": 100, "learning_starts": 1_000, "updates_per_step": 2}


def point_mass_return(sac: SAC, episodes: int = 100) -> float:
    """Mean return of the deterministic policy over `episodes` point-mass episodes (fixed starts)."""
    env = PointMassEnv(episodes)
    obs, _ = env.reset(seed=12345)
    ret = np.zeros(episodes)
    for _ in range(env.length):
        obs, reward, *_ = env.step(sac.act_deterministic(obs))
        ret += reward
    return float(ret.mean())


def sac_return_gain(seed: int) -> tuple[float, float]:
    """(untrained return, return after SAC_ITERATIONS iterations) of SAC on PointMassEnv."""
    sac = SAC(SACConfig(seed=seed, threads=1, **SAC_CONFIG), make_config("hover"))
    sac.env = PointMassEnv(sac.cfg.num_envs)
    sac.reseed(seed)
    before = point_mass_return(sac)
    for _ in range(SAC_ITERATIONS):
        sac.iterate()
    return before, point_mass_return(sac)


def test_sac_improves_its_return_on_a_point_mass():
    before, after = sac_return_gain(SEED)
    # seeds 0-4: untrained −48.5 to −48.8; gain after 8,000 steps 36.4, 36.0, 35.7, 35.4, 36.0;
    # threshold 20. 6-11 s.
    assert after - before >= 20.0, f"SAC return {before:.1f} → {after:.1f} after {SAC_ITERATIONS} iterations"

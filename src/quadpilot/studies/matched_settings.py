"""The matched settings of the SB3 comparison, written down: how every `PPOConfig` field reaches
Stable-Baselines3 PPO through `quadpilot.train.sb3_baseline.sb3_settings`, or why it cannot be matched
exactly (`FIELD_MAP`; a test fails when PPOConfig gains a field that is not in it), the settings that
are not fields but decide what the two compute (`IMPLICIT_ROWS`), and the table quad-compare's report
writes into docs/comparison.md (`settings_rows`).
"""

from __future__ import annotations

import dataclasses

from quadpilot.train.ppo import PPOConfig
from quadpilot.train.sb3_baseline import sb3_settings

# Every PPOConfig field: (where it goes in `sb3_settings(cfg)`, or None; how it maps or how it differs).
# Keys in the first element are paths into the settings dict ("ppo.n_steps").
FIELD_MAP: dict[str, tuple[str | None, str]] = {
    "num_envs": ("n_envs", "same vector env, as many drones"),
    "rollout_steps": ("ppo.n_steps", ""),
    "total_steps": ("total_timesteps", "both round up to whole rollouts"),
    "epochs": ("ppo.n_epochs", ""),
    "minibatch_size": (
        "ppo.batch_size",
        "when the rollout is not a multiple of it, SB3 adds a shorter last minibatch each epoch; ours "
        "drops the remainder (a different random one each epoch)",
    ),
    "lr": ("learning_rate.initial", "Adam, eps 1e-5 in both"),
    "lr_schedule": (
        "learning_rate.schedule",
        "SB3 evaluates its schedule after the rollout (progress 1 − k/K at update k); `MatchedLR` shifts it "
        "by one update so update k uses lr·(1 − (k−1)/K) in both",
    ),
    "gamma": ("ppo.gamma", ""),
    "lam": ("ppo.gae_lambda", ""),
    "clip_eps": ("ppo.clip_range", ""),
    "clip_value": ("ppo.clip_range_vf", "clip_eps when clip_value, else None (no value clipping)"),
    "vf_coef": (
        "ppo.vf_coef",
        "halved: SB3's value loss is the MSE, ours ½·MSE (PPO paper eq. 9 with the ½ of a squared error); "
        "the gradients are then identical. metrics.csv logs ½·SB3's value_loss so the column means one thing",
    ),
    "ent_coef": ("ppo.ent_coef", "entropy of the diagonal Gaussian summed over actions in both"),
    "max_grad_norm": ("ppo.max_grad_norm", "global norm over all parameters, log-std included, in both"),
    "target_kl": (
        "ppo.target_kl",
        "not exact: SB3 stops when a minibatch's approx_kl > 1.5·target_kl, before that step; ours after an "
        "epoch whose last minibatch exceeded target_kl. Passed as target_kl/1.5 so the thresholds agree "
        "(None in every preset)",
    ),
    "arch": ("policy", "mlp → MlpPolicy (ActorCriticPolicy); the comparison matches the MLP only"),
    "lstm_hidden": (None, "unused by an MLP policy"),
    "bptt_steps": (None, "unused by an MLP policy"),
    "obs_history": (None, "1 (the plain observation) only: SB3 would need a frame-stacking wrapper"),
    "actor_hidden": ("policy_kwargs.net_arch.pi", "separate actor and critic networks in both"),
    "critic_hidden": ("policy_kwargs.net_arch.vf", ""),
    "activation": ("policy_kwargs.activation_fn", ""),
    "init_log_std": (
        "policy_kwargs.log_std_init",
        "state-independent learned log-std in both; orthogonal init with gains √2 (hidden), 0.01 (policy "
        "output), 1 (value output) and zero biases in both (ortho_init)",
    ),
    "reward_scale": (
        "reward_scale",
        "our `ScaleReward` VecEnv wrapper multiplies rewards by it; VecNormalize's norm_reward (division by "
        "a running std of the discounted return) is a different thing, so it stays off",
    ),
    "normalize_obs": (
        "vec_normalize.norm_obs",
        "VecNormalize(norm_obs, clip_obs=10, epsilon=1e-8), the same formula and clip as ours, but SB3 "
        "updates its statistics every step while ours updates them between rollouts; off in both presets "
        "(no VecNormalize at all then)",
    ),
    "normalize_adv": ("ppo.normalize_advantage", "per minibatch, (A − mean)/(std + 1e-8), in both"),
    "max_nonfinite_updates": (
        None,
        "no equivalent: SB3 does not skip non-finite data or gradients (a NaN would reach the weights)",
    ),
    "seed": (
        "seed",
        "SB3 seeds Python, NumPy, torch and the env (reset seed); the random streams differ from ours, so "
        "seed s of one is not seed s of the other",
    ),
    "threads": ("threads", "torch.set_num_threads in both"),
    "update": (
        None,
        "how our PPO computes its update and rollout forward passes (numpy: quadpilot.train.ppo.numpy_ppo, or "
        "torch; equal to float32 rounding); SB3 computes its own with torch autograd",
    ),
}

# Settings that are not PPOConfig fields but decide what the two compute.
IMPLICIT_ROWS: tuple[tuple[str, str, str], ...] = (
    (
        "truncation (time limit) bootstrapping",
        "next value = V(final observation) for truncated steps; GAE chain cut at every episode end",
        "adds γ·V(terminal_observation) to the reward when infos['TimeLimit.truncated'] (SB3 2.9: "
        "collect_rollouts, one forward call per ended drone); the same advantages",
    ),
    (
        "action clipping",
        "sampled action stored unclipped; clipped to [−1, 1] for the env",
        "the same (np.clip to the action space)",
    ),
    (
        "rollout / update split",
        "collect (with GAE) then update; advantages float64",
        "collect_rollouts (with GAE) then train; buffer float32",
    ),
    (
        "approx_kl, clip_fraction (logged)",
        "(r − 1) − log r, mean over all minibatches of the update",
        "the same estimator, mean over the last epoch's minibatches",
    ),
    ("grad_norm (logged)", "before clipping, mean over the update", "not logged by SB3 (blank)"),
    (
        "checkpoints",
        "checkpoint.pt every update (included in training time)",
        "none during training; policy and statistics written at the end",
    ),
)


def _get(d: dict, path: str):
    for k in path.split("."):
        d = d[k]
    return d


def settings_rows(cfg: PPOConfig) -> list[tuple[str, str, str]]:
    """(our field = value, SB3 parameter = value, note) for every PPOConfig field: the table of
    docs/comparison.md."""
    s = sb3_settings(cfg)
    rows = []
    for f in dataclasses.fields(PPOConfig):
        path, note = FIELD_MAP[f.name]
        ours = f"{f.name} = {getattr(cfg, f.name)!r}"
        theirs = "—" if path is None else f"{path.split('.')[-1]} = {_get(s, path)!r}"
        rows.append((ours, theirs, note))
    return rows

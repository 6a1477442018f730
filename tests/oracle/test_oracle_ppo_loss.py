"""Oracle tests of the PPO objective (Schulman et al. 2017, arXiv:1707.06347) and of the SAC losses
(Haarnoja et al. 2018, arXiv:1812.05905) against hand-computed values and gradient directions.

The PPO loss lives inside `PPO.update`, so the tests go through it: one epoch, one minibatch holding
the whole batch, so the reported metrics are the losses at the parameters before the step. Each
batch is built from the network's own log-probabilities and values so that the ratio r_t, the value
error and the value change since collection take chosen numbers:

    old log π = log π_θ(a|s) − log r_target,   ret = V(s) − e,   old V = V(s) − Δ.

    L^CLIP = mean(min(r·Â, clip(r, 1 − ε, 1 + ε)·Â))     (eq. 7; the trainer minimises −L^CLIP)
    L^VF   = ½·mean((V − R)²), or ½·mean(max((V − R)², (V_old + clip(V − V_old, ±ε) − R)²))
    approx_kl = mean((r − 1) − log r)                    (Schulman 2020, "Approximating KL Divergence")
"""

import math

import numpy as np
import pytest
import torch

from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, NonFiniteError, PPOConfig
from quadpilot.train.ppo import recurrent as recurrent_ppo
from quadpilot.train.sac import SAC, SACConfig, squashed_log_prob, temperature_loss

EPS = 0.2
# (ratio, advantage) pairs: inside and outside [1 − ε, 1 + ε], positive and negative advantages.
RATIOS = [1.5, 0.5, 1.3, 0.7, 1.1, 0.95]
ADVS = [1.0, 1.0, -1.0, -1.0, 2.0, -2.0]
# min(r·A, clip(r)·A) row by row:
#   min(1.5, 1.2) = 1.2;  min(0.5, 0.8) = 0.5;  min(−1.3, −1.2) = −1.3;  min(−0.7, −0.8) = −0.8;
#   min(2.2, 2.2) = 2.2;  min(−1.9, −1.9) = −1.9;   sum = −0.1, L^CLIP = −0.1/6
POLICY_LOSS = 0.1 / 6  # −L^CLIP
POLICY_LOSS_IF_CLIP_IGNORED = -0.3 / 6  # −mean(r·A) = −(1.5 + 0.5 − 1.3 − 0.7 + 2.2 − 1.9)/6
CLIP_FRACTION = 4 / 6  # |r − 1| > ε for the first four rows
# (r − 1) − log r: 1.5 → 0.0945348919, 0.5 → 0.1931471806, 1.3 → 0.0376357355, 0.7 → 0.0566749439,
# 1.1 → 0.0046898202, 0.95 → 0.0012932944. mean(r) ≠ 1 here, so the (r − 1) term counts: the plain
# estimator mean(−log r) = 0.0563293 differs from it.
APPROX_KL = (0.0945348919 + 0.1931471806 + 0.0376357355 + 0.0566749439 + 0.0046898202 + 0.0012932944) / 6
# Value: e = V − R and Δ = V − V_old per row.
VALUE_ERR = [-1.0, 1.0, 0.0, -0.5, 0.5, -2.0]
VALUE_DELTA = [0.3, 0.3, 0.0, -0.3, 0.0, 0.3]
VALUE_LOSS = 0.5 * (1 + 1 + 0 + 0.25 + 0.25 + 4) / 6  # 0.541666…
# Clipped: V_clip − R = e − (Δ − clip(Δ, ±0.2)) = [−1.1, 0.9, 0, −0.4, 0.5, −2.1];
# max of the squares per row: [1.21, 1, 0, 0.25, 0.25, 4.41], sum 7.12.
VALUE_LOSS_CLIPPED = 0.5 * 7.12 / 6  # 0.593333…
LOG_STD = -1.0
ENTROPY = 4 * (0.5 + 0.5 * math.log(2 * math.pi) + LOG_STD)  # 4 independent Gaussians, σ = e^−1: 1.6757541


def make_ppo(**kw) -> PPO:
    base = dict(
        num_envs=2,
        rollout_steps=4,
        epochs=1,
        minibatch_size=6,
        normalize_adv=False,
        lr_schedule="constant",
        clip_eps=EPS,
        init_log_std=LOG_STD,
        actor_hidden=(8,),
        critic_hidden=(8,),
        max_grad_norm=1e6,
        threads=1,
        seed=0,
    )
    return PPO(PPOConfig(**{**base, **kw}), make_config("hover", episode_steps=8))


def mlp_batch(ppo: PPO, n: int = 6, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random observations and actions; logp, ret, val set from the network for the chosen numbers."""
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(n, ppo.obs_dim, generator=g)
    act = torch.randn(n, 4, generator=g) * 0.5
    with torch.no_grad():
        logp = ppo.model.distribution(obs).log_prob(act).sum(-1)
        v = ppo.model.value(obs)
    return {"obs": obs, "act": act, "logp": logp, "adv": torch.zeros(n), "ret": v.clone(), "val": v.clone()}


def set_targets(batch, logp_now, v_now, ratios, advs, value_err, value_delta) -> dict[str, torch.Tensor]:
    b = dict(batch)
    t = lambda x: torch.tensor(x, dtype=torch.float32).reshape(logp_now.shape)  # noqa: E731
    b["logp"] = logp_now - torch.log(t(ratios))
    b["adv"] = t(advs)
    b["ret"] = v_now - t(value_err)
    b["val"] = v_now - t(value_delta)
    return b


def hand_batch(ppo: PPO) -> dict[str, torch.Tensor]:
    b = mlp_batch(ppo)
    return set_targets(b, b["logp"], b["val"], RATIOS, ADVS, VALUE_ERR, VALUE_DELTA)


def test_policy_loss_matches_the_clipped_surrogate_by_hand():
    ppo = make_ppo()
    m = ppo.update(hand_batch(ppo))
    assert m["policy_loss"] == pytest.approx(POLICY_LOSS, abs=1e-5)
    assert m["clip_fraction"] == pytest.approx(CLIP_FRACTION, abs=1e-6)


def test_the_clip_matters():
    """With ε so large that nothing clips, the loss is −mean(r·A): a clip that is ignored gives
    that number in the test above too, and fails it."""
    ppo = make_ppo(clip_eps=10.0)
    m = ppo.update(hand_batch(ppo))
    assert m["policy_loss"] == pytest.approx(POLICY_LOSS_IF_CLIP_IGNORED, abs=1e-5)
    assert m["clip_fraction"] == 0.0
    assert abs(POLICY_LOSS - POLICY_LOSS_IF_CLIP_IGNORED) > 0.05


def test_value_loss_entropy_and_approx_kl_by_hand():
    ppo = make_ppo()
    m = ppo.update(hand_batch(ppo))
    assert m["value_loss"] == pytest.approx(VALUE_LOSS, abs=1e-5)
    assert m["entropy"] == pytest.approx(ENTROPY, abs=1e-5)
    assert m["approx_kl"] == pytest.approx(APPROX_KL, abs=1e-5)
    assert APPROX_KL == pytest.approx(np.mean([(r - 1) - math.log(r) for r in RATIOS]), abs=1e-9)


def test_clipped_value_loss_by_hand():
    ppo = make_ppo(clip_value=True)
    m = ppo.update(hand_batch(ppo))
    assert m["value_loss"] == pytest.approx(VALUE_LOSS_CLIPPED, abs=1e-5)
    assert abs(VALUE_LOSS_CLIPPED - VALUE_LOSS) > 0.05  # the clip changes this batch's loss


def test_recurrent_policy_uses_the_same_objective():
    """The LSTM path (`recurrent_ppo.forward`) feeds the same loss: same hand numbers, with the 6 rows
    laid out as 2 steps × 3 sequences."""
    ppo = make_ppo(arch="lstm", lstm_hidden=4, rollout_steps=2, clip_value=True)
    length, seqs, h = 2, 3, 4
    g = torch.Generator().manual_seed(1)
    batch = {
        "obs": torch.randn(length, seqs, ppo.obs_dim, generator=g),
        "act": torch.randn(length, seqs, 4, generator=g) * 0.5,
        "starts": torch.tensor([[True, True, True], [False, True, False]]),
        **{k: torch.randn(seqs, h, generator=g) * 0.1 for k in recurrent_ppo.STATE_KEYS},
    }
    for k in ("logp", "adv", "ret", "val"):
        batch[k] = torch.zeros(length, seqs)
    with torch.no_grad():
        dist, v, _ = recurrent_ppo.forward(ppo.model, batch, torch.arange(seqs))
        logp = dist.log_prob(batch["act"].reshape(-1, 4)).sum(-1).reshape(length, seqs)
        v = v.reshape(length, seqs)
    batch = set_targets(batch, logp, v, RATIOS, ADVS, VALUE_ERR, VALUE_DELTA)
    m = ppo.update(batch)
    assert m["policy_loss"] == pytest.approx(POLICY_LOSS, abs=1e-5)
    assert m["value_loss"] == pytest.approx(VALUE_LOSS_CLIPPED, abs=1e-5)
    assert m["approx_kl"] == pytest.approx(APPROX_KL, abs=1e-5)
    assert m["clip_fraction"] == pytest.approx(CLIP_FRACTION, abs=1e-6)


def weighted_logp(ppo: PPO, batch) -> float:
    with torch.no_grad():
        logp = ppo.model.distribution(batch["obs"]).log_prob(batch["act"]).sum(-1)
    return float((batch["adv"] * logp).sum())


@pytest.mark.parametrize("normalize_adv", [False, True])
def test_a_policy_step_raises_the_advantage_weighted_log_probability(normalize_adv):
    """Ascent on L^CLIP from θ_old (r = 1) moves along +∇ Σ Â·log π(a|s): after one optimiser step
    the actions with positive advantage are, in aggregate, more likely and those with negative
    advantage less.
    A flipped objective sign or an inverted ratio lowers the sum instead."""
    n = 32
    ppo = make_ppo(minibatch_size=n, vf_coef=0.0, ent_coef=0.0, lr=1e-3, normalize_adv=normalize_adv)
    b = mlp_batch(ppo, n=n, seed=4)
    adv = torch.randn(n, generator=torch.Generator().manual_seed(5))
    b["adv"] = adv - adv.mean()  # zero mean: per-minibatch normalisation keeps every sign
    before = weighted_logp(ppo, b)
    m = ppo.update(b)
    after = weighted_logp(ppo, b)
    assert m["approx_kl"] == pytest.approx(0.0, abs=1e-6)  # the batch was collected by this policy
    assert after > before + 1e-3, (before, after)
    # in aggregate the positive-advantage actions became more likely, the negative ones less
    with torch.no_grad():
        logp0 = b["logp"]
        logp1 = ppo.model.distribution(b["obs"]).log_prob(b["act"]).sum(-1)
    pos, neg = b["adv"] > 0, b["adv"] < 0
    assert float(((logp1 - logp0) * b["adv"])[pos].sum()) > 0
    assert float(((logp1 - logp0) * b["adv"])[neg].sum()) > 0


def test_a_value_step_moves_the_value_towards_the_return():
    """With zero advantages only c1·L^VF drives the step: V(s) must approach the return."""
    n = 32
    ppo = make_ppo(minibatch_size=n, vf_coef=1.0, ent_coef=0.0, lr=1e-3)
    b = mlp_batch(ppo, n=n, seed=6)
    b["ret"] = b["val"] + torch.linspace(-2.0, 2.0, n)
    err0 = float(((b["val"] - b["ret"]) ** 2).sum())
    ppo.update(b)
    with torch.no_grad():
        err1 = float(((ppo.model.value(b["obs"]) - b["ret"]) ** 2).sum())
    assert err1 < err0 - 1e-3, (err0, err1)


def test_the_entropy_bonus_raises_the_entropy():
    """Loss − c2·S: with zero advantages and no value weight, a step raises the policy's log σ."""
    n = 16
    ppo = make_ppo(minibatch_size=n, vf_coef=0.0, ent_coef=0.1, lr=1e-3)
    b = mlp_batch(ppo, n=n, seed=7)
    ppo.update(b)
    log_std = ppo.model.log_std.detach()
    np.testing.assert_allclose(log_std.numpy(), LOG_STD + 1e-3, rtol=0, atol=1e-6)  # Adam's first step: +lr


def lstm_batch(ppo: PPO, seqs: int = 3, seed: int = 1) -> dict[str, torch.Tensor]:
    """seqs sequences of ppo.seq_len steps, zero advantages, returns equal to the stored values."""
    length, h = ppo.seq_len, ppo.cfg.lstm_hidden
    g = torch.Generator().manual_seed(seed)
    batch = {
        "obs": torch.randn(length, seqs, ppo.obs_dim, generator=g),
        "act": torch.randn(length, seqs, 4, generator=g) * 0.5,
        "starts": torch.zeros(length, seqs, dtype=torch.bool),
        **{k: torch.randn(seqs, h, generator=g) * 0.1 for k in recurrent_ppo.STATE_KEYS},
    }
    batch["starts"][0] = True
    for k in ("logp", "adv", "ret", "val"):
        batch[k] = torch.zeros(length, seqs)
    return batch


def test_the_linear_schedule_decays_the_learning_rate_to_zero():
    """lr_k = lr·max(0, 1 − k/N) at update k of N = ⌈total_steps / batch_size⌉ (here 8 steps per
    batch, 80 total: N = 10)."""
    ppo = make_ppo(lr_schedule="linear", lr=1e-3, total_steps=80)
    assert ppo.cfg.num_updates == 10
    b = hand_batch(ppo)
    for k, lr in ((0, 1e-3), (1, 9e-4), (4, 6e-4), (10, 0.0), (25, 0.0)):
        ppo.updates = k
        m = ppo.update(b)
        assert m["lr"] == pytest.approx(lr, abs=1e-15), k
        assert ppo.opt.param_groups[0]["lr"] == pytest.approx(lr, abs=1e-15)
        assert ppo.updates == k + 1
    constant = make_ppo(lr_schedule="constant", lr=1e-3, total_steps=80)
    constant.updates = 5
    assert constant.update(hand_batch(constant))["lr"] == 1e-3


def test_recurrent_non_finite_sequences_are_skipped_and_counted_in_steps():
    """A sequence holding a NaN is left out whole; the count is in transitions: 1 sequence × 2 steps."""
    ppo = make_ppo(arch="lstm", lstm_hidden=4, rollout_steps=2, minibatch_size=6)
    batch = lstm_batch(ppo)
    batch["obs"][1, 2, 0] = float("nan")  # step 1 of sequence 2
    m = ppo.update(batch)
    assert m["nonfinite_skipped"] == 2
    assert math.isfinite(m["policy_loss"])


def test_recurrent_minibatches_hold_whole_sequences():
    """minibatch_size 2 with sequences of 2 steps: one sequence per minibatch, so 3 sequences give 3
    optimiser steps. With zero advantages and value weight only the entropy bonus moves log σ, by lr
    per Adam step (a constant gradient): 3 steps of 1e-3."""
    ppo = make_ppo(arch="lstm", lstm_hidden=4, rollout_steps=2, minibatch_size=2, vf_coef=0.0, ent_coef=0.1, lr=1e-3)
    ppo.update(lstm_batch(ppo))
    log_std = ppo.model.log_std.detach().numpy()
    np.testing.assert_allclose(log_std, LOG_STD + 3e-3, rtol=0, atol=1e-6)


def test_normalised_advantages_by_hand():
    """Per minibatch Â ← (Â − mean)/(std + 1e-8), std with Bessel's correction (torch's default).
    Advantages of mean 0.5 so that the centring matters; the clipped surrogate of the hand ratios
    then recomputed row by row."""
    advs = [a + 0.5 for a in ADVS]
    mean = sum(advs) / 6
    std = math.sqrt(sum((a - mean) ** 2 for a in advs) / 5)  # √(12/5) = 1.549193…
    norm = [(a - mean) / (std + 1e-8) for a in advs]
    expected = -sum(min(r * a, min(max(r, 1 - EPS), 1 + EPS) * a) for r, a in zip(RATIOS, norm, strict=True)) / 6
    assert expected == pytest.approx(POLICY_LOSS / math.sqrt(12 / 5), rel=1e-6)  # mean 0 after centring
    ppo = make_ppo(normalize_adv=True)
    b = mlp_batch(ppo)
    b = set_targets(b, b["logp"], b["val"], RATIOS, advs, VALUE_ERR, VALUE_DELTA)
    m = ppo.update(b)
    assert m["policy_loss"] == pytest.approx(expected, abs=1e-6)


def test_clipped_value_loss_when_the_value_fell_by_more_than_epsilon():
    """Rows (e, Δ): (0.5, −0.3): V_clip − R = 0.5 − (−0.3 + 0.2) = 0.6, max(0.25, 0.36) = 0.36;
    (−0.5, 0.3): −0.6, 0.36; (0.5, 0.1) inside the clip: 0.25; three zeros. ½·0.97/6."""
    ppo = make_ppo(clip_value=True)
    b = mlp_batch(ppo)
    b = set_targets(b, b["logp"], b["val"], RATIOS, ADVS, [0.5, -0.5, 0.5, 0, 0, 0], [-0.3, 0.3, 0.1, 0, 0, 0])
    assert ppo.update(b)["value_loss"] == pytest.approx(0.5 * 0.97 / 6, abs=1e-6)


def test_only_whole_minibatches_are_stepped():
    """8 transitions in minibatches of 3: two optimiser steps per epoch (the 2 left over are drawn in
    another order next epoch). Entropy bonus only: log σ rises by lr per Adam step, 2e-3."""
    ppo = make_ppo(minibatch_size=3, vf_coef=0.0, ent_coef=0.1, lr=1e-3)
    ppo.update(mlp_batch(ppo, n=8, seed=3))
    np.testing.assert_allclose(ppo.model.log_std.detach().numpy(), LOG_STD + 2e-3, rtol=0, atol=1e-6)


def test_non_finite_losses_skip_their_step_and_are_counted():
    """Finite data whose ratio overflows: old log π = −1e30 makes r = e^(1e30) = ∞, and with
    negative advantages −Â·r = +∞ wins the max. Both minibatches of the epoch are skipped (2), the
    weights are not touched; a batch with nothing finite is skipped whole without a step."""
    ppo = make_ppo(minibatch_size=3)
    before = [p.detach().clone() for p in ppo.model.parameters()]
    b = mlp_batch(ppo)
    b["logp"] = torch.full_like(b["logp"], -1e30)
    b["adv"] = torch.full_like(b["adv"], -1.0)
    m = ppo.update(b)
    assert m["nonfinite_skipped"] == 2
    assert all(torch.equal(p0, p1) for p0, p1 in zip(before, ppo.model.parameters(), strict=True))
    nan = mlp_batch(ppo)
    nan["ret"] = torch.full_like(nan["ret"], float("nan"))
    m = make_ppo(minibatch_size=3).update(nan)
    assert m["nonfinite_skipped"] == 6 and math.isnan(m["policy_loss"])


def test_overflowing_gradients_skip_their_step_and_are_counted():
    """A finite loss whose gradient overflows float32: advantages of 1e20 give a policy loss of
    about −1e20 but a gradient norm of ∞. Both minibatches are skipped, the weights not touched."""
    ppo = make_ppo(minibatch_size=3)
    before = [p.detach().clone() for p in ppo.model.parameters()]
    b = mlp_batch(ppo)
    b["adv"] = torch.full_like(b["adv"], 1e20)
    assert ppo.update(b)["nonfinite_skipped"] == 2
    assert all(torch.equal(p0, p1) for p0, p1 in zip(before, ppo.model.parameters(), strict=True))


def test_consecutive_non_finite_updates_abort_after_the_configured_count():
    """Every update counts; max_nonfinite_updates = 3 non-finite updates in a row raise NonFiniteError
    naming the count, the skipped transitions and steps, and what to do."""
    ppo = make_ppo(max_nonfinite_updates=3)
    b = mlp_batch(ppo)
    b["adv"] = torch.full_like(b["adv"], 1e20)
    ppo.update(b)
    ppo.update(b)
    assert ppo.updates == 2
    with pytest.raises(NonFiniteError) as info:
        ppo.update(b)
    message = str(info.value)
    assert message.startswith("3 consecutive updates met NaN/Inf (this one: 0 non-finite transitions, 1 skipped")
    assert message.endswith("Lower the learning rate or check the environment and reward for NaN.")


def test_target_kl_stops_the_epochs_early():
    """approx_kl of the hand batch is 0.064 at its first step: with target_kl 0.01 the update stops
    after the first of 3 epochs (one Adam step), without it all 3 epochs run."""
    steps = {}
    for target in (0.01, None):
        ppo = make_ppo(epochs=3, target_kl=target)
        m = ppo.update(hand_batch(ppo))
        steps[target] = ppo.opt.state[ppo.model.log_std]["step"].item()
        if target is not None:
            assert m["approx_kl"] == pytest.approx(APPROX_KL, abs=1e-5)  # the one step's value
    assert steps == {0.01: 1, None: 3}


@pytest.mark.parametrize(
    "ret, val, expected",
    [
        # y − v = (0, 0, 0, 0, 0, −1): Var = 1/6 (Bessel); Var(y) of 1..6 = 3.5; 1 − (1/6)/3.5 = 20/21
        ([1, 2, 3, 4, 5, 6], [1, 2, 3, 4, 5, 7], 20 / 21),
        ([1, 3], [1, 2], 0.75),  # Var(y) = 2, Var((0, 1)) = 0.5
        ([2, 2, 2], [1, 2, 3], float("nan")),  # Var(y) = 0: undefined
    ],
)
def test_explained_variance_by_hand(ret, val, expected):
    """explained_variance = 1 − Var(R − V_old)/Var(R) over the batch's transitions."""
    n = len(ret)
    ppo = make_ppo(minibatch_size=n)
    b = mlp_batch(ppo, n=n)
    b["ret"] = torch.tensor(ret, dtype=torch.float32)
    b["val"] = torch.tensor(val, dtype=torch.float32)
    ev = ppo.update(b)["explained_variance"]
    if math.isnan(expected):
        assert math.isnan(ev)
    else:
        assert ev == pytest.approx(expected, abs=1e-6)


# --- SAC ----------------------------------------------------------------------------------------

SAC_GAMMA, SAC_ALPHA, REWARD, REWARD_SCALE = 0.9, 0.5, 1.0, 2.0
Q_ONLINE = (0.5, 1.0)  # Q_θ1, Q_θ2 of every (s, a)
Q_TARGET = (2.0, 3.0)  # Q_θ̄1, Q_θ̄2 of every (s', a')
NEXT_LOGP = -1.2  # log π(a'|s')


def constant_twin_q(q: torch.nn.Module, values: tuple[float, float]) -> None:
    """Zero every weight; the output bias of critic j is values[j]: Q_j(s, a) = values[j]."""
    with torch.no_grad():
        for w in q.weights:
            w.zero_()
        for b in q.biases:
            b.zero_()
        q.biases[-1][0].fill_(values[0])
        q.biases[-1][1].fill_(values[1])


@pytest.mark.parametrize(
    "terminated, y",
    [
        # y = r·scale + γ·(1 − d)·(min(Q̄1, Q̄2) − α·log π(a'|s')) = 2 + 0.9·(2 − 0.5·(−1.2)) = 2 + 0.9·2.6
        (0.0, 4.34),
        (1.0, 2.0),  # no bootstrap after a crash
    ],
)
def test_sac_soft_q_target_by_hand(monkeypatch, terminated, y):
    """J_Q = Σ_j ½·mean((Q_j − y)²) with the soft target of 1812.05905 eqs. 3 and 5 and the minimum
    of the two target critics (Fujimoto et al. 2018). Critics are made constant; the policy's
    log π(a'|s') is pinned to NEXT_LOGP (its sample keeps its graph so the actor step still runs)."""
    cfg = SACConfig(
        num_envs=2,
        buffer_size=8,
        minibatch_size=8,
        learning_starts=0,
        gamma=SAC_GAMMA,
        init_alpha=SAC_ALPHA,
        reward_scale=REWARD_SCALE,
        actor_hidden=(4,),
        critic_hidden=(4,),
        threads=1,
        seed=0,
    )
    sac = SAC(cfg, make_config("hover", episode_steps=8))
    d = sac.env_cfg.layout.dim
    rng = np.random.default_rng(0)
    sac.buffer.add(
        rng.normal(size=(8, d)),
        rng.uniform(-1, 1, (8, 4)),
        np.full(8, REWARD),
        rng.normal(size=(8, d)),
        np.full(8, terminated),
    )
    constant_twin_q(sac.critic, Q_ONLINE)
    constant_twin_q(sac.critic_target, Q_TARGET)
    real_sample = sac.actor.sample

    def pinned_sample(obs, generator=None):
        a, logp = real_sample(obs, generator)
        return a, logp - logp.detach() + NEXT_LOGP

    monkeypatch.setattr(sac.actor, "sample", pinned_sample)
    m = sac.gradient_step()
    expected = 0.5 * ((Q_ONLINE[0] - y) ** 2 + (Q_ONLINE[1] - y) ** 2)
    assert m["q_loss"] == pytest.approx(expected, abs=1e-4)
    assert m["q_mean"] == pytest.approx(0.75, abs=1e-6)


def test_sac_squashed_log_prob_by_hand():
    """log π(tanh u) = log N(u; μ, σ²) − Σ log(1 − tanh² u), with log(1 − tanh² u) = −2·log cosh u."""
    u = torch.tensor([[0.5, -2.0, 10.0, 0.0]], dtype=torch.float64)
    mean = torch.tensor([[0.2, -1.0, 9.0, 0.0]], dtype=torch.float64)
    log_std = torch.tensor([[-1.0, 0.0, 0.5, -2.0]], dtype=torch.float64)
    expected = 0.0
    for ui, mi, li in zip(u[0].tolist(), mean[0].tolist(), log_std[0].tolist(), strict=True):
        z = (ui - mi) / math.exp(li)
        expected += -0.5 * z * z - li - 0.5 * math.log(2 * math.pi) + 2.0 * math.log(math.cosh(ui))
    got = squashed_log_prob(u, mean, log_std)
    assert float(got[0]) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize(
    "logp, grad_sign",
    [
        ([-1.0, -3.0], +1.0),  # entropy 2 > target −4: the step lowers α
        ([5.0, 7.0], -1.0),  # entropy −6 < target −4: the step raises α
    ],
)
def test_sac_temperature_loss_by_hand(logp, grad_sign):
    """J(log α) = −log α · mean(log π + H̄), H̄ = −4 (1812.05905 eq. 18)."""
    log_alpha = torch.tensor(math.log(0.5), requires_grad=True)
    loss = temperature_loss(log_alpha, torch.tensor(logp), -4.0)
    mean_term = np.mean(logp) - 4.0
    assert float(loss.detach()) == pytest.approx(-math.log(0.5) * mean_term, abs=1e-6)
    loss.backward()
    assert float(log_alpha.grad) == pytest.approx(-mean_term, abs=1e-6)
    assert math.copysign(1.0, float(log_alpha.grad)) == grad_sign

"""PPO's loss in torch and its gradient step, as autograd and torch.optim.Adam compute them: the
reference update (`ppo.TorchPPO`, `ppo.RecurrentPPO`), against which the NumPy
update (`numpy_ppo`) is checked. Schulman et al. 2017, arXiv:1707.06347, as a loss to minimise:

    r_t(θ) = π_θ(a_t|s_t) / π_θold(a_t|s_t)                                  (eq. 6)
    L^CLIP = E_t[min(r_t·Â_t, clip(r_t, 1 − ε, 1 + ε)·Â_t)]                   (eq. 7)
    L      = −L^CLIP + c1·L^VF − c2·S[π_θ]                                    (eq. 9)

with L^VF = ½·(V − R)² (or, with clip_value, the larger of that and the clipped value's, as OpenAI
baselines), Â normalised per minibatch when normalize_adv.
"""

from __future__ import annotations

import torch


def gradient_step(model, opt, dist, v: torch.Tensor, data: dict[str, torch.Tensor], cfg) -> tuple | None:
    """One step on a minibatch: the Gaussian `dist` of the policy at its states and the values `v`
    (B,) under the current weights, `data` its stored act, logp (log π_θold), adv, ret and val.
    Returns (policy_loss, value_loss, entropy, approx_kl, clip_fraction, grad_norm), or None when
    the loss or the gradient norm is not finite (then the weights are not touched)."""
    act, old_logp = data["act"], data["logp"]
    adv, ret, old_v = data["adv"], data["ret"], data["val"]
    if cfg.normalize_adv:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    logp = dist.log_prob(act).sum(-1)
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    # L^CLIP as a loss: max of the negated unclipped and clipped objectives
    pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - cfg.clip_eps, 1 + cfg.clip_eps)).mean()
    if cfg.clip_value:
        v_clip = old_v + (v - old_v).clamp(-cfg.clip_eps, cfg.clip_eps)
        v_loss = 0.5 * torch.max((v - ret) ** 2, (v_clip - ret) ** 2).mean()
    else:
        v_loss = 0.5 * ((v - ret) ** 2).mean()
    entropy = dist.entropy().sum(-1).mean()
    loss = pg_loss + cfg.vf_coef * v_loss - cfg.ent_coef * entropy
    opt.zero_grad(set_to_none=True)
    if not torch.isfinite(loss):
        return None
    loss.backward()
    gnorm = torch.nn.utils.clip_grad_norm_(list(model.parameters()), cfg.max_grad_norm)
    if not torch.isfinite(gnorm):
        opt.zero_grad(set_to_none=True)
        return None
    opt.step()
    with torch.no_grad():
        return (
            pg_loss.item(),
            v_loss.item(),
            entropy.item(),
            ((ratio - 1) - log_ratio).mean().item(),
            ((ratio - 1).abs() > cfg.clip_eps).float().mean().item(),
            gnorm.item(),
        )

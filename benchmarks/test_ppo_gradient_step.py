"""One PPO minibatch gradient step of the hover networks at minibatch 64 and 1,024, in one run
(docs/comparison.md, "Why not 10×"): how much of a step is fixed per-call cost, which an
implementation could remove, and how much is the arithmetic that grows with the minibatch.

The step is what both our PPO and SB3's do per minibatch: forward of actor (18 → 64 → 64 → 4, tanh)
and critic (18 → 64 → 64 → 1), Gaussian log-probability, clipped surrogate and value loss,
backward, global gradient-norm clip, Adam. One torch thread, as in the comparison runs.

    .venv/bin/python -m pytest benchmarks/test_ppo_gradient_step.py --benchmark-enable --benchmark-only \
        -p no:cacheprovider

`extra_info` carries the multiply-add count of the matrix products and the GFLOP/s they imply.
"""

from __future__ import annotations

import pytest
import torch

from quadpilot.train.networks import ActorCritic


@pytest.mark.parametrize("minibatch", [64, 1024])
def test_gradient_step(benchmark, minibatch):
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = ActorCritic(18, 4)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4, eps=1e-5)
    obs, act = torch.randn(minibatch, 18), torch.randn(minibatch, 4)
    adv, ret, old_logp = torch.randn(minibatch), torch.randn(minibatch), torch.randn(minibatch)

    def step():
        ratio = (model.distribution(obs).log_prob(act).sum(-1) - old_logp).exp()
        pg = torch.max(-adv * ratio, -adv * ratio.clamp(0.8, 1.2)).mean()
        loss = pg + 0.25 * ((model.value(obs) - ret) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 0.5)
        opt.step()

    benchmark.pedantic(step, rounds=300, iterations=1, warmup_rounds=30)
    macs = minibatch * (2 * (18 * 64 + 64 * 64) + 64 * 4 + 64)  # actor and critic, forward
    benchmark.extra_info.update(minibatch=minibatch, forward_macs=macs)
    if benchmark.stats is not None:  # None without --benchmark-enable (a smoke run)
        seconds = benchmark.stats.stats.min
        benchmark.extra_info["gflops_matrix_products"] = 2 * 3 * macs / seconds / 1e9  # forward + 2× backward

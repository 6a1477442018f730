"""One PPO minibatch gradient step of the hover networks at minibatch 64 and 1,024, in one run
(docs/comparison.md, "Why not 10×"): how much of a step is fixed per-call cost, which an
implementation could remove, and how much is the arithmetic that grows with the minibatch; and the
same step on our NumPy path (`quadpilot.train.ppo.numpy_ppo`, `PPOConfig.update = "numpy"`), measured in
the same run so that the JSON holds both and the NumPy entries carry the ratio.

The step is what both our PPO and SB3's do per minibatch: forward of actor (18 → 64 → 64 → 4, tanh)
and critic (18 → 64 → 64 → 1), Gaussian log-probability, clipped surrogate and value loss,
backward, global gradient-norm clip, Adam. One torch thread, as in the comparison runs; the NumPy
step runs its products on one OpenBLAS thread (`numpy_ppo.one_blas_thread`, as training does).

    .venv/bin/python -m pytest benchmarks/test_ppo_gradient_step.py --benchmark-enable --benchmark-only \
        --benchmark-json=FILE -p no:cacheprovider

`extra_info` carries the multiply-add count of the matrix products and the GFLOP/s they imply; the
NumPy entries also `speedup_vs_torch`, torch's fastest step over NumPy's at the same minibatch.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from quadpilot.train.networks import ActorCritic
from quadpilot.train.ppo.numpy_ppo import NumpyPPO, one_blas_thread

FASTEST: dict[tuple[str, int], float] = {}
"""(path, minibatch) → fastest step in seconds, for the ratio (torch's tests run first: file order)."""


def setup(minibatch: int):
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = ActorCritic(18, 4)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4, eps=1e-5)
    obs, act = torch.randn(minibatch, 18), torch.randn(minibatch, 4)
    adv, ret, old_logp = torch.randn(minibatch), torch.randn(minibatch), torch.randn(minibatch)
    return model, opt, obs, act, adv, ret, old_logp


def record(benchmark, path: str, minibatch: int) -> None:
    macs = minibatch * (2 * (18 * 64 + 64 * 64) + 64 * 4 + 64)  # actor and critic, forward
    benchmark.extra_info.update(path=path, minibatch=minibatch, forward_macs=macs)
    if benchmark.stats is not None:  # None without --benchmark-enable (a smoke run)
        seconds = benchmark.stats.stats.min
        benchmark.extra_info["gflops_matrix_products"] = 2 * 3 * macs / seconds / 1e9  # forward + 2× backward
        FASTEST[path, minibatch] = seconds
        if path == "numpy" and ("torch", minibatch) in FASTEST:
            benchmark.extra_info["speedup_vs_torch"] = FASTEST["torch", minibatch] / seconds


@pytest.mark.parametrize("minibatch", [64, 1024])
def test_gradient_step(benchmark, minibatch):
    model, opt, obs, act, adv, ret, old_logp = setup(minibatch)

    def step():
        ratio = (model.distribution(obs).log_prob(act).sum(-1) - old_logp).exp()
        pg = torch.max(-adv * ratio, -adv * ratio.clamp(0.8, 1.2)).mean()
        loss = pg + 0.25 * ((model.value(obs) - ret) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 0.5)
        opt.step()

    benchmark.pedantic(step, rounds=300, iterations=1, warmup_rounds=30)
    record(benchmark, "torch", minibatch)


@pytest.mark.parametrize("minibatch", [64, 1024])
def test_gradient_step_numpy(benchmark, minibatch):
    """The same loss (clip 0.2, ½·vf_coef 0.5 on ½·MSE = 0.25·MSE, no entropy, no advantage
    normalisation), clip 0.5 and Adam, by `NumpyPPO` on the same network and optimiser."""
    model, opt, *data = setup(minibatch)
    obs, act, adv, ret, old_logp = (np.ascontiguousarray(t.numpy()) for t in data)
    fast = NumpyPPO(model, opt)
    cfg = SimpleNamespace(clip_eps=0.2, clip_value=False, vf_coef=0.5, ent_coef=0.0, normalize_adv=False)

    def step():
        with one_blas_thread():
            fast.loss_and_grad(obs, act, old_logp, adv, ret, ret, cfg)
            fast.clip_and_adam(0.5)

    benchmark.pedantic(step, rounds=300, iterations=1, warmup_rounds=30)
    record(benchmark, "numpy", minibatch)

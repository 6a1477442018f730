"""PPO's minibatch step for the feed-forward actor-critic (`networks.ActorCritic`), written out in
NumPy: the forward pass, the backward of exactly the loss `ppo.PPO.update` computes, the global
gradient-norm clip and Adam, and the forward passes of the rollout (`PPO.collect`). It exists for
speed: a torch step of the hover networks is mostly fixed cost per operation (autograd's graph, the
dispatcher, the distribution objects), which a handful of preallocated NumPy calls do not pay.
torch stays the reference: tests/train/test_numpy_ppo.py checks every gradient against autograd and a
whole step against `torch.nn.utils.clip_grad_norm_` and `torch.optim.Adam`.

Memory is torch's. The parameters are moved, once, onto one flat float32 tensor (each `Parameter`
keeps its identity and shape, its `.data` a view of that tensor), and Adam's moments and step counts
live in flat tensors whose views are the optimiser's own state entries (`opt.state[p]["exp_avg"]`,
`"exp_avg_sq"`, `"step"`): a checkpoint holds what torch's path would write, and a state loaded by
`opt.load_state_dict` is taken over at the next update (`attach`), so a run resumes on either path.

The loss of a minibatch of B transitions, as `PPO.update` (PPO paper, arXiv:1707.06347, eq. 7 and 9):
    log π(a|s) = Σ_j −(a_j − μ_j)²/(2σ_j²) − log σ_j − log √(2π),   σ = exp(log_std)
    r = exp(log π − log π_old),   Â per-minibatch normalised with the unbiased std (torch's default)
    L = −mean(min(r·Â, clip(r, 1 − ε, 1 + ε)·Â)) + c1·L^VF − c2·mean(Σ_j ½ + ½·log 2π + log σ_j)
and its gradient by hand, with torch's tie rules (derivatives.yaml: `maximum` and `minimum` split
the gradient half and half where both arguments are equal; `clamp` passes it where min ≤ x ≤ max;
`threshold_backward` zeroes it where the ReLU's output is ≤ 0).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from threadpoolctl import ThreadpoolController
from torch import nn

from ..networks import ActorCritic

ACTIVATION_NAMES = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu"}
LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))  # as torch.distributions.Normal.log_prob writes it
ENTROPY_CONST = 0.5 + 0.5 * math.log(2 * math.pi)  # as torch.distributions.Normal.entropy writes it
F32 = np.float32
MAX_CACHED_SIZES = 8
"""Batch sizes whose buffers a network keeps, the least recently used dropped first (the minibatch,
the rollout's drones, the latest sizes of the truncated drones a rollout bootstraps)."""


@functools.cache
def _blas() -> ThreadpoolController:
    """The BLAS libraries this process has loaded (threadpoolctl finds them; built once)."""
    return ThreadpoolController()


def one_blas_thread():
    """The BLAS numpy uses, on one thread inside the block. The products here are small (a
    1024 × 64 by 64 × 64 product is ~0.1 ms): measured on this project's 2-core machine, a step took
    1.3 ms on one thread and 2.2-17 ms on two, whose hand-offs cost more than they share. Entering
    costs ~8 µs."""
    return _blas().limit(limits=1, user_api="blas")


@dataclass
class Layer:
    """One nn.Linear as NumPy views: weight (out, in) and bias of the flat parameters, and their
    gradients in the flat gradient."""

    w: np.ndarray
    b: np.ndarray
    gw: np.ndarray
    gb: np.ndarray


class Net:
    """An `networks.mlp` (Linear, activation, …, Linear) as Layers, with the forward and backward
    passes over buffers preallocated per batch size."""

    def __init__(self, seq: nn.Sequential, view, gview) -> None:
        self.layers: list[Layer] = []
        kinds = set()
        for k, m in enumerate(seq):
            if k % 2 == 0 and isinstance(m, nn.Linear):
                self.layers.append(Layer(view(m.weight), view(m.bias), gview(m.weight), gview(m.bias)))
            elif k % 2 == 1 and type(m) in ACTIVATION_NAMES and getattr(m, "alpha", 1.0) == 1.0:
                kinds.add(ACTIVATION_NAMES[type(m)])
            else:
                raise ValueError(
                    f"the NumPy update knows Linear layers with one Tanh, ReLU or ELU(alpha=1) between two; found {m}"
                )
        if len(kinds) > 1 or len(seq) % 2 == 0:
            raise ValueError(f"expected Linear layers with one kind of activation between each two; found {seq}")
        self.kind = kinds.pop() if kinds else "tanh"
        self.widths = [layer.w.shape[0] for layer in self.layers]
        self._bufs: dict[int, dict] = {}

    def buffers(self, n: int) -> dict:
        """Per batch size: the pre-activations/activations `a` of each layer (the output layer's is
        the output), ELU's expm1 part `e`, the back-propagated gradient `d` of each hidden layer and a
        scratch array `t`."""
        if n in self._bufs:
            self._bufs[n] = self._bufs.pop(n)  # the most recently used last
        else:
            if len(self._bufs) >= MAX_CACHED_SIZES:  # the rollout's truncated subsets come in many sizes
                del self._bufs[next(iter(self._bufs))]
            hidden = self.widths[:-1]
            self._bufs[n] = {
                "a": [np.empty((n, w), F32) for w in self.widths],
                "e": [np.empty((n, w), F32) for w in hidden] if self.kind == "elu" else [],
                "d": [np.empty((n, w), F32) for w in hidden],
                "t": np.empty((n, max(hidden, default=1)), F32),
                "mask": np.empty((n, max(hidden, default=1)), bool),
            }
        return self._bufs[n]

    def forward(self, x: np.ndarray, buf: dict) -> np.ndarray:
        """x (n, in) → output (n, out), a view of `buf` (overwritten by the next call with the same n)."""
        a = x
        last = len(self.layers) - 1
        for k, layer in enumerate(self.layers):
            z = buf["a"][k]
            np.matmul(a, layer.w.T, out=z)
            z += layer.b
            if k < last:
                if self.kind == "tanh":
                    np.tanh(z, out=z)
                elif self.kind == "relu":
                    np.maximum(z, F32(0), out=z)
                else:  # ELU(α = 1): max(z, 0) + expm1(min(z, 0)); its derivative is then expm1(min(z, 0)) + 1
                    e = buf["e"][k]
                    np.minimum(z, F32(0), out=e)
                    np.expm1(e, out=e)
                    np.maximum(z, F32(0), out=z)
                    z += e
            a = z
        return a

    def backward(self, x: np.ndarray, buf: dict, dout: np.ndarray, ones: np.ndarray) -> None:
        """Gradients of every weight and bias into the Layers' gradient views, from dout = ∂L/∂output
        (n, out) and the activations `forward` left in `buf`. `ones` is (n,) of ones: a bias gradient
        is the column sum, done as a matrix-vector product."""
        d = dout
        for k in range(len(self.layers) - 1, -1, -1):
            layer = self.layers[k]
            a_prev = x if k == 0 else buf["a"][k - 1]
            np.matmul(d.T, a_prev, out=layer.gw)
            np.matmul(ones, d, out=layer.gb)
            if k == 0:
                break
            da = buf["d"][k - 1]
            # np.dot: for one output column (the critic's), matmul's outer product skips BLAS (~7x slower)
            (np.dot if d.shape[1] == 1 else np.matmul)(d, layer.w, out=da)
            a = buf["a"][k - 1]
            w = a.shape[1]
            if self.kind == "tanh":  # tanh' = 1 − tanh²
                t = buf["t"][:, :w]
                np.multiply(a, a, out=t)
                np.subtract(F32(1), t, out=t)
                da *= t
            elif self.kind == "relu":  # threshold_backward: 0 where the output is ≤ 0
                mask = buf["mask"][:, :w]
                np.less_equal(a, F32(0), out=mask)
                np.copyto(da, F32(0), where=mask)
            else:
                t = buf["t"][:, :w]
                np.add(buf["e"][k - 1], F32(1), out=t)
                da *= t
            d = da


class NumpyPPO:
    """The NumPy path of `PPO` for an `ActorCritic` and its `torch.optim.Adam` (one parameter group,
    no weight decay, amsgrad or maximize: what `PPO` builds). Construction moves the parameters onto
    flat memory (values unchanged); `attach` before each update; `minibatch_step` per minibatch."""

    def __init__(self, model: ActorCritic, opt: torch.optim.Optimizer) -> None:
        if not isinstance(model, ActorCritic):
            raise ValueError(f"the NumPy update is for the feed-forward ActorCritic, got {type(model).__name__}")
        params = list(model.parameters())
        group = opt.param_groups[0] if len(opt.param_groups) == 1 else {}
        if (
            not isinstance(opt, torch.optim.Adam)
            or [id(p) for p in group.get("params", [])] != [id(p) for p in params]
            or group["weight_decay"] != 0
            or group["amsgrad"]
            or group["maximize"]
        ):
            raise ValueError("the NumPy update implements plain Adam over all the model's parameters in one group")
        if any(p.dtype != torch.float32 for p in params):
            raise ValueError("the NumPy update works in float32")
        self.model, self.opt, self.params = model, opt, params
        self.sizes = [p.numel() for p in params]
        self.offsets = np.cumsum([0, *self.sizes]).tolist()
        total = self.offsets[-1]
        self._flat_t = torch.empty(total)
        starts = self.offsets[:-1]
        self._param_t = [self._flat_t[o : o + p.numel()].view(p.shape) for p, o in zip(params, starts, strict=True)]
        self.flat = self._flat_t.numpy()
        self.grad = np.zeros(total, F32)
        self._m_t, self._v_t, self._steps_t = torch.zeros(total), torch.zeros(total), torch.zeros(len(params))
        self.m, self.v, self.steps = self._m_t.numpy(), self._v_t.numpy(), self._steps_t.numpy()
        self._installed = [False] * len(params)
        self._bind_params()
        index = {id(p): i for i, p in enumerate(params)}

        def view(p: torch.Tensor) -> np.ndarray:
            i = index[id(p)]
            return self.flat[self.offsets[i] : self.offsets[i + 1]].reshape(p.shape)

        def gview(p: torch.Tensor) -> np.ndarray:
            i = index[id(p)]
            return self.grad[self.offsets[i] : self.offsets[i + 1]].reshape(p.shape)

        self.actor = Net(model.actor, view, gview)
        self.critic = Net(model.critic, view, gview)
        self.log_std, self.g_log_std = view(model.log_std), gview(model.log_std)
        self.act_dim = self.log_std.shape[0]
        self._ones: dict[int, np.ndarray] = {}
        self._loss_bufs: dict[int, dict] = {}
        self._scratch, self._scratch2 = np.empty(total, F32), np.empty(total, F32)
        self._rows: dict[int, np.ndarray] = {}

    # --- torch's memory ----------------------------------------------------------------------
    def _bind_params(self) -> None:
        """Each parameter's data onto its slice of the flat tensor (copying its current values)."""
        with torch.no_grad():
            for p, t in zip(self.params, self._param_t, strict=True):
                if p.data_ptr() != t.data_ptr():
                    t.copy_(p)
                    p.data = t

    def attach(self) -> None:
        """Before an update: the parameters still on the flat memory (a `p.data = …` elsewhere is
        taken over), and Adam's state, if the optimiser holds one that is not ours (a fresh
        optimiser has none; `load_state_dict` makes new tensors), copied into the flat moments."""
        self._bind_params()
        for i, p in enumerate(self.params):
            s = self.opt.state.get(p)
            lo, hi = self.offsets[i], self.offsets[i + 1]
            if not s:  # torch creates the state at the parameter's first step: so do we
                self.m[lo:hi] = 0.0
                self.v[lo:hi] = 0.0
                self.steps[i] = 0.0
                self._installed[i] = False
            elif s["exp_avg"].data_ptr() != self._m_t[lo].data_ptr():
                self.m[lo:hi] = s["exp_avg"].detach().reshape(-1).numpy()
                self.v[lo:hi] = s["exp_avg_sq"].detach().reshape(-1).numpy()
                self.steps[i] = float(s["step"])
                self._install(i)

    def _install(self, i: int) -> None:
        p, lo, hi = self.params[i], self.offsets[i], self.offsets[i + 1]
        self.opt.state[p] = {
            "step": self._steps_t[i],
            "exp_avg": self._m_t[lo:hi].view(p.shape),
            "exp_avg_sq": self._v_t[lo:hi].view(p.shape),
        }
        self._installed[i] = True

    # --- the rollout's forward passes -----------------------------------------------------------
    def actor_mean(self, obs: np.ndarray) -> np.ndarray:
        """Gaussian means (n, act_dim) of float32 observations (n, in); reused by the next call."""
        with one_blas_thread():
            return self.actor.forward(obs, self.actor.buffers(obs.shape[0]))

    def value(self, obs: np.ndarray) -> np.ndarray:
        """V (n,) of float32 observations (n, in); reused by the next call."""
        with one_blas_thread():
            return self.critic.forward(obs, self.critic.buffers(obs.shape[0]))[:, 0]

    # --- the minibatch -------------------------------------------------------------------------
    def _ones_of(self, n: int) -> np.ndarray:
        if n not in self._ones:
            self._ones[n] = np.ones(n, F32)
        return self._ones[n]

    def _lbuf(self, n: int) -> dict:
        if n not in self._loss_bufs:
            a = self.act_dim
            self._loss_bufs[n] = {
                **{k: np.empty((n, a), F32) for k in ("diff", "q", "dmu")},
                **{k: np.empty(n, F32) for k in ("logp", "lr", "r", "adv", "x", "y", "k", "dlogp", "v1", "v2", "dv")},
                **{k: np.empty(n, bool) for k in ("b1", "b2")},
            }
        return self._loss_bufs[n]

    def loss_and_grad(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        old_logp: np.ndarray,
        adv: np.ndarray,
        ret: np.ndarray,
        old_v: np.ndarray,
        cfg,
    ) -> tuple[float, float, float, float, float, float] | None:
        """The loss of one minibatch (float32 arrays, B rows) under `cfg` (a PPOConfig: clip_eps,
        clip_value, vf_coef, ent_coef, normalize_adv) and its gradient in `self.grad`. Returns
        (loss, policy_loss, value_loss, entropy, approx_kl, clip_fraction), or None when the loss is
        not finite (the gradient is then not computed)."""
        n = obs.shape[0]
        lb = self._lbuf(n)
        ab, cb = self.actor.buffers(n), self.critic.buffers(n)
        mu = self.actor.forward(obs, ab)
        v = self.critic.forward(obs, cb)[:, 0]
        log_std = self.log_std
        std = np.exp(log_std)
        var = std * std
        log_scale = np.log(std)
        # log π(a|s), summed over the action dimensions
        diff, q = lb["diff"], lb["q"]
        np.subtract(act, mu, out=diff)
        np.multiply(diff, diff, out=q)
        q /= F32(2) * var  # (a − μ)²/(2σ²)
        logp = lb["logp"]
        np.sum(q, axis=1, out=logp)
        np.negative(logp, out=logp)
        logp -= F32(log_scale.sum() + F32(self.act_dim * LOG_SQRT_2PI))
        log_ratio, r = lb["lr"], lb["r"]
        np.subtract(logp, old_logp, out=log_ratio)
        np.exp(log_ratio, out=r)
        a = lb["adv"]
        if cfg.normalize_adv:  # (Â − mean)/(std + 1e-8), std with Bessel's correction as torch.std
            np.subtract(adv, adv.mean(dtype=F32), out=a)
            sd = np.sqrt(np.dot(a, a) / F32(n - 1)) if n > 1 else F32("nan")
            a /= sd + F32(1e-8)
        else:
            a[:] = adv
        # L^CLIP as a loss: −mean(min(r·Â, clip(r)·Â))
        eps = cfg.clip_eps
        x, y = lb["x"], lb["y"]
        np.multiply(a, r, out=x)
        np.clip(r, F32(1 - eps), F32(1 + eps), out=y)
        y *= a
        pg_loss = -np.minimum(x, y).mean(dtype=F32)
        # value loss
        v1, v2 = lb["v1"], lb["v2"]
        np.subtract(v, ret, out=v1)
        if cfg.clip_value:
            np.subtract(v, old_v, out=v2)
            inside_v = lb["b2"]
            np.less_equal(np.abs(v2), F32(eps), out=inside_v)  # clamp passes its gradient here
            np.clip(v2, F32(-eps), F32(eps), out=v2)
            v2 += old_v
            v2 -= ret
            sq1, sq2 = v1 * v1, v2 * v2
            v_loss = F32(0.5) * np.maximum(sq1, sq2).mean(dtype=F32)
        else:
            v_loss = F32(0.5) * np.dot(v1, v1) / F32(n)
        entropy = F32(np.sum(F32(ENTROPY_CONST) + log_scale, dtype=F32))
        loss = pg_loss + F32(cfg.vf_coef) * v_loss - F32(cfg.ent_coef) * entropy
        if not np.isfinite(loss):
            return None
        approx_kl = float(np.mean((r - F32(1)) - log_ratio, dtype=F32))
        clip_fraction = float(np.mean(np.abs(r - F32(1)) > F32(eps), dtype=F32))

        # ∂L/∂r: from −min(x, y); x wins where x < y, ties split half and half, and the clipped
        # branch passes the gradient only where 1 − ε ≤ r ≤ 1 + ε (then y == x, a tie: the halves sum to one).
        k, tie = lb["k"], lb["b1"]
        np.less(x, y, out=tie)
        k[:] = tie
        np.equal(x, y, out=tie)
        k += F32(0.5) * tie
        np.greater_equal(r, F32(1 - eps), out=tie)
        tie &= r <= F32(1 + eps)
        np.copyto(k, F32(1), where=tie)
        dlogp = lb["dlogp"]
        np.multiply(a, k, out=dlogp)
        dlogp *= r  # ∂r/∂log π = r
        dlogp *= F32(-1.0 / n)
        # ∂L/∂μ = ∂L/∂log π · (a − μ)/σ²; ∂L/∂log σ_j = Σ ∂L/∂log π · ((a − μ)²/σ² − 1) − c2
        dmu = lb["dmu"]
        np.divide(diff, var, out=dmu)
        dmu *= dlogp[:, None]
        np.matmul(dlogp, q, out=self.g_log_std)
        self.g_log_std *= F32(2)
        self.g_log_std -= dlogp.sum(dtype=F32) + F32(cfg.ent_coef)
        # ∂L/∂V
        dv = lb["dv"]
        if cfg.clip_value:  # from max(sq1, sq2): sq1 wins where larger, ties split
            gt = lb["b1"]
            np.greater(sq1, sq2, out=gt)
            k1 = gt.astype(F32)
            k2 = (sq1 < sq2).astype(F32)
            half = F32(0.5) * (sq1 == sq2)
            k1 += half
            k2 += half
            k2 *= inside_v
            np.multiply(k1, v1, out=dv)
            k2 *= v2
            dv += k2
        else:
            dv[:] = v1
        dv *= F32(cfg.vf_coef / n)
        ones = self._ones_of(n)
        self.actor.backward(obs, ab, dmu, ones)
        self.critic.backward(obs, cb, dv[:, None], ones)
        return float(loss), float(pg_loss), float(v_loss), float(entropy), approx_kl, clip_fraction

    def clip_and_adam(self, max_grad_norm: float) -> float | None:
        """Scale `self.grad` to global norm ≤ max_grad_norm as `torch.nn.utils.clip_grad_norm_`
        (coefficient max_norm/(norm + 1e-6), clamped at 1) and take one Adam step as
        `torch.optim.Adam` (its single-tensor CPU path) with the optimiser's lr, betas and eps.
        Returns the norm before clipping, or None (and no step) when it is not finite."""
        g = self.grad
        norm = np.sqrt(np.dot(g, g))  # float32, as torch's: a norm that overflows float32 is inf in both
        if not np.isfinite(norm):
            return None
        coef = F32(max_grad_norm) / (norm + F32(1e-6))
        if coef < 1:
            g *= coef
        self._adam()
        return float(norm)

    def _adam(self) -> None:
        group = self.opt.param_groups[0]
        lr, (beta1, beta2), eps = group["lr"], group["betas"], group["eps"]
        for i, done in enumerate(self._installed):
            if not done:
                self._install(i)
        self.steps += F32(1)
        g, m, v, t = self.grad, self.m, self.v, self._scratch
        # exp_avg.lerp_(grad, 1 − β1); exp_avg_sq.mul_(β2).addcmul_(grad, grad, value=1 − β2)
        np.subtract(g, m, out=t)
        t *= F32(1 - beta1)
        m += t
        v *= F32(beta2)
        np.multiply(g, F32(1 - beta2), out=t)
        t *= g
        v += t
        first = float(self.steps[0])
        if np.all(self.steps == first):
            step_size, bc2_sqrt = self._corrections(lr, beta1, beta2, first)
        else:  # parameters that joined at different steps (not in a run of ours; a hand-made state)
            per = [self._corrections(lr, beta1, beta2, float(s)) for s in self.steps]
            step_size = np.repeat(np.array([s for s, _ in per], F32), self.sizes)
            bc2_sqrt = np.repeat(np.array([b for _, b in per], F32), self.sizes)
        # denom = sqrt(exp_avg_sq)/sqrt(1 − β2^t) + eps; param += (−lr/(1 − β1^t))·exp_avg/denom
        np.sqrt(v, out=t)
        t /= bc2_sqrt
        t += F32(eps)
        upd = self._scratch2
        np.multiply(m, -step_size, out=upd)
        upd /= t
        self.flat += upd

    @staticmethod
    def _corrections(lr: float, beta1: float, beta2: float, step: float):
        """Adam's bias-corrected step size and √(1 − β2^t), in double as torch computes them."""
        return F32(lr / (1 - beta1**step)), F32((1 - beta2**step) ** 0.5)

    # --- PPO.update's minibatches ---------------------------------------------------------------
    def pack(self, batch: dict[str, torch.Tensor]) -> np.ndarray:
        """A rollout (obs, act, logp, adv, ret, val tensors) as one float32 array of rows, so a
        minibatch is one gather."""
        n = batch["obs"].shape[0]
        cols = [batch["obs"].reshape(n, -1), batch["act"].reshape(n, -1)]
        cols += [batch[k].reshape(n, 1) for k in ("logp", "adv", "ret", "val")]
        return torch.cat(cols, dim=1).numpy().astype(F32, copy=False)

    def minibatch_step(self, packed: np.ndarray, idx: np.ndarray, cfg) -> tuple | None:
        """One gradient step on rows `idx` of `pack`'s array: (policy_loss, value_loss, entropy,
        approx_kl, clip_fraction, grad_norm), or None when the loss or the gradient norm is not
        finite (nothing changed)."""
        n = idx.shape[0]
        rows = self._rows.get(n)
        if rows is None or rows.shape[1] != packed.shape[1]:
            rows = self._rows[n] = np.empty((n, packed.shape[1]), F32)
        np.take(packed, idx, axis=0, out=rows)
        d, a = rows.shape[1] - self.act_dim - 4, self.act_dim
        # overflow is found by the finiteness checks, as torch's path finds it
        with np.errstate(all="ignore"), one_blas_thread():
            out = self.loss_and_grad(rows[:, :d], rows[:, d : d + a], *(rows[:, d + a + j] for j in range(4)), cfg)
            if out is None:
                return None
            norm = self.clip_and_adam(cfg.max_grad_norm)
        if norm is None:
            return None
        return (*out[1:], norm)

"""The NumPy update (quadpilot.train.ppo.numpy_ppo) against torch, the reference: on random networks and
batches (several seeds and widths, a non-zero log-std, ratios inside and outside the clip range,
value clipping on and off, an entropy bonus, each activation) every gradient equals autograd's and a
whole step (gradient clip and Adam) leaves the parameters and Adam's state where torch's leaves
them, to float32 rounding (1e-5). Both paths run `PPO.update` itself, so the loss compared is the one
training uses. Then: the rollout's forward passes and noise, non-finite steps, determinism, resume,
a switch of path at a checkpoint, the checkpoint's format, and the configuration and flag."""

import dataclasses
import json
import math

import pytest
import torch

from quadpilot.train.algorithms import load_checkpoint
from quadpilot.train.cli import main
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.runs.checkpoint import LATEST

TOL = 1e-5
# per seed: network widths and observation history, so the check covers more than the default shape
SHAPES = {
    0: {},
    1: {"actor_hidden": (32, 16), "critic_hidden": (24,)},
    2: {"actor_hidden": (16,), "critic_hidden": (48, 48, 8), "obs_history": 2},
}


def make(update: str, **kw) -> PPO:
    base = dict(
        num_envs=2, rollout_steps=4, epochs=1, minibatch_size=96, lr_schedule="constant", ent_coef=0.01, threads=1
    )
    return PPO(PPOConfig(**{**base, **kw, "update": update}), make_config("hover", episode_steps=8))


def randomize(ppo: PPO, seed: int) -> None:
    """Random weights and biases (not the near-zero initial policy head) and a log-std away from 0."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in ppo.model.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)
        ppo.model.log_std.copy_(torch.rand(4, generator=g) - 1.2)


def random_batch(ppo: PPO, n: int, seed: int) -> dict[str, torch.Tensor]:
    """Observations and actions drawn around the policy; old log-probabilities so that the ratios
    spread over [0.6, 1.4] (ε = 0.2: inside and outside the clip); advantages of non-zero mean; old
    values within ±0.4 of V (value clip ε = 0.2: inside and outside)."""
    g = torch.Generator().manual_seed(1000 + seed)
    obs = torch.randn(n, ppo.obs_dim, generator=g)
    with torch.no_grad():
        dist, v = ppo.model.distribution(obs), ppo.model.value(obs)
        act = dist.mean + dist.stddev * torch.randn(n, 4, generator=g)
        logp = dist.log_prob(act).sum(-1)
    ratio = 0.6 + 0.8 * torch.rand(n, generator=g)
    return {
        "obs": obs,
        "act": act,
        "logp": logp - ratio.log(),
        "adv": torch.randn(n, generator=g) + 0.3,
        "ret": v + torch.randn(n, generator=g),
        "val": v + 0.4 * (2 * torch.rand(n, generator=g) - 1),
    }


def pair(seed: int, **kw) -> tuple[PPO, PPO, dict]:
    """The torch and the NumPy trainer with the same random network, the same RNG, and a batch."""
    kw = {**SHAPES[seed % 3], **kw}
    ref, fast = make("torch", seed=seed, **kw), make("numpy", seed=seed, **kw)
    randomize(ref, seed)
    randomize(fast, seed)
    fast.torch_gen.set_state(ref.torch_gen.get_state())
    return ref, fast, random_batch(ref, 96, seed)


def numpy_grads(ppo: PPO) -> list[torch.Tensor]:
    o, g = ppo._np.offsets, ppo._np.grad
    return [torch.from_numpy(g[o[k] : o[k + 1]].reshape(p.shape)) for k, p in enumerate(ppo.model.parameters())]


def max_diff(a, b) -> float:
    return max(float((x.detach() - y.detach()).abs().max()) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("clip_value", [False, True])
@pytest.mark.parametrize("activation", ["tanh", "relu", "elu"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_gradient_equals_autograds(seed, activation, clip_value):
    """One minibatch holding the whole batch, no gradient clip: after `update`, torch's p.grad and
    the NumPy gradient are both the gradient of the loss at the weights before the step."""
    ref, fast, batch = pair(seed, activation=activation, clip_value=clip_value, max_grad_norm=1e9)
    with torch.no_grad():
        ratio = (ref.model.distribution(batch["obs"]).log_prob(batch["act"]).sum(-1) - batch["logp"]).exp()
        dv = (ref.model.value(batch["obs"]) - batch["val"]).abs()
    assert ((ratio - 1).abs() > 0.2).any() and ((ratio - 1).abs() < 0.2).any()  # clipped and not
    assert (dv > 0.2).any() and (dv < 0.2).any()  # the value clip acts on some rows
    m_ref, m_fast = ref.update(batch), fast.update(batch)
    grads = [p.grad for p in ref.model.parameters()]
    assert all(float(g.abs().max()) > 1e-4 for g in grads)  # every parameter gets a gradient worth checking
    assert max_diff(grads, numpy_grads(fast)) <= TOL
    for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "explained_variance"):
        assert m_fast[k] == pytest.approx(m_ref[k], abs=TOL), k
    assert m_fast["grad_norm"] == pytest.approx(m_ref["grad_norm"], rel=1e-5)


@pytest.mark.parametrize("normalize_adv", [True, False])
@pytest.mark.parametrize("activation", ["tanh", "relu", "elu"])
def test_a_whole_update_leaves_parameters_and_adam_state_where_torchs_does(activation, normalize_adv):
    """Two epochs of two minibatches with the gradient clip acting (max_grad_norm 0.5, norms of several):
    four clipped Adam steps; parameters, exp_avg, exp_avg_sq and step as torch's. Then a second update
    at a lower (scheduled) learning rate continues from the state both hold."""
    ref, fast, batch = pair(0, activation=activation, normalize_adv=normalize_adv, epochs=2, minibatch_size=48)
    ref_cfg = dataclasses.replace(ref.cfg, lr_schedule="linear", total_steps=64)
    ref.cfg, fast.cfg = ref_cfg, dataclasses.replace(ref_cfg, update="numpy")
    for _ in range(2):
        m_ref, m_fast = ref.update(batch), fast.update(batch)
        assert m_ref["grad_norm"] > 1.0  # the clip scaled the gradients
        assert max_diff(ref.model.parameters(), fast.model.parameters()) <= TOL
        for p, q in zip(ref.model.parameters(), fast.model.parameters(), strict=True):
            s, t = ref.opt.state[p], fast.opt.state[q]
            assert float(s["step"]) == float(t["step"]) == 4 * ref.updates
            assert max_diff([s["exp_avg"], s["exp_avg_sq"]], [t["exp_avg"], t["exp_avg_sq"]]) <= TOL
        assert m_fast["lr"] == m_ref["lr"] and m_fast["policy_loss"] == pytest.approx(m_ref["policy_loss"], abs=TOL)
    assert m_ref["lr"] < ref.cfg.lr


def test_adam_state_with_unequal_step_counts_is_stepped_as_torch_steps_it():
    """A hand-made optimiser state whose parameters joined at different steps: each bias correction
    uses that parameter's own count."""
    ref, fast, batch = pair(1)
    for ppo in (ref, fast):
        for k, p in enumerate(ppo.model.parameters()):
            g = torch.Generator().manual_seed(k)
            ppo.opt.state[p] = {
                "step": torch.tensor(float(k + 1)),
                "exp_avg": torch.randn(p.shape, generator=g) * 0.01,
                "exp_avg_sq": torch.rand(p.shape, generator=g) * 1e-4,
            }
    ref.update(batch)
    fast.update(batch)
    assert max_diff(ref.model.parameters(), fast.model.parameters()) <= TOL


def test_the_rollout_draws_the_same_noise_and_computes_the_same_log_probs_and_values():
    """`collect` on both paths from the same seed: the exploration noise comes from torch_gen on both,
    so actions, log-probabilities and values agree to rounding, and torch_gen ends in the same state."""
    ref, fast = make("torch", seed=4), make("numpy", seed=4)
    a, b = ref.collect(), fast.collect()
    for k in ("act", "logp", "val", "obs"):
        assert float((a[k] - b[k]).abs().max()) <= 1e-4, k
    assert torch.equal(ref.torch_gen.get_state(), fast.torch_gen.get_state())


@pytest.mark.parametrize("update", ["torch", "numpy"])
def test_non_finite_steps_are_skipped_and_counted_as_on_torchs_path(update):
    """A loss that overflows (old log π = −1e30 makes r infinite), a gradient norm that overflows
    float32 (advantages of 1e20, no normalisation) and NaN returns: the same counts on both paths,
    the weights untouched."""
    ppo = make(update, minibatch_size=3, normalize_adv=False)
    before = [p.detach().clone() for p in ppo.model.parameters()]
    b = random_batch(ppo, 6, 0)
    inf_loss = {**b, "logp": torch.full((6,), -1e30), "adv": torch.full((6,), -1.0)}
    assert ppo.update(inf_loss)["nonfinite_skipped"] == 2
    assert ppo.update({**b, "adv": torch.full((6,), 1e20)})["nonfinite_skipped"] == 2
    m = ppo.update({**b, "ret": torch.full((6,), float("nan"))})
    assert m["nonfinite_skipped"] == 6 and math.isnan(m["policy_loss"])
    assert max_diff(before, ppo.model.parameters()) == 0.0


def test_the_numpy_path_is_deterministic():
    def run() -> list[torch.Tensor]:
        ppo = make("numpy", seed=7, num_envs=8, rollout_steps=16, minibatch_size=32, epochs=2)
        for _ in range(2):
            ppo.iterate()
        return [p.detach().clone() for p in ppo.model.parameters()]

    a, b = run(), run()
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


# a constant learning rate: a linear one follows total_steps (so a run extended by --resume would anneal
# differently from a straight one, and an update past total_steps would not move)
TINY = [
    *("--task", "hover", "--num-envs", "8", "--rollout-steps", "16", "--minibatch-size", "32", "--lr-schedule"),
    *("constant", "--threads", "1", "--eval-episodes", "0", "--eval-every", "0", "--update", "numpy"),
]
STEPS_PER_UPDATE = PPOConfig().epochs * 128 // 32  # Adam steps: K epochs of 8 × 16 transitions in minibatches of 32


def test_a_resumed_numpy_run_ends_exactly_like_a_straight_one_and_saves_torchs_format(tmp_path):
    """A run extended by --resume from 2 to 4 updates ends bit for bit where a straight 4-update run
    does; the optimiser state it saves has torch's entries, each tensor on its own storage as
    torch.optim.Adam's are."""
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert main([*TINY, "--total-steps", "512", "--out", str(straight)]) == 0
    assert main([*TINY, "--total-steps", "256", "--out", str(resumed)]) == 0
    assert main([*TINY, "--total-steps", "512", "--out", str(resumed), "--resume"]) == 0
    a, b = load_checkpoint(straight / LATEST), load_checkpoint(resumed / LATEST)
    assert a["updates"] == b["updates"] == 4
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    for i, s in a["optimizer"]["state"].items():
        assert set(s) == {"step", "exp_avg", "exp_avg_sq"} and float(s["step"]) == 4 * STEPS_PER_UPDATE
        for k, v in s.items():
            assert torch.equal(v, b["optimizer"]["state"][i][k])
            assert v.dtype == torch.float32 and v.untyped_storage().nbytes() == 4 * v.numel()  # its own storage
    assert json.loads((straight / "config.json").read_text())["ppo"]["update"] == "numpy"


@pytest.mark.parametrize(("saved_by", "continued_by"), [("torch", "numpy"), ("numpy", "torch")])
def test_a_checkpoint_continues_on_the_other_path(tmp_path, saved_by, continued_by):
    """A run saved by one path, continued on each: the same rollout, then the update on both paths
    (the one continued on the other path takes over the saved Adam state) lands within rounding."""
    out = tmp_path / "run"
    argv = [*TINY[:-1], saved_by, "--total-steps", "256", "--out", str(out)]
    assert main(argv) == 0
    same = PPO.from_checkpoint(load_checkpoint(out / LATEST))
    # a checkpoint of its own: torch.optim.Adam.load_state_dict keeps the file's tensors as its state
    other = PPO.from_checkpoint(load_checkpoint(out / LATEST), cfg=dataclasses.replace(same.cfg, update=continued_by))
    assert (same.cfg.update, other.cfg.update) == (saved_by, continued_by)
    batch = same.collect()
    other.torch_gen.set_state(same.torch_gen.get_state())
    assert same.update(batch)["lr"] == other.update(batch)["lr"] > 0
    assert max_diff(same.model.parameters(), other.model.parameters()) <= TOL
    for p, q in zip(same.model.parameters(), other.model.parameters(), strict=True):
        assert float(same.opt.state[p]["step"]) == float(other.opt.state[q]["step"]) == 3 * STEPS_PER_UPDATE


def test_the_configuration_resolves_auto_and_old_files_read_as_torch():
    assert PPOConfig().update == "numpy" and PPOConfig(arch="lstm").update == "torch"
    stored = PPOConfig(update="numpy").to_json()
    assert stored["update"] == "numpy" and PPOConfig.from_json(stored).update == "numpy"
    del stored["update"]  # a configuration saved before the field existed
    assert PPOConfig.from_json(stored).update == "torch"
    with pytest.raises(ValueError, match="update 'numpy' is for arch 'mlp' only"):
        PPOConfig(arch="lstm", update="numpy")
    with pytest.raises(ValueError, match="update must be one of auto, numpy, torch; got 'jax'"):
        PPOConfig(update="jax")


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--algo", "sac"], "--update: options of our PPO (--algo ppo), not of --algo sac"),
        (["--algo", "sb3"], "--update: options of our PPO (--algo ppo), not of --algo sb3"),
        (["--arch", "lstm"], "PPO configuration: update 'numpy' is for arch 'mlp' only"),
    ],
)
def test_the_update_flag_is_refused_where_it_has_no_meaning_in_one_line(tmp_path, capsys, flags, says):
    assert main([*TINY, "--total-steps", "256", *flags, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1


def test_a_resume_keeps_the_update_path(tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*TINY, "--total-steps", "256", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main([*TINY[:-1], "torch", "--total-steps", "512", "--resume", "--out", str(out)]) == 2
    assert "--update torch (checkpoint: numpy)" in capsys.readouterr().err


def test_a_network_numpy_does_not_implement_is_refused():
    ppo = make("torch")
    ppo.model.actor[1] = torch.nn.Sigmoid()
    from quadpilot.train.ppo.numpy_ppo import NumpyPPO

    with pytest.raises(ValueError, match="Linear layers with one Tanh, ReLU or ELU"):
        NumpyPPO(ppo.model, ppo.opt)


# --- edges of the update and what it refuses ---------------------------------------------------


def numpy_arrays(fast: PPO, batch: dict) -> tuple:
    return tuple(batch[k].numpy().astype("float32") for k in ("obs", "act", "logp", "adv", "ret", "val"))


@pytest.mark.parametrize("clip_value", [False, True])
def test_the_total_loss_is_the_one_torchs_update_minimises(clip_value):
    """loss_and_grad's loss (the number its finite-check guards) is L_policy + c_v·L_value − c_e·H."""
    ref, fast, batch = pair(1, clip_value=clip_value, max_grad_norm=1e9)
    cfg = fast.cfg
    fast._np.attach()
    loss = fast._np.loss_and_grad(*numpy_arrays(fast, batch), cfg)[0]
    m = ref.update(batch)
    want = m["policy_loss"] + cfg.vf_coef * m["value_loss"] - cfg.ent_coef * m["entropy"]
    assert loss == pytest.approx(want, abs=TOL)


@pytest.mark.parametrize("clip_value", [False, True])
def test_the_first_minibatch_of_an_update_ties_as_torch_does(clip_value):
    """On fresh rollouts every ratio is exactly 1 and every clipped value exactly V: min(r·Â, clip(r)·Â)
    and max of the two value losses tie on every row, and torch gives each side half the gradient."""
    ref, fast, batch = pair(0, clip_value=clip_value, max_grad_norm=1e9)
    with torch.no_grad():
        batch["logp"] = ref.model.distribution(batch["obs"]).log_prob(batch["act"]).sum(-1)
        batch["val"] = ref.model.value(batch["obs"])
    m_ref = ref.update(batch)
    fast.update(batch)
    assert m_ref["clip_fraction"] == 0.0
    assert max_diff([p.grad for p in ref.model.parameters()], numpy_grads(fast)) <= TOL


def test_a_gradient_under_the_norm_limit_is_not_scaled():
    """clip_grad_norm_ leaves a gradient whose norm is below max_grad_norm as it is (coefficient
    clamped at 1): with the limit 1.5 times the norm, the step is torch's."""
    ref, fast, batch = pair(2, max_grad_norm=1e9)
    norm = ref.update(batch)["grad_norm"]
    ref, fast, batch = pair(2, max_grad_norm=1.5 * norm)
    ref.update(batch), fast.update(batch)
    assert max_diff(list(ref.model.parameters()), list(fast.model.parameters())) <= TOL


def test_a_minibatch_of_two_normalises_its_advantages_as_torch():
    ref, fast, batch = pair(0, minibatch_size=2, max_grad_norm=1e9, normalize_adv=True)
    small = {k: v[:2] for k, v in batch.items()}
    ref.update(small), fast.update(small)
    assert max_diff([p.grad for p in ref.model.parameters()], numpy_grads(fast)) <= TOL


@pytest.mark.parametrize("activation", ["tanh", "elu"])
def test_the_numpy_update_works_in_float32_throughout(activation):
    """Every array the update keeps (parameters, gradients, Adam's state, layer and loss buffers, the
    packed batch) is float32, as the torch model it stands for: a float64 buffer would change the
    bits of every step and double the memory, and no comparison within float32 rounding would see it."""
    import numpy as np

    _, fast, batch = pair(1, max_grad_norm=0.5, activation=activation)
    fast.update(batch)
    np_ppo = fast._np
    arrays = [v for v in vars(np_ppo).values() if isinstance(v, np.ndarray)]
    for holder in (np_ppo._loss_bufs, np_ppo._ones, np_ppo._rows, np_ppo.actor._bufs, np_ppo.critic._bufs):
        stack = list(holder.values())
        while stack:
            v = stack.pop()
            if isinstance(v, dict):
                stack += list(v.values())
            elif isinstance(v, list):
                stack += v
            elif isinstance(v, np.ndarray):
                arrays.append(v)
    arrays.append(np_ppo.pack(batch))
    assert len(arrays) > 20
    assert {a.dtype.name for a in arrays} <= {"float32", "bool"}, {a.dtype.name for a in arrays}


@pytest.mark.parametrize(
    "change, says",
    [
        (dict(amsgrad=True), "plain Adam over all the model's parameters in one group"),
        (dict(maximize=True), "plain Adam over all the model's parameters in one group"),
        (dict(weight_decay=0.01), "plain Adam over all the model's parameters in one group"),
    ],
)
def test_an_optimiser_other_than_plain_adam_is_refused(change, says):
    from quadpilot.train.ppo.numpy_ppo import NumpyPPO

    ppo = make("torch")
    opt = torch.optim.Adam(ppo.model.parameters(), lr=1e-3, **change)
    with pytest.raises(ValueError, match=says):
        NumpyPPO(ppo.model, opt)


def test_adam_over_part_of_the_model_or_sgd_or_float64_is_refused():
    from quadpilot.train.ppo.numpy_ppo import NumpyPPO

    ppo = make("torch")
    params = list(ppo.model.parameters())
    for opt in (torch.optim.Adam(params[:-1], lr=1e-3), torch.optim.SGD(params, lr=1e-3)):
        with pytest.raises(ValueError, match=r"^the NumPy update implements plain Adam over all"):
            NumpyPPO(ppo.model, opt)
    two_groups = torch.optim.Adam([{"params": params[:2]}, {"params": params[2:]}], lr=1e-3)
    with pytest.raises(ValueError, match=r"^the NumPy update implements plain Adam over all"):
        NumpyPPO(ppo.model, two_groups)
    ppo.model.double()
    with pytest.raises(ValueError, match=r"^the NumPy update works in float32$"):
        NumpyPPO(ppo.model, torch.optim.Adam(ppo.model.parameters(), lr=1e-3))
    with pytest.raises(ValueError, match=r"^the NumPy update is for the feed-forward ActorCritic, got Linear$"):
        NumpyPPO(torch.nn.Linear(2, 2), torch.optim.Adam(torch.nn.Linear(2, 2).parameters()))


@pytest.mark.parametrize(
    "edit, says",
    [
        (lambda a: a.__setitem__(1, torch.nn.ELU(alpha=0.5)), "ELU\\(alpha=1\\) between two; found ELU"),
        (lambda a: a.__setitem__(1, torch.nn.ReLU()), "one kind of activation between each two"),
        (lambda a: a.append(torch.nn.Tanh()), "one kind of activation between each two"),
        (lambda a: a.__setitem__(0, torch.nn.Tanh()), "Linear layers with one Tanh, ReLU or ELU"),
    ],
    ids=["elu-alpha", "two-kinds", "ends-in-activation", "no-linear-first"],
)
def test_a_network_the_numpy_update_cannot_run_is_refused_naming_it(edit, says):
    """ELU with alpha ≠ 1, two kinds of activation, an activation last, an activation where a Linear
    belongs: each refused with what was found."""
    from quadpilot.train.ppo.numpy_ppo import NumpyPPO

    ppo = make("torch", actor_hidden=(16, 16), activation="tanh")
    edit(ppo.model.actor)
    with pytest.raises(ValueError, match=says):
        NumpyPPO(ppo.model, torch.optim.Adam(ppo.model.parameters(), lr=1e-3))


def test_a_network_without_hidden_layers_runs():
    """One Linear, no activation: the kind defaults (and is not used); gradients are torch's."""
    ref, fast, batch = pair(0, actor_hidden=(), critic_hidden=(), max_grad_norm=1e9)
    ref.update(batch), fast.update(batch)
    assert fast._np.actor.kind == "tanh" and len(fast._np.actor.layers) == 1
    assert max_diff([p.grad for p in ref.model.parameters()], numpy_grads(fast)) <= TOL

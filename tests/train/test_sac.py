"""SAC: the maths against references (the tanh-squashed log-probability against a numerical
density, the Polyak update, the temperature's direction, the twin critics against two plain MLPs),
the replay buffer's truncation handling and ring, and `quad-train --algo sac` end to end: its files,
a bit-exact resume (replay buffer included), a torn checkpoint, clear refusals, and its policy.pt
exported by quad-export and flown by both runtime backends within the parity bar."""

import copy
import csv
import json
import math

import numpy as np
import pytest
import torch

from quadpilot.export.cli import main as export_main
from quadpilot.export.onnx_export import check_parity, export_onnx, reference_commands
from quadpilot.modelfile.model import read_model
from quadpilot.runtime.backends import load_policy as load_runtime_policy
from quadpilot.train.algorithms import load_checkpoint, load_policy
from quadpilot.train.cli import main
from quadpilot.train.envs import make_config
from quadpilot.train.runs.checkpoint import LATEST, PREVIOUS
from quadpilot.train.sac import (
    HEADER,
    REPLAY_DIR,
    SAC,
    ReplayBuffer,
    SACConfig,
    SquashedGaussianActor,
    TwinQ,
    polyak_update,
    squashed_log_prob,
    temperature_loss,
)

# 8 drones × 8 vector steps = 64 transitions per iteration; a 100-transition buffer wraps in the
# second iteration, so resume has to rebuild a wrapped ring from its chunks
TINY = ["--num-envs", "8", "--rollout-steps", "8", "--threads", "1", "--eval-episodes", "4"]
TINY_SET = [
    "--set",
    "learning_starts=16",
    "--set",
    "buffer_size=100",
    "--set",
    "minibatch_size=32",
    "--set",
    "updates_per_step=2",
]


def sac_run(out, *args):
    return main(["--algo", "sac", "--task", "hover", "--out", str(out), *TINY, *TINY_SET, *args])


def rows(out):
    with open(out / "metrics.csv", newline="") as f:
        return list(csv.DictReader(f))


# --- the maths ------------------------------------------------------------------------------


def test_squashed_log_prob_matches_a_numerical_density():
    """log π(a) of a = tanh(u), u ~ N(μ, σ²) per dimension: against the derivative of the CDF
    P(A ≤ a) = Φ((atanh a − μ)/σ), taken by central differences in float64."""
    g = torch.Generator().manual_seed(0)
    mean = torch.randn(64, 4, generator=g, dtype=torch.float64)
    log_std = torch.empty(64, 4, dtype=torch.float64).uniform_(-2.0, 0.5, generator=g)
    u = mean + log_std.exp() * torch.randn(64, 4, generator=g, dtype=torch.float64)
    a = torch.tanh(u).clamp(-1 + 1e-9, 1 - 1e-9)
    h = 1e-6 * (1 - a.abs()).clamp(min=1e-9)  # a step that stays inside (−1, 1)

    def cdf(x):
        return torch.special.ndtr((torch.atanh(x) - mean) / log_std.exp())

    density = (cdf(a + h) - cdf(a - h)) / (2 * h)
    reference = density.log().sum(-1)
    ok = (1 - a.abs() > 1e-6).all(-1)  # where float64 differences still resolve the density
    assert ok.sum() > 50
    got = squashed_log_prob(u, mean, log_std)
    torch.testing.assert_close(got[ok], reference[ok], rtol=1e-6, atol=1e-5)


def test_squashed_log_prob_stays_finite_where_one_minus_tanh_squared_underflows():
    u = torch.tensor([[-30.0, -12.0, 12.0, 30.0]])
    mean, log_std = torch.zeros(1, 4), torch.zeros(1, 4)
    naive = (-0.5 * u**2 - 0.5 * math.log(2 * math.pi) - torch.log(1 - torch.tanh(u) ** 2)).sum(-1)
    got = squashed_log_prob(u, mean, log_std)
    assert not torch.isfinite(naive).all() and torch.isfinite(got).all()
    # log(1 − tanh² u) → log 4 − 2|u| for large |u|
    expect = (-0.5 * u**2 - 0.5 * math.log(2 * math.pi) - (math.log(4) - 2 * u.abs())).sum(-1)
    torch.testing.assert_close(got, expect, rtol=1e-5, atol=1e-4)


def test_actor_sample_is_a_reparameterised_tanh_gaussian():
    torch.manual_seed(0)
    actor = SquashedGaussianActor(18, 4, (32, 32), "relu", init_log_std=-0.5)
    obs = torch.randn(256, 18)
    a, logp = actor.sample(obs, torch.Generator().manual_seed(1))
    assert a.shape == (256, 4) and logp.shape == (256,) and (a.abs() < 1).all()
    mean, log_std = actor(obs)
    torch.testing.assert_close(
        logp, squashed_log_prob(torch.atanh(a.double()).float(), mean, log_std), atol=2e-3, rtol=0
    )
    (-logp.mean()).backward()  # gradients reach the mean and log-σ heads through the sample
    assert actor.log_std_head.weight.grad.abs().sum() > 0 and actor.actor[-2].weight.grad.abs().sum() > 0
    torch.testing.assert_close(actor.mean_action(obs), torch.tanh(mean))  # the deterministic action


def test_polyak_update_averages_the_target_towards_the_source():
    torch.manual_seed(0)
    source, target = TwinQ(18, 4, (16,), "relu"), TwinQ(18, 4, (16,), "relu")
    start = [p.detach().clone() for p in target.parameters()]
    polyak_update(target, source, 0.1)
    for p0, pt, ps in zip(start, target.parameters(), source.parameters(), strict=True):
        torch.testing.assert_close(pt, 0.9 * p0 + 0.1 * ps)
    for _ in range(9):
        polyak_update(target, source, 0.1)
    for p0, pt, ps in zip(start, target.parameters(), source.parameters(), strict=True):
        torch.testing.assert_close(pt - ps, 0.9**10 * (p0 - ps), atol=1e-6, rtol=1e-5)
    polyak_update(target, source, 1.0)
    assert all(torch.equal(a, b) for a, b in zip(target.parameters(), source.parameters(), strict=True))


@pytest.mark.parametrize(("entropy", "alpha_moves"), [(-6.0, "up"), (-2.0, "down")])
def test_temperature_step_moves_alpha_towards_the_target_entropy(entropy, alpha_moves):
    """Target −|A| = −4: a policy less random than that (entropy −6) raises α, a more random one lowers it."""
    log_alpha = torch.tensor(math.log(0.2), requires_grad=True)
    opt = torch.optim.Adam([log_alpha], lr=1e-2)
    log_prob = torch.full((256,), -entropy)  # entropy = −E[log π]
    before = log_alpha.exp().item()
    opt.zero_grad()
    temperature_loss(log_alpha, log_prob, -4.0).backward()
    opt.step()
    after = log_alpha.exp().item()
    assert (after > before) if alpha_moves == "up" else (after < before)


def test_twin_critics_are_two_plain_mlps():
    torch.manual_seed(0)
    q = TwinQ(18, 4, (32, 16), "tanh")
    obs, act = torch.randn(10, 18), torch.rand(10, 4) * 2 - 1
    out = q(obs, act)
    assert out.shape == (2, 10)
    x0 = torch.cat([obs, act], -1)
    for j in range(2):
        x = x0
        for k, (w, b) in enumerate(zip(q.weights, q.biases, strict=True)):
            x = x @ w[j] + b[j, 0]
            x = torch.tanh(x) if k < len(q.weights) - 1 else x
        torch.testing.assert_close(out[j], x.squeeze(-1))
    assert not torch.allclose(out[0], out[1])  # independently initialised


def test_gradient_step_updates_critics_actor_temperature_and_targets():
    sac = SAC(
        SACConfig(num_envs=8, rollout_steps=4, learning_starts=0, minibatch_size=32, seed=3), make_config("hover")
    )
    sac.iterate()  # 32 transitions, 4 × 2 gradient steps
    target0 = [p.detach().clone() for p in sac.critic_target.parameters()]
    actor0 = [p.detach().clone() for p in sac.actor.parameters()]
    alpha0 = sac.alpha
    out = sac.gradient_step()
    assert set(out) == {"q_loss", "policy_loss", "alpha_loss", "entropy", "q_mean"}
    for p0, pt, pc in zip(target0, sac.critic_target.parameters(), sac.critic.parameters(), strict=True):
        torch.testing.assert_close(pt, 0.995 * p0 + 0.005 * pc)
    assert any(not torch.equal(a, b) for a, b in zip(actor0, sac.actor.parameters(), strict=True))
    assert sac.alpha != alpha0 and not any(p.grad is not None for p in sac.critic_target.parameters())


# --- replay buffer --------------------------------------------------------------------------


def test_replay_buffer_ring_and_rows_round_trip():
    buf = ReplayBuffer(10, 2, 1)
    for k in range(3):  # 12 transitions into 10 rows: the first 2 are overwritten
        n = 4
        i = np.arange(4 * k, 4 * k + n, dtype=np.float32)
        buf.add(np.stack([i, i], 1), i[:, None], i, np.stack([i + 0.5, i + 0.5], 1), np.zeros(n))
    assert buf.stored == 12 and len(buf) == 10
    torch.testing.assert_close(buf.rows(2, 12)[:, 0], torch.arange(2, 12, dtype=torch.float32))
    with pytest.raises(ValueError, match="not in the buffer"):
        buf.rows(1, 5)
    copy_ = ReplayBuffer(10, 2, 1)
    copy_.put_rows(2, buf.rows(2, 12))
    assert torch.equal(copy_.data, buf.data) and copy_.stored == 12
    s = buf.sample(64, torch.Generator().manual_seed(0))
    assert set(s) == {"obs", "act", "rew", "next_obs", "term"} and (s["obs"][:, 0] >= 2).all()
    torch.testing.assert_close(s["next_obs"], s["obs"] + 0.5)


def test_transitions_that_end_an_episode_store_the_final_observation():
    """s' of the last step of an episode is where the drone ended, not the next episode's start."""
    sac = SAC(
        SACConfig(num_envs=4, rollout_steps=6, learning_starts=10**6, seed=0), make_config("hover", episode_steps=5)
    )
    sac.iterate()
    d = sac.buffer.data[: sac.buffer.stored]
    s = sac.buffer.slices
    obs, nxt, term = d[:, s["obs"]].reshape(6, 4, -1), d[:, s["next_obs"]].reshape(6, 4, -1), d[:, s["term"]]
    assert not term.any()  # random actions for 5 steps: nobody crashes, all are truncated at step 5
    torch.testing.assert_close(nxt[:4], obs[1:5])  # within an episode s' is the next row's s
    assert (nxt[4] - obs[5]).abs().amax(-1).min() > 1e-3  # at the truncation it is not the reset state


# --- quad-train --algo sac ------------------------------------------------------------------


def test_a_sac_run_writes_every_file(tmp_path, capsys):
    out = tmp_path / "run"
    assert sac_run(out, "--total-steps", "192", "--eval-every", "2") == 0
    assert "done (sac), 192 steps in 3 iterations" in capsys.readouterr().out
    names = {p.name for p in out.iterdir()}
    assert {"config.json", "metrics.csv", LATEST, PREVIOUS, "policy.pt", "eval.json", "curves.png", REPLAY_DIR} <= names
    assert not [n for n in names if n.endswith(".tmp")]
    assert (out / "metrics.csv").read_text().splitlines()[0] == HEADER
    r = rows(out)
    assert [int(x["update"]) for x in r] == [1, 2, 3] and [int(x["global_step"]) for x in r] == [64, 128, 192]
    assert r[1]["eval_success_rate"] != "" and r[0]["eval_success_rate"] == ""
    assert (
        all(float(x["alpha"]) > 0 for x in r) and r[-1]["q_loss"] and int(r[-1]["grad_steps"]) == 2 * (24 - 1)
    )  # from the 2nd of 24 vector steps
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["algo"] == "sac" and cfg["sac"]["buffer_size"] == 100 and cfg["sac"]["num_envs"] == 8
    assert SACConfig.from_json(cfg["sac"]).learning_starts == 16 and cfg["command"].startswith("quad-train --algo sac")
    ev = json.loads((out / "eval.json").read_text())
    assert ev["algo"] == "sac" and ev["episodes"] == 4 and ev["updates"] == 3 and "time_breakdown_s" in ev
    # tensors and JSON-able data only: torch.load(weights_only=True) reads every file
    for f in (out / "policy.pt", out / LATEST, *(out / REPLAY_DIR).iterdir()):
        torch.load(f, weights_only=True)
    ckpt = load_checkpoint(out / "policy.pt")
    assert ckpt["algo"] == "sac" and set(ckpt["optimizer"]) == {"actor", "critic", "alpha"}
    assert ckpt["replay"]["stored"] == 192


def test_resume_continues_bit_for_bit_with_the_replay_buffer(tmp_path, capsys):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert sac_run(straight, "--total-steps", "256", "--eval-episodes", "0", "--eval-every", "0") == 0
    assert sac_run(resumed, "--total-steps", "128", "--eval-episodes", "0", "--eval-every", "0") == 0
    chunks = sorted(p.name for p in (resumed / REPLAY_DIR).iterdir())
    assert chunks == ["000000000000-000000000064.pt", "000000000064-000000000128.pt"]
    assert sac_run(resumed, "--total-steps", "256", "--eval-episodes", "0", "--eval-every", "0", "--resume") == 0
    assert "resuming" in capsys.readouterr().out
    a, b = load_checkpoint(straight / "policy.pt"), load_checkpoint(resumed / "policy.pt")
    for key in ("model", "critic", "critic_target"):
        assert all(torch.equal(a[key][k], b[key][k]) for k in a[key]), key
    assert torch.equal(a["log_alpha"], b["log_alpha"]) and a["grad_steps"] == b["grad_steps"]
    assert [r["q_loss"] for r in rows(straight)] == [r["q_loss"] for r in rows(resumed)]
    # a 100-transition buffer: chunks that no checkpoint needs any more are gone
    assert sorted(p.name for p in (resumed / REPLAY_DIR).iterdir())[0] != "000000000000-000000000064.pt"
    assert len(json.loads((resumed / "config.json").read_text())["resumes"]) == 1


def test_a_torn_checkpoint_resumes_from_the_previous_one(tmp_path, capsys):
    out = tmp_path / "run"
    assert sac_run(out, "--total-steps", "192", "--eval-episodes", "0", "--eval-every", "0") == 0
    (out / LATEST).write_bytes((out / LATEST).read_bytes()[:1000])
    assert sac_run(out, "--total-steps", "256", "--eval-episodes", "0", "--eval-every", "0", "--resume") == 0
    text = capsys.readouterr()
    assert "resuming the previous checkpoint" not in text.out and "checkpoint.prev.pt" in text.err
    assert "from checkpoint.prev.pt at iteration 2" in text.out
    assert [int(r["update"]) for r in rows(out)] == [1, 2, 3, 4]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algo", "sac", "--set", "nope=1"], "expected NAME=VALUE with NAME a SAC hyper-parameter"),
        (["--algo", "sac", "--set", "tau=lots"], "'lots' is not a valid float"),
        (["--algo", "sac", "--set", "tau=2"], "tau must be in (0, 1]"),
        (["--algo", "sac", "--preset", "fast"], "--preset chooses a PPO recipe"),
        (["--set", "tau=0.01"], "expected NAME=VALUE with NAME a PPO hyper-parameter"),  # PPO's, without --algo
    ],
)
def test_bad_sac_requests_exit_2_with_one_line(tmp_path, capsys, args, message):
    out = tmp_path / "fresh"
    assert main(["--task", "hover", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not out.exists()


def test_resume_keeps_the_sac_configuration_and_the_algorithm(tmp_path, capsys):
    out = tmp_path / "run"
    assert sac_run(out, "--total-steps", "64", "--eval-episodes", "0") == 0
    capsys.readouterr()
    assert sac_run(out, "--resume", "--set", "tau=0.01") == 2
    assert "tau 0.01 (checkpoint: 0.005)" in capsys.readouterr().err
    assert main(["--task", "hover", "--out", str(out), "--resume"]) == 2
    assert "holds a sac run; resume it with --algo sac" in capsys.readouterr().err


# --- export and runtime ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def sac_policy(tmp_path_factory):
    """A tiny SAC run's policy.pt with its mean head re-initialised with gain 1 (training's 0.01
    makes every pre-tanh output ≈ 0, where tanh ≈ identity): the outputs then reach beyond ±1, so a
    graph or backend that clipped instead of applying tanh would be caught. Motors 1 and 2 get a
    bias of −9 and −11: there 1 + tanh(z) ≈ 1e-8 cancels in float32 (motor almost off), where a
    runtime computing √(1 + tanh z) naively would be ~1e-4 off."""
    d = tmp_path_factory.mktemp("sac")
    assert sac_run(d / "run", "--total-steps", "128", "--eval-episodes", "0", "--eval-every", "0") == 0
    ckpt = load_checkpoint(d / "run" / "policy.pt")
    ckpt["model"] = copy.deepcopy(ckpt["model"])
    last = max(int(k.split(".")[1]) for k in ckpt["model"] if k.startswith("actor.") and k.endswith(".weight"))
    torch.manual_seed(0)
    torch.nn.init.orthogonal_(ckpt["model"][f"actor.{last}.weight"], 1.0)
    ckpt["model"][f"actor.{last}.bias"] += torch.tensor([0.2, -9.0, -11.0, 0.2])
    torch.save(ckpt, d / "policy.pt")
    return d / "policy.pt"


def test_quad_export_writes_the_deterministic_sac_action_and_both_backends_fly_it(sac_policy, tmp_path, capsys):
    out = tmp_path / "sac.onnx"
    assert export_main([str(sac_policy), "-o", str(out), "--parity-samples", "2000"]) == 0
    assert "parity within 1e-05: ok" in capsys.readouterr().out
    _, info = read_model(out)
    assert [layer["activation"] for layer in info.architecture["layers"]] == ["relu", "relu", "tanh"]
    policy = load_policy(sac_policy)
    obs = np.random.default_rng(0).normal(0, 1.5, (300, 18)).astype(np.float32)
    with torch.inference_mode():
        pre = policy.model(torch.from_numpy(obs))[0]
    assert (pre.abs() > 1.0).float().mean() > 0.2  # beyond ±1 tanh and a clip differ
    want = reference_commands(policy, obs)  # tanh(mean), then core's action-to-command map
    assert want[:, 1:3].max() < 1e-2 and (want[:, 1:3] < 1e-4).any()  # nearly off, where float32 cancels
    for backend in ("numpy", "onnxruntime"):
        rt = load_runtime_policy(out, backend)
        got = np.stack([rt.act(o) for o in obs])
        np.testing.assert_allclose(got, want, atol=1e-5, rtol=0, err_msg=backend)
    clipped = 0.5 * np.sqrt(1.0 + np.clip(pre.numpy(), -1, 1))  # what a missing tanh would give (u_hover ≈ 0.5)
    assert np.abs(want - clipped).max() > 0.05


def test_sac_parity_covers_every_path(sac_policy, tmp_path):
    out = tmp_path / "p.onnx"
    export_onnx(sac_policy, out)
    parity = check_parity(sac_policy, out, n=2000)
    assert {"torch_vs_runtime_numpy", "torch_vs_runtime_onnxruntime", "training_path_vs_torch"} <= set(parity)
    assert max(v for k, v in parity.items() if k != "observations") <= 1e-5, parity

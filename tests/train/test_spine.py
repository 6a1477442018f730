"""The one training spine: every algorithm runs through the same loop and writes one checkpoint
schema. Pinned against the code before it (quadpilot f6db119): checkpoints that code wrote resume
and continue to the very weights that code computed, and tiny PPO, recurrent PPO and SAC runs give
the weights they gave then. Then: SAC takes the environment options (randomisation, sensor noise,
motor lag) and snapshots as PPO does, and its checkpoint carries their state; --set sets PPO's
hyper-parameters too. (No import circle and no module over 600 lines: tests/test_architecture.py.)

The pinned weights are sha256 hashes of every tensor's bytes; `print_pins()` prints them for the
code in the working tree (`python tests/train/test_spine.py`). The LSTM's two pins (its resumed fixture and
its tiny run, both with randomised motor lag) were recomputed at quadpilot b446ba2: the motor lag's
thrust averaged along the lag (13cc0e7) changed the environment they train on, on purpose; before
that they were the weights of the code before the spine. The other pins are still those.

Float results can differ between CPU instruction sets and torch versions, and the environment's
between NumPy versions and SIMD targets (tests/train/test_env_bit_identity.py), so the hashes are
compared only where they were computed (the torch version and CPU capability, NumPy version and
SIMD target in data/pre_spine/expected.json); elsewhere those checks skip, and what remains is that
the files load and training continues."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from quadpilot.train.algorithms import load_checkpoint, load_policy, load_trainer
from quadpilot.train.cli import main
from quadpilot.train.ppo import PPO
from quadpilot.train.runs.checkpoint import LATEST, snapshot_path
from quadpilot.train.sac import SAC

DATA = Path(__file__).parent / "data" / "pre_spine"
EXPECTED = json.loads((DATA / "expected.json").read_text())


def simd() -> str:
    from numpy._core import _multiarray_umath as m

    best = [t for t in m.__cpu_dispatch__ if m.__cpu_features__.get(t)]
    return best[-1] if best else "none"


def blas_core() -> str | None:
    """The core whose kernels NumPy's OpenBLAS runs (set by OPENBLAS_CORETYPE, or detected)."""
    from threadpoolctl import threadpool_info

    return next((i.get("architecture") for i in threadpool_info() if i.get("internal_api") == "openblas"), None)


HERE = {
    "torch": torch.__version__,
    "cpu_capability": torch.backends.cpu.get_cpu_capability(),
    "numpy": np.__version__,
    "simd": simd(),
}
SAME_MACHINE = EXPECTED["made_with"] == HERE


def digest(*state_dicts) -> str:
    h = hashlib.sha256()
    for sd in state_dicts:
        for k in sorted(sd):
            h.update(k.encode())
            h.update(sd[k].detach().contiguous().numpy().tobytes())
    return h.hexdigest()


def pinned(got: str, want: str) -> None:
    if not SAME_MACHINE:
        pytest.skip(f"weights pinned with {EXPECTED['made_with']}; this machine has {HERE}")
    assert got == want


# --- what the code before the spine wrote and computed --------------------------------------


@pytest.mark.parametrize("kind", ["ppo", "lstm", "history", "sac"])
def test_a_checkpoint_written_before_the_spine_resumes_to_the_same_weights(tmp_path, kind):
    run = tmp_path / kind
    shutil.copytree(DATA / kind, run)
    agent = load_trainer(run / LATEST)
    assert isinstance(agent, SAC if kind == "sac" else PPO)
    assert load_policy(run / LATEST).algo == agent.algo  # the deployable view reads it too
    agent.iterate()
    nets = (agent.actor, agent.critic, agent.critic_target) if kind == "sac" else (agent.model,)
    pinned(digest(*(n.state_dict() for n in nets)), EXPECTED["weights_sha256"][kind])


TINY = ["--threads", "1", "--eval-episodes", "0", "--eval-every", "0"]
# quad-train flags → sha256 of policy.pt's model, computed by quadpilot f6db119 on this machine (lstm:
# recomputed at b446ba2, see the module's docstring); that
# code trained what --obs-version 1 trains (world-frame attitude, no heading to hold), and with torch:
# --update torch keeps these runs on the reference path now that an MLP's default is numpy, and
# --epochs 10 on the epochs that code ran by default
PPO_TINY = [
    *("--task", "hover", "--num-envs", "16", "--rollout-steps", "16", "--minibatch-size", "64", "--epochs", "10"),
    *("--total-steps", "512"),
]
RUNS = {
    "ppo": ([*PPO_TINY, "--update", "torch"], "dd7ecdeaa3943416c1908330d3e4d9ac5ca2c734d02afd3b3c1f7974a5bc4ab9"),
    "lstm": (
        [
            *("--task", "hover", "--arch", "lstm", "--bptt-steps", "8", "--num-envs", "8", "--rollout-steps", "16"),
            *("--minibatch-size", "64", "--total-steps", "256", "--randomize", "--sensor-noise", "--update", "torch"),
            *("--epochs", "10"),
        ],
        "594f78702f489675749cbb6e9659c575f8b5deb6d256b2cffc7a8fd1c7c6998e",
    ),
    "sac": (
        [
            *("--algo", "sac", "--task", "hover", "--num-envs", "8", "--rollout-steps", "8", "--total-steps", "128"),
            *("--set", "learning_starts=32", "--set", "minibatch_size=32"),
        ],
        "8fba53962fd042d18b1793a238fdd80ac34ad3b0ed62665e02244cbdbe07e296",
    ),
}


@pytest.mark.parametrize("kind", sorted(RUNS))
def test_two_iterations_give_the_weights_they_gave_before_the_spine(tmp_path, kind):
    argv, want = RUNS[kind]
    assert main([*argv, *TINY, "--obs-version", "1", "--timing", "none", "--out", str(tmp_path / "run")]) == 0
    ckpt = load_checkpoint(tmp_path / "run" / "policy.pt")
    assert ckpt["updates"] == 2
    pinned(digest(ckpt["model"]), want)


# The NumPy update (quadpilot.train.ppo.numpy_ppo) on the same run: pinned when it was written, with its own
# machine key, since its products run in numpy's BLAS, not torch's. OpenBLAS's kernels, picked by
# OPENBLAS_CORETYPE or detected, round differently, so the key holds the core in use and each core
# checked has its own pin: SkylakeX (what OpenBLAS detects on the pinning machine) gives the weights
# pinned when the update was written (quadpilot d357138), Haswell (that machine's CI sets
# OPENBLAS_CORETYPE=Haswell) others, the same at d357138 and b446ba2. OPENBLAS_L2_SIZE (512 there,
# or unset) did not change them.
NUMPY_RUN = [*PPO_TINY, "--update", "numpy"]
NUMPY_PINNED = {
    "SkylakeX": "6397f9f66873dc26de18a7cb380640a18b97487d5dbe5833fa22fe9ff0b023b8",
    "Haswell": "8983d6c787f0b49d3b1921612fcf6f3abce942a12462d766d733a00d2c10a713",
}
NUMPY_MADE_WITH = {"numpy": "2.4.6", "blas": "0.3.31.188.0", "cpu_capability": "AVX512", "simd": "AVX512_ICL"}


def numpy_here() -> dict:
    return {
        "numpy": np.__version__,
        "blas": np.__config__.CONFIG["Build Dependencies"]["blas"].get("version"),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "simd": simd(),
    }


def test_two_iterations_on_the_numpy_update_give_the_weights_pinned_for_it(tmp_path):
    assert main([*NUMPY_RUN, *TINY, "--obs-version", "1", "--timing", "none", "--out", str(tmp_path / "run")]) == 0
    ckpt = load_checkpoint(tmp_path / "run" / "policy.pt")
    assert ckpt["updates"] == 2
    here, core = numpy_here(), blas_core()
    if here != NUMPY_MADE_WITH or core not in NUMPY_PINNED:
        pytest.skip(f"weights pinned with {NUMPY_MADE_WITH} on OpenBLAS {sorted(NUMPY_PINNED)}; here {here} on {core}")
    assert digest(ckpt["model"]) == NUMPY_PINNED[core]


# --- one set of options for every algorithm ---------------------------------------------------

SAC_TINY = [
    *("--algo", "sac", "--task", "hover", "--num-envs", "8", "--rollout-steps", "8", "--threads", "1"),
    *("--eval-episodes", "0", "--eval-every", "0", "--set", "learning_starts=16", "--set", "minibatch_size=32"),
    *("--randomize", "pushes", "--sensor-noise", "--motor-tau", "0.02"),
]


def test_sac_takes_the_environment_options_and_resumes_their_state_bit_for_bit(tmp_path, capsys):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert main([*SAC_TINY, "--total-steps", "192", "--snapshot-every", "2", "--out", str(straight)]) == 0
    env = json.loads((straight / "config.json").read_text())["env"]
    assert env["randomization"]["name"] == "pushes" and env["sensor_noise"]["name"] == "seed"
    assert env["vehicle"]["motor_tau"] == 0.02
    ckpt = load_checkpoint(straight / LATEST)
    assert ckpt["algo"] == "sac" and "randomization" in ckpt["env"] and "noise" in ckpt["trainer"]["extra_state"]
    for steps in (0, 128, 192):  # at 0 steps, every 2 iterations and at the end
        assert load_policy(snapshot_path(straight, steps)).algo == "sac"
    assert main([*SAC_TINY, "--total-steps", "128", "--out", str(resumed)]) == 0
    assert main([*SAC_TINY, "--total-steps", "192", "--out", str(resumed), "--resume"]) == 0
    assert main([*SAC_TINY[:-1], "0.03", "--total-steps", "256", "--out", str(resumed), "--resume"]) == 2
    assert "--motor-tau 0.03 (checkpoint: 0.02)" in capsys.readouterr().err
    a, b = load_checkpoint(straight / "policy.pt"), load_checkpoint(resumed / "policy.pt")
    for key in ("model", "critic", "critic_target"):
        assert all(torch.equal(a[key][k], b[key][k]) for k in a[key]), key
    for key in ("state", "rotor", "obs"):  # the episodes in flight, on their randomised plants
        assert torch.equal(a["env"][key], b["env"][key]), key
    assert torch.equal(a["env"]["randomization"]["params"]["mass"], b["env"]["randomization"]["params"]["mass"])


def test_set_sets_ppo_hyper_parameters_too_and_a_resume_keeps_them(tmp_path, capsys):
    out = tmp_path / "run"
    ppo = ["--task", "hover", "--num-envs", "16", "--rollout-steps", "16", *TINY, "--out", str(out)]
    assert main([*ppo, "--total-steps", "256", "--set", "ent_coef=0.01", "--set", "actor_hidden=16,16"]) == 0
    cfg = json.loads((out / "config.json").read_text())["ppo"]
    assert cfg["ent_coef"] == 0.01 and cfg["actor_hidden"] == [16, 16]
    assert main([*ppo, "--total-steps", "512", "--resume", "--set", "ent_coef=0.02"]) == 2
    assert "--ent-coef 0.02 (checkpoint: 0.01)" in capsys.readouterr().err


def print_pins() -> None:
    """Print every pinned hash for the code in the working tree (run on the code the pins stand for)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for kind in ("ppo", "lstm", "history", "sac"):
            shutil.copytree(DATA / kind, out / kind)
            agent = load_trainer(out / kind / LATEST)
            agent.iterate()
            nets = (agent.actor, agent.critic, agent.critic_target) if kind == "sac" else (agent.model,)
            print(f"expected.json weights_sha256 {kind}: {digest(*(n.state_dict() for n in nets))}")
        for kind, (argv, _) in sorted(RUNS.items()):
            main([*argv, *TINY, "--obs-version", "1", "--timing", "none", "--out", str(out / f"run_{kind}")])
            print(f"RUNS {kind}: {digest(load_checkpoint(out / f'run_{kind}' / 'policy.pt')['model'])}")
        main([*NUMPY_RUN, *TINY, "--obs-version", "1", "--timing", "none", "--out", str(out / "run_numpy")])
        model = load_checkpoint(out / "run_numpy" / "policy.pt")["model"]
        print(f"NUMPY_PINNED {blas_core()}: {digest(model)}")
    print(f"made_with: {HERE}; numpy update: {numpy_here()}")


if __name__ == "__main__":
    print_pins()

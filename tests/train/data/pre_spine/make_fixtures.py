"""How the checkpoint fixtures of tests/train/test_spine.py were written: with the code of the commit
before the one training spine (quadpilot f6db119, whose API this calls; the current code has other
names), first on the path:

    PYTHONPATH=<f6db119 checkout>/src python make_fixtures.py OUT_DIR

Each fixture is a tiny trainer (4-unit layers, 2 drones) saved after one iteration (SAC: two, so its
12-row replay ring has wrapped), plus, in expected.json, the hash of its weights after one more
iteration resumed from the file, and the torch version and CPU capability that computed it. The
policy.pt files it also writes were not kept (load_policy reads checkpoint.pt alike).

expected.json has since been edited by hand, from what `python tests/train/test_spine.py` prints
(the fixtures themselves are still those this script wrote): its lstm hash was recomputed at
quadpilot b446ba2, after the motor lag's thrust averaged along the lag (13cc0e7) changed the
randomised environment it trains on, and made_with gained the NumPy version and SIMD target, which
the environment's results depend on."""

import hashlib
import json
import sys
from pathlib import Path

import torch

from quadpilot.train.algorithms import load_checkpoint
from quadpilot.train.envs import make_config
from quadpilot.train.ppo import PPO, PPOConfig
from quadpilot.train.ppo.checkpoint import ppo_from_checkpoint
from quadpilot.train.runs import checkpoint as ck


def digest(*state_dicts) -> str:
    h = hashlib.sha256()
    for sd in state_dicts:
        for k in sorted(sd):
            h.update(k.encode())
            h.update(sd[k].detach().contiguous().numpy().tobytes())
    return h.hexdigest()


def ppo_fixture(out: Path, cfg: PPOConfig, env_cfg) -> str:
    out.mkdir(parents=True)
    ppo = PPO(cfg, env_cfg)
    ppo.iterate()
    ck.save_for_resume(out, ppo, {"preset": "fast", "elapsed_s": 1.0, "first_success": None, "metrics": {}})
    ck.save_checkpoint(out / ck.POLICY, ppo, {"preset": "fast"})
    again = ppo_from_checkpoint(load_checkpoint(out / ck.LATEST), source="fixture")
    again.iterate()
    return digest(again.model.state_dict())


def sac_fixture(out: Path) -> str:
    from quadpilot.train import sac as S

    out.mkdir(parents=True)
    cfg = S.SACConfig(
        num_envs=2,
        rollout_steps=4,
        total_steps=64,
        learning_starts=4,
        minibatch_size=8,
        updates_per_step=1,
        buffer_size=12,
        actor_hidden=(4,),
        critic_hidden=(4,),
        threads=1,
    )
    sac = S.SAC(cfg, make_config("hover"))
    sac.iterate()
    sac.iterate()  # 16 transitions in a 12-row ring: it has wrapped
    S.save_for_resume(out, sac, 0, {"elapsed_s": 1.0, "first_success": None, "metrics": {}})
    S.save_policy(out / ck.POLICY, sac, {})
    again = S.load_trainer(out / ck.LATEST)
    again.iterate()
    return digest(again.actor.state_dict(), again.critic.state_dict(), again.critic_target.state_dict())


def main(root: Path) -> None:
    small = dict(
        num_envs=2,
        rollout_steps=8,
        minibatch_size=8,
        epochs=2,
        total_steps=64,
        threads=1,
        actor_hidden=(4,),
        critic_hidden=(4,),
        lstm_hidden=4,
    )
    expected = {
        "ppo": ppo_fixture(root / "ppo", PPOConfig(**small), make_config("hover")),
        "lstm": ppo_fixture(
            root / "lstm",
            PPOConfig(**small, arch="lstm", bptt_steps=4),
            make_config("waypoint", randomization="default", sensor_noise="seed"),
        ),
        "history": ppo_fixture(
            root / "history", PPOConfig(**small, obs_history=2, normalize_obs=True), make_config("circle")
        ),
        "sac": sac_fixture(root / "sac"),
    }
    meta = {"torch": torch.__version__, "cpu_capability": torch.backends.cpu.get_cpu_capability()}
    (root / "expected.json").write_text(json.dumps({"made_with": meta, "weights_sha256": expected}, indent=2) + "\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]))

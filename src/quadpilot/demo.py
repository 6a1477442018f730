"""quad-demo: fly each environment one episode at hover trim, time the batched one, say what happened.

A check that the environments install and run (the train extra), not training: with every rotor at
hover trim the random starts drift off and end in crashes; the batched hover environment is then
stepped with small random actions and its speed printed. README.md, "The environments".

Exit codes: 0 done; 2 a bad flag (one line on stderr).
"""

from __future__ import annotations

import time

import numpy as np

from quadpilot.console import Parser, run_command
from quadpilot.console import int_in as _int_in

MAX_ENVS = 1 << 16  # quad-train's bound (train.runs.checks.MAX_ENVS): 65 536 drones are ~5 MB of state
MAX_STEPS = 1_000_000


def main(argv: list[str] | None = None) -> int:
    ap = Parser(prog="quad-demo", description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--num-envs", type=_int_in(1, MAX_ENVS), default=1024, help="drones in the batched vector environment"
    )
    ap.add_argument("--steps", type=_int_in(1, MAX_STEPS), default=1000, help="vector-environment steps to run")
    ap.add_argument("--seed", type=_int_in(0, 2**63 - 1), default=0, help="random seed")
    return run_command("quad-demo", lambda: _demo(ap.parse_args(argv)))


def _demo(args) -> int:
    import gymnasium as gym

    import quadpilot.train  # noqa: F401  (registers the environments)

    rng = np.random.default_rng(args.seed)
    for env_id in ("quadpilot/Hover-v0", "quadpilot/Waypoint-v0", "quadpilot/Circle-v0"):
        env = gym.make(env_id)
        obs, info = env.reset(seed=args.seed)
        ret, n, done = 0.0, 0, False
        while not done:  # zero action = every rotor at hover trim; random starts drift and tumble
            obs, r, term, trunc, info = env.step(np.zeros(4, np.float32))
            ret, n, done = ret + r, n + 1, term or trunc
        why = "crashed" if term else "time limit"
        print(
            f"{env_id:24s} obs {obs.shape[0]:2d}  one episode at hover trim: {n:3d} steps, "
            f"return {ret:7.2f}, ended by {why}, final position error {info['pos_error']:.2f} m"
        )
        env.close()

    venv = gym.make_vec("quadpilot/Hover-v0", num_envs=args.num_envs, vectorization_mode="vector_entry_point")
    venv.reset(seed=args.seed)
    ended = crashed = 0
    t0 = time.perf_counter()
    for _ in range(args.steps):
        actions = rng.uniform(-0.05, 0.05, (args.num_envs, 4)).astype(np.float32)
        _, _, term, trunc, _ = venv.step(actions)
        ended += int((term | trunc).sum())
        crashed += int(term.sum())
    dt = time.perf_counter() - t0
    rate = args.num_envs * args.steps / dt
    print(
        f"vector env: {args.num_envs} drones × {args.steps} steps in {dt:.2f} s = {rate / 1e6:.2f} M drone-steps/s; "
        f"{ended} episodes ended ({crashed} crashed, {ended - crashed} reached the time limit)"
    )
    print("next: quad-train --task hover --out runs/hover trains a policy that holds the target (README.md, Training).")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""quadpilot: train a quadrotor controller with PPO written from scratch, export it to ONNX and fly
that exact file over MAVLink against a software-in-the-loop quadrotor.

`import quadpilot` is light: it imports neither torch nor gymnasium. Its packages and top-level
modules, from the bottom up (docs/architecture.md says what each may import):

- `core`: NumPy-only foundations (vehicles, dynamics, frames, observation, reward, mission);
- `atomic_files`: the one way a file is written, whole or not at all;
- `console`: the command-line scaffold every command shares;
- `link`: the MAVLink contract (frames, messages, transport, .tlog);
- `viz`: plots, flight videos and montages;
- `modelfile`: what a policy file is, and reading and checking one, torch-free;
- `ccode`: a policy's network as C99, and the Cortex-M harness that boots it in QEMU;
- `runtime`: running a policy file, torch-free (NumPy, ONNX Runtime and C backends, the safety
  monitor and its fallback);
- `autopilot`: the vehicle stack around a policy, as PX4 runs it (the node, commander, navigator);
- `simulator`: the simulator side of software-in-the-loop (plant, sensors, MAVLink server);
- `sitl`: `quad-sitl`, a policy file flown through the node against the simulator;
- `train`: environments and training (torch, gymnasium), `quad-train`;
- `studies`: the experiments built on training (`quad-compare`, robustness, montages);
- `export`: `quad-export`, a trained policy as ONNX or C (torch, onnx);
- `demo`: `quad-demo`, the environments run once at hover trim.
"""

__version__ = "0.1.0"

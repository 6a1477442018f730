"""quadpilot: train a quadrotor controller with PPO written from scratch, export it to ONNX and fly
that exact file over MAVLink against a software-in-the-loop quadrotor.

`import quadpilot` is light: it imports neither torch nor gymnasium. Subpackages: `core` (NumPy
model), `train` (torch, gymnasium), `export` (torch, onnx), `link` (MAVLink contract),
`runtime` and `simulator` (NumPy, ONNX Runtime, pymavlink).
"""

__version__ = "0.1.0"

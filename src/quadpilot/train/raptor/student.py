"""The GRU policy of exactly the shape PX4's mc_raptor is compiled for, in PyTorch, for training.

blob/policy.h fixes it: dense 22 -> 16 ReLU, GRU 16, dense 16 -> 4 identity, 2,084 parameters,
the state after a reset a learned vector (RLtools' `initial_hidden_state`). PyTorch's `nn.GRU`
computes RLtools' equations with the gates in RLtools' order r | z | n and the hidden bias of the
candidate inside the reset gate's product, so its parameters are the RLtools weights unchanged:
`weights()` gives the weight dict runtime/gru.py documents (what `GruStep`, the ONNX graph and
`rltools_tar.write_policy_tar` take), and `from_weights` reads one back.

The inputs are the `px4-raptor` contract's 22 (core/px4_raptor.py), the outputs its 4 actions
before clipping; the GRU advances once per 100 Hz step (the contract's `Executor`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from quadpilot.core.px4_raptor import ACTION_DIM, OBS_DIM
from quadpilot.runtime.gru import GRU_KEYS, HIDDEN, check_weights


class RaptorStudent(nn.Module):
    """`forward(x (T, B, 22), h (B, 16) or None) -> (actions (T, B, 4), h' (B, 16))`; None starts
    every sequence from the learned initial state."""

    def __init__(self) -> None:
        super().__init__()
        self.dense_in = nn.Linear(OBS_DIM, HIDDEN)
        self.gru = nn.GRU(HIDDEN, HIDDEN)
        self.initial_hidden_state = nn.Parameter(torch.zeros(HIDDEN))
        self.dense_out = nn.Linear(HIDDEN, ACTION_DIM)

    def initial_state(self, batch: int) -> torch.Tensor:
        return self.initial_hidden_state.expand(batch, HIDDEN)

    def forward(self, x: torch.Tensor, h: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        if h is None:
            h = self.initial_state(x.shape[1])
        y, h_next = self.gru(torch.relu(self.dense_in(x)), h.unsqueeze(0).contiguous())
        return self.dense_out(y), h_next[0]

    def weights(self) -> dict[str, np.ndarray]:
        """The weight dict of runtime/gru.py (float32 copies, keys `GRU_KEYS`)."""
        tensors = {
            "layers/0/weights": self.dense_in.weight,
            "layers/0/biases": self.dense_in.bias,
            "layers/1/weights_input": self.gru.weight_ih_l0,
            "layers/1/biases_input": self.gru.bias_ih_l0,
            "layers/1/weights_hidden": self.gru.weight_hh_l0,
            "layers/1/biases_hidden": self.gru.bias_hh_l0,
            "layers/1/initial_hidden_state": self.initial_hidden_state,
            "layers/2/weights": self.dense_out.weight,
            "layers/2/biases": self.dense_out.bias,
        }
        assert list(tensors) == list(GRU_KEYS)
        return {k: t.detach().cpu().numpy().astype(np.float32) for k, t in tensors.items()}

    @classmethod
    def from_weights(cls, weights: dict) -> RaptorStudent:
        """A student holding `weights` (checked by runtime/gru.check_weights)."""
        w = {k: torch.from_numpy(v.copy()) for k, v in check_weights(weights).items()}
        net = cls()
        with torch.no_grad():
            net.dense_in.weight.copy_(w["layers/0/weights"])
            net.dense_in.bias.copy_(w["layers/0/biases"])
            net.gru.weight_ih_l0.copy_(w["layers/1/weights_input"])
            net.gru.bias_ih_l0.copy_(w["layers/1/biases_input"])
            net.gru.weight_hh_l0.copy_(w["layers/1/weights_hidden"])
            net.gru.bias_hh_l0.copy_(w["layers/1/biases_hidden"])
            net.initial_hidden_state.copy_(w["layers/1/initial_hidden_state"])
            net.dense_out.weight.copy_(w["layers/2/weights"])
            net.dense_out.bias.copy_(w["layers/2/biases"])
        return net

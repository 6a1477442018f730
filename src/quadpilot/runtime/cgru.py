"""`CGruStep`: the GRU policy of PX4 mc_raptor's shape run as generated C (`ccode.gru`), compiled by
the runtime's C backend machinery (`cbackend.build_library`: the system compiler, a private cache)
and called through ctypes with preallocated float32 buffers. The same interface as
`gru.GruStep`: `step(x, h) → (action (4,), h' (16,))`, `initial_state`."""

from __future__ import annotations

import ctypes

import numpy as np

from quadpilot.ccode.gru import ACTIONS, HIDDEN, OBS, STEP, gru_code

from .cbackend import build_library
from .gru import check_weights


class CGruStep:
    """The compiled step; CCompilerError (from `build_library`) when there is no C compiler."""

    def __init__(self, weights: dict) -> None:
        w = check_weights(weights)
        self.initial_state = w["layers/1/initial_hidden_state"]
        self.code = gru_code(w)
        self.library = build_library(self.code)
        self._lib = ctypes.CDLL(str(self.library))
        self._fn = getattr(self._lib, STEP)
        self._fn.argtypes = [ctypes.c_void_p] * 4
        self._fn.restype = None
        # fixed buffers, their addresses taken once: a call converts no array (ndpointer's checks
        # cost microseconds, several times the kernel)
        self._x, self._h = np.zeros(OBS, np.float32), np.zeros(HIDDEN, np.float32)
        self._a, self._h_out = np.zeros(ACTIONS, np.float32), np.zeros(HIDDEN, np.float32)
        self._args = [ctypes.c_void_p(b.ctypes.data) for b in (self._x, self._h, self._a, self._h_out)]

    def __call__(self, x: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._x[:] = x
        self._h[:] = h
        self._fn(*self._args)
        return self._a.copy(), self._h_out.copy()

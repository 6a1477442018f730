"""Running mean and variance of observations (NumPy), shared by training and export.

Parallel/batched update of Chan, Golub & LeVeque (1979), the same merge SB3's RunningMeanStd uses.
"""

from __future__ import annotations

import numpy as np


class RunningMeanStd:
    """Mean and variance over everything seen so far, per feature; float64 accumulators."""

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-4, clip: float = 10.0) -> None:
        self.mean = np.zeros(shape, np.float64)
        self.var = np.ones(shape, np.float64)
        self.count = float(epsilon)  # a tiny prior count keeps the first merge well defined
        self.clip = float(clip)

    def update(self, x: np.ndarray) -> None:
        """Merge a batch x of shape (B, *shape). Non-finite rows are ignored, never merged."""
        x = np.asarray(x, np.float64)
        x = x[np.isfinite(x).all(axis=tuple(range(1, x.ndim)))]
        b = x.shape[0]
        if b == 0:
            return
        b_mean, b_var = x.mean(axis=0), x.var(axis=0)
        total = self.count + b
        delta = b_mean - self.mean
        self.mean = self.mean + delta * b / total
        m2 = self.var * self.count + b_var * b + delta**2 * self.count * b / total
        self.var = m2 / total
        self.count = total

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(self.var + 1e-8)

    def normalize(self, x: np.ndarray) -> np.ndarray:
        """(x − mean)/std clipped to ±clip, float32."""
        return np.clip((x - self.mean) / self.std, -self.clip, self.clip).astype(np.float32)

    def state_dict(self) -> dict:
        return {"mean": self.mean.copy(), "var": self.var.copy(), "count": self.count, "clip": self.clip}

    def load_state_dict(self, d: dict) -> None:
        self.mean = np.asarray(d["mean"], np.float64).copy()
        self.var = np.asarray(d["var"], np.float64).copy()
        self.count = float(d["count"])
        self.clip = float(d["clip"])

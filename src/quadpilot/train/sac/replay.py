"""SAC's replay buffer and the files that make it resumable.

`ReplayBuffer` is a ring of transitions (s, a, r, s', terminated), one float32 row each. A run keeps
it across a resume without writing the whole buffer at every checkpoint: each save first writes
the transitions added since the previous save as an immutable chunk `replay/<start>-<end>.pt`
(tensors only, atomic, `save_replay_chunk`), then the checkpoint records how many transitions it
covers; chunks no checkpoint generation needs are deleted (`prune_replay`), and a resume refills the
ring from the chunks (`load_replay`), dropping any written after the checkpoint it resumes from.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import torch

from quadpilot.atomic_files import atomic_write
from quadpilot.core.params import NUM_MOTORS

from ..runs.checks import CheckpointError, load_weights_only

ACT_DIM = NUM_MOTORS  # the action is one command a rotor
REPLAY_DIR = "replay"
REPLAY_SCHEMA = "quadpilot.replay/1"


class ReplayBuffer:
    """A ring buffer of transitions (s, a, r, s', terminated), one float32 row each:
    [obs (D) | action (4) | reward (1) | next obs (D) | terminated (1)].

    `stored` counts every transition ever added; transition i lives in row i mod capacity. The
    reward is stored unscaled. s' of a drone whose episode ended is its final observation (the
    vector env's `final_obs`), never the next episode's first."""

    def __init__(self, capacity: int, obs_dim: int, act_dim: int = ACT_DIM) -> None:
        self.capacity, self.obs_dim, self.act_dim = int(capacity), obs_dim, act_dim
        d, a = obs_dim, act_dim
        self.width = 2 * d + a + 2
        self.slices = {
            "obs": slice(0, d),
            "act": slice(d, d + a),
            "rew": slice(d + a, d + a + 1),
            "next_obs": slice(d + a + 1, 2 * d + a + 1),
            "term": slice(2 * d + a + 1, 2 * d + a + 2),
        }
        self.data = torch.empty(self.capacity, self.width)  # pages are touched only as rows arrive
        self.stored = 0

    def __len__(self) -> int:
        return min(self.stored, self.capacity)

    def add(self, obs, act, rew, next_obs, term) -> None:
        """Append n transitions: obs, next_obs (n, D); act (n, 4); rew, term (n,)."""
        n = obs.shape[0]
        assert obs.shape == next_obs.shape == (n, self.obs_dim) and act.shape == (n, self.act_dim)
        rows = np.empty((n, self.width), np.float32)
        s = self.slices
        rows[:, s["obs"]] = obs
        rows[:, s["act"]] = act
        rows[:, s["rew"]] = np.asarray(rew).reshape(n, 1)
        rows[:, s["next_obs"]] = next_obs
        rows[:, s["term"]] = np.asarray(term).reshape(n, 1)
        self.put_rows(self.stored, torch.from_numpy(rows))

    def put_rows(self, start: int, rows: torch.Tensor) -> None:
        """Write rows for transitions start, start + 1, … (at most `capacity` of them)."""
        n = rows.shape[0]
        if n > self.capacity:
            rows, start, n = rows[-self.capacity :], start + n - self.capacity, self.capacity
        i = start % self.capacity
        first = min(n, self.capacity - i)
        self.data[i : i + first] = rows[:first]
        if first < n:
            self.data[: n - first] = rows[first:]
        self.stored = max(self.stored, start + n)

    def rows(self, start: int, end: int) -> torch.Tensor:
        """A copy of transitions start … end − 1 (they must still be in the buffer)."""
        if not (self.stored - len(self) <= start <= end <= self.stored):
            raise ValueError(
                f"transitions {start}…{end} are not in the buffer ({self.stored - len(self)}…{self.stored})"
            )
        idx = torch.arange(start, end) % self.capacity
        return self.data[idx].clone()

    def sample(self, n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        """n transitions drawn uniformly with replacement: views of one gathered (n, width) tensor."""
        rows = self.data[torch.randint(len(self), (n,), generator=generator)]
        s = self.slices
        return {
            "obs": rows[:, s["obs"]],
            "act": rows[:, s["act"]],
            "rew": rows[:, s["rew"]].squeeze(1),
            "next_obs": rows[:, s["next_obs"]],
            "term": rows[:, s["term"]].squeeze(1),
        }


# --- chunks ---------------------------------------------------------------------------------


_CHUNK = re.compile(r"^(\d{12})-(\d{12})\.pt$")


def _chunks(directory: Path) -> list[tuple[int, int, Path]]:
    """(start, end, path) of the replay chunks in directory/replay, by start."""
    d = directory / REPLAY_DIR
    if not d.is_dir():
        return []
    out = []
    for p in d.iterdir():
        m = _CHUNK.match(p.name)
        if m:
            out.append((int(m.group(1)), int(m.group(2)), p))
    return sorted(out)


def save_replay_chunk(directory: str | os.PathLike, buffer: ReplayBuffer, start: int) -> Path | None:
    """Write transitions start … buffer.stored − 1 (those still in the buffer) as one immutable
    chunk file replay/<start>-<end>.pt, atomically; None if there is nothing new."""
    directory = Path(directory)
    end = buffer.stored
    start = max(start, end - len(buffer))
    if end <= start:
        return None
    (directory / REPLAY_DIR).mkdir(exist_ok=True)
    data = {"schema": REPLAY_SCHEMA, "start": start, "end": end, "rows": buffer.rows(start, end)}
    return atomic_write(directory / REPLAY_DIR / f"{start:012d}-{end:012d}.pt", lambda f: torch.save(data, f))


def prune_replay(directory: str | os.PathLike, keep_from: int) -> None:
    """Delete chunks that end at or before transition `keep_from` (no checkpoint needs them)."""
    for _start, end, p in _chunks(Path(directory)):
        if end <= keep_from:
            p.unlink(missing_ok=True)


def load_replay(directory: str | os.PathLike, buffer: ReplayBuffer, stored: int) -> None:
    """Refill `buffer` with the transitions max(0, stored − capacity) … stored − 1 from the chunks
    in directory/replay. Chunks from beyond `stored` (written before a kill, after the checkpoint)
    are deleted. Raises CheckpointError naming what is missing or unreadable."""
    directory = Path(directory)
    need_from = max(0, stored - buffer.capacity)
    pos = need_from
    for start, end, p in _chunks(directory):
        if start >= stored:
            p.unlink(missing_ok=True)  # written after the checkpoint we resume from
            continue
        if end <= need_from:
            continue
        if start > pos or end > stored:
            break
        chunk = load_weights_only(p)
        try:
            rows = chunk["rows"]
            ok = chunk.get("schema") == REPLAY_SCHEMA and tuple(rows.shape) == (end - start, buffer.width)
        except Exception:  # a foreign file: not a dict, no rows, rows without a shape
            ok = False
        if not ok:
            raise CheckpointError(f"{p}: not a replay chunk of this run (schema {REPLAY_SCHEMA}, width {buffer.width})")
        lo = max(start, pos)
        buffer.put_rows(lo, rows[lo - start :])
        pos = end
    if pos != stored:
        raise CheckpointError(
            f"{directory / REPLAY_DIR}: the checkpoint's replay buffer holds transitions {need_from:,}…{stored:,}, "
            f"but the chunks there reach only {pos:,}; the replay buffer cannot be rebuilt, so this run "
            "cannot be resumed (start a new run with another --out)"
        )
    buffer.stored = stored

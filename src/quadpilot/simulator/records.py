"""What the simulator reports: one `EpisodeRecord` per episode (connection), `SimStats` over all of
them, and the bookkeeping of the episode being served (`EpisodeTally`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

TOUCHDOWN_MAX_SPEED = 1.0
"""m/s: an air start's first ground contact slower than this (and upright) is a landing, not a crash."""
TOUCHDOWN_MAX_TILT_DEG = 30.0
"""deg: ... and tilted less than this the step before it."""
END_REASONS = ("peer_closed", "lockstep_timeout", "peer_silent", "max_steps", "stopped")


@dataclass
class EpisodeRecord:
    """What one episode (one connection) did."""

    index: int
    peer: str
    steps: int
    sim_time_s: float
    wall_time_s: float
    end_reason: str
    """One of END_REASONS: peer_closed (TCP EOF), lockstep_timeout, peer_silent (realtime),
    max_steps, stopped."""
    crashed: bool
    """`core.reward.crashed` (below ground, tilt > 60° or > 5 m from `target`) at any step."""
    first_crash_step: int | None
    final_pos_error_m: float
    initial_state: tuple[float, ...]
    final_state: tuple[float, ...]
    dropped: dict[str, int]
    esc_timeouts: int
    commands: int = 0
    """HIL_ACTUATOR_CONTROLS messages applied (armed and valid, or disarmed: motors 0)."""
    esc_cut_silence_s: float | None = None
    """How long valid commands had been missing when the ESCs cut the motors, s (host clock in realtime,
    simulated time in lockstep; None: never)."""
    period_jitter_ms: tuple[float, float, float] | None = None
    """Realtime: |step period − dt| in ms over the episode, (p50, p99, max)."""
    overruns: int = 0
    """Realtime: steps that started more than one dt late."""
    rate_limited_steps: int = 0
    """Steps whose body rates the plant had to saturate at `link.wire.MAX_BODY_RATE` (a tumble)."""
    touchdown: tuple[int, float, float] | None = None
    """An air start's first ground contact: (step, impact speed m/s, tilt deg the step before, as the
    ground stands the vehicle level). Below TOUCHDOWN_MAX_SPEED and TOUCHDOWN_MAX_TILT_DEG it is a
    landing, not a crash. None: it never touched the ground."""
    max_descent_speed: float = 0.0
    """m/s, the fastest the vehicle moved down in the air over the episode."""
    motors_off_airborne_steps: int = 0
    """Steps flown with every motor commanded off while the vehicle was in the air (a cut in the air)."""
    truth: list | None = None
    """With `SimConfig.record_truth`: (simulated time s, 12-state) after every step; else None."""

    def summary(self) -> str:
        dropped = sum(self.dropped.values())
        crash = f"crashed at step {self.first_crash_step}" if self.crashed else "no crash"
        return (
            f"episode {self.index}: {self.steps} steps ({self.sim_time_s:.2f} s simulated, "
            f"{self.wall_time_s:.2f} s wall), ended by {self.end_reason}, {crash}, "
            f"final error {self.final_pos_error_m:.3f} m, dropped {dropped} packets"
            + (f", {self.esc_timeouts} ESC timeouts" if self.esc_timeouts else "")
        )


@dataclass
class SimStats:
    """Counters over all episodes; `records` has one entry per finished episode."""

    steps: int = 0
    episodes: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    """Packets thrown away, by reason: garbage (a run of stray bytes without a MAVLink start
    marker, as pymavlink reports it), bad_crc, bad_data (other framing errors), unknown_message_id,
    signature_unsigned / signature_bad / signature_replayed / signature_stale (signing on),
    parser_error, non_finite_control, out_of_range_control, before_first_state (UDP: an actuator
    message in the datagram that opened the episode), foreign_peer (UDP: a datagram from anyone but
    the pinned peer), truncated_datagram (UDP: a datagram that ended inside a message),
    oversized_datagram (UDP: longer than link.transport.MAX_DATAGRAM, dropped unparsed)."""
    ignored: dict[str, int] = field(default_factory=dict)
    """Well-formed messages the simulator has no use for, by type."""
    heartbeats: int = 0
    esc_timeouts: int = 0
    """Times the motors were cut because valid commands stopped (see `SimConfig.esc_timeout_s`)."""
    overruns: int = 0
    """Realtime mode: steps that started more than one dt late (the clock was then re-synchronised)."""
    records: list[EpisodeRecord] = field(default_factory=list)


class EpisodeTally:
    """Per-episode bookkeeping, kept by the server loop (`process`) and the message handling
    (`protocol`) while the episode runs; the loop turns it into the episode's EpisodeRecord."""

    def __init__(self, index: int, peer: str) -> None:
        self.index, self.peer = index, peer
        self.dropped: dict[str, int] = {}
        self.esc_timeouts = 0
        self.esc_cut_silence_s: float | None = None
        self.commands = 0
        self.step_times: list[float] = []
        self.overruns = 0
        self.steps_done = 0
        self.first_crash_step: int | None = None
        self.touchdown: tuple[int, float, float] | None = None
        self.max_descent_speed = 0.0
        self.motors_off_airborne_steps = 0
        self.truth: list | None = None

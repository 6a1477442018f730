"""How the node connects and what it flies (`NodeConfig`): `autopilot.node.Node` and the episode it
flies (`autopilot.flight.Flight`) both read it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from quadpilot.link import wire
from quadpilot.link.spin import LOCKSTEP_SPIN_S, check_spin

from .state_loss import StateLossConfig

START_MODES = ("air", "landed")
"""`NodeConfig.start`: where a commanded flight starts."""


@dataclass(frozen=True)
class NodeConfig:
    """How the node connects and what it flies."""

    connect: str = "tcp:127.0.0.1:4560"
    """Address of the simulator: tcp:HOST:PORT, or udp:HOST:PORT for a simulator on UDP."""
    target: tuple[float, float, float] | None = (0.0, 0.0, 2.0)
    """m, local ENU hover target (the training environment's home); None: the first valid position
    (hold where the flight starts)."""
    targets: Callable[[int], tuple[np.ndarray, np.ndarray | None]] | None = field(default=None, compare=False)
    """Moving target: policy step k → (position (3,), velocity (3,) or None), world ENU. None: `target`."""
    home: wire.Home | None = field(default_factory=wire.Home)
    """Geodetic origin of the local frame (our simulator's by default); None: the first valid
    position received (HIL_STATE_QUATERNION, the message the node flies on)."""
    duration_s: float = 5.0
    """s of simulated flight per episode (the steps' time_usec, not the host's clock)."""
    lockstep: bool = True
    """Set the lockstep flag in HIL_ACTUATOR_CONTROLS (the simulator advances one step per message)."""
    spin_s: float = LOCKSTEP_SPIN_S
    """s, in lockstep: poll the simulator link this long before sleeping (`transport.Link.spin_s`;
    0: sleep at once, off with one usable CPU)."""
    link_timeout_s: float = 0.1
    """s without a state message before the failsafe latches: host time in real time; in lockstep
    only without a valid state, on simulated time (see the module docstring)."""
    first_state_timeout_s: float = 10.0
    """s to wait for the simulator's first state message after connecting (a simulator started by
    hand may take a while between our HEARTBEAT and its first step); `link_timeout_s` after it."""
    connect_timeout_s: float = 10.0
    """s to keep retrying the connection while the simulator starts."""
    heartbeat_period_s: float = 1.0
    """s between HEARTBEATs to the simulator, sent from the control loop."""
    max_time_jump_s: float = 1.0
    """A state timestamp further ahead than this is dropped as a jump."""
    gcs: str | None = "udp:127.0.0.1:14550"
    """Where ground-station telemetry goes (udp:HOST:PORT); None: no telemetry."""
    telemetry_hz: float = 25.0
    """ATTITUDE and LOCAL_POSITION_NED rate, per simulated second."""
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes) for the simulator link; None: unsigned."""
    control_period_s: float | None = None
    """s per simulator step, if known in advance; None: measured from the steps' time_usec (until
    two steps have arrived, the policy's period is assumed)."""
    speak_as_peer: bool = True
    """Answer in the MAVLink version the simulator speaks (`transport.Link.speak_as_peer`); False,
    or a signing key: MAVLink 2 only."""
    command: bool = False
    """Answer the ground station at `gcs` as a PX4 vehicle (`autopilot.commander`): the policy flies to
    the commander's setpoint (`target` and `targets` are not used), the motors are off while it is
    disarmed or idle, its telemetry streams replace the GroundStation's own, and the flight ends
    DISARMED_LINGER_S after the vehicle has flown and been disarmed (`duration_s` is the cap)."""
    start: str = "air"
    """With `command`: "air", armed and holding where the first valid state is (a simulator that
    starts in flight); "landed", disarmed on the ground until the ground station arms it."""

    state_loss: StateLossConfig = field(default_factory=StateLossConfig)
    """What the node flies when a step's HIL_SENSOR comes without its state (`autopilot.state_loss`):
    the policy on an estimate from HIL_SENSOR, then a hold of attitude and height, then a landing."""

    def __post_init__(self) -> None:
        check_spin(self.spin_s)
        if self.start not in START_MODES:
            raise ValueError(f"start must be one of {START_MODES}, got {self.start!r}")

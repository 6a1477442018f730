"""A policy.tar put onto the vehicle over MAVLink FTP, as onto a PX4 SD card, and flown.

PX4's mc_raptor loads `/fs/microsd/raptor/policy.tar` once, when the module starts (a new file
needs a restart). Here the file is taken while the vehicle runs:
- Checked when its upload ends (the client's TerminateSession after the last write: MAVSDK's
  `ftp.upload`, MAVProxy's `ftp put`), with the reader `quad-sitl policy.tar` uses
  (`runtime.rltools_tar.parse_policy_tar`: every member, every value, the whole stored example
  replayed; about 20 ms). A damaged file is refused and the ground station told why in a STATUSTEXT
  ("policy.tar refused: ...", in chunks when longer than one); the vehicle goes on with the
  policy it has. A good one is announced ("policy.tar checked: NAME").
- Swapped in only while the vehicle is disarmed: at once when the upload ends on the ground,
  otherwise at the disarm after the landing; never in the air. The next arming flies it
  ("Policy loaded: NAME", and the run's JSON summary lists it under `commanded.policies`).
- Only in place of a RAPTOR policy (a policy.tar or raptor:foundation): the file fills mc_raptor's
  contract (its observation, its rate); a vehicle flying another kind of policy checks the file and
  says it cannot fly it. It flies on the vehicle the running policy flies on, with its backend.
"""

from __future__ import annotations

from quadpilot.runtime.rltools_tar import PolicyTar, PolicyTarError, parse_policy_tar


def check_upload(data: bytes) -> tuple[PolicyTar | None, str]:
    """The checked policy, or None, and what to tell the ground station."""
    try:
        tar = parse_policy_tar(data)
    except PolicyTarError as e:
        return None, f"policy.tar refused: {e}"
    return tar, f"policy.tar checked: {tar.checkpoint_name}"[:50]


def load_uploaded(monitor, tar: PolicyTar, name: str) -> tuple[bool, str]:
    """Fly `tar` in `monitor` (a `runtime.safety.SafetyMonitor`) from its next reset: whether it was
    loaded, and what to tell the ground station."""
    from quadpilot.runtime.raptor import RaptorPolicy, raptor_from_weights

    old = monitor.policy
    if not isinstance(old, RaptorPolicy):
        return False, "policy.tar not loaded: not flying a RAPTOR policy"
    example = {"input": tar.example_in, "output": tar.example_out}
    try:
        new = raptor_from_weights(tar.weights, example, name, tar.sha256, old.backend, old.info.vehicle)
    except Exception as e:  # a contract error, a C backend that cannot build it: said, never the end
        return False, f"policy.tar not loaded: {e}"
    new.gyro_rate_hz = old.gyro_rate_hz
    monitor.replace_policy(new)
    return True, f"Policy loaded: {tar.checkpoint_name}"[:50]


def fly_uploaded(commander, monitor) -> bool:
    """The owner's step while disarmed with `commander.new_policy` waiting: load it into `monitor`,
    tell the ground station (through the commander's next messages) and record it. Whether the
    policy flown changed."""
    from pymavlink.dialects.v20 import common as mavlink2

    from .ftp_protocol import POLICY_PATH

    tar, commander.new_policy = commander.new_policy, None
    ok, said = load_uploaded(monitor, tar, POLICY_PATH)
    commander.long_text(said, mavlink2.MAV_SEVERITY_INFO if ok else mavlink2.MAV_SEVERITY_ERROR)
    flown = monitor.policy.info.source_sha256 if ok else None  # what the monitor now flies
    commander.policies.append({"at_s": commander.now, "text": said, "sha256": flown})
    return ok

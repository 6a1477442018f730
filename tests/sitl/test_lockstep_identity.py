"""A lockstep flight is the same flight, and the same bytes on the wire, as before the SITL speed work.

The shipped hover policy flown by the node against our simulator (two processes, loopback TCP,
lockstep), 3 s of simulated time (300 steps) from a fixed seed: once plain, once with every sensor
and disturbance path on (IMU noise, the estimator's ODOMETRY, wind, gusts). Pinned per flight:

- `flight`: the node's log (ground truth per step, targets, motor commands) and its judged
  summary (`autopilot.node.episode_summary`: success, errors, heading);
- `from_simulator`: every frame the simulator sent, byte for byte (HIL_GPS, HIL_STATE_QUATERNION,
  ODOMETRY, HIL_SENSOR, sequence numbers and CRCs included);
- `from_node`: every HIL_ACTUATOR_CONTROLS the node sent, header (sequence number left out: a
  HEARTBEAT, sent on the host's clock, may fall between two of them on a slow machine) and payload;
- `simulator`: the simulator's record of the episode (`--json`: its start and final 12-state in
  full float64, which the wire's integers and float32s would round a last-bit change away from,
  crash, drops, commands), host-dependent fields (peer address, wall time) left out.

The digests were computed with the code as it was before the speed work (main at 8e01231, its
source unchanged), per OpenBLAS kernel (below); a retrained shipped policy, or a C library whose
sin/cos round differently, changes them.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from quadpilot.autopilot.flight_log import episode_summary
from quadpilot.autopilot.node import Node, NodeConfig
from quadpilot.runtime import SafetyMonitor, load_policy
from quadpilot.sitl.simulator_process import start_simulator

# the policy the digests were pinned with: models/hover as it was before it was retrained through delay
# (90e3a0d), kept as a fixture so that the pins guard the node and the simulator, not the shipped model
POLICY = Path(__file__).resolve().parents[1] / "data" / "policies" / "hover_before_delay.onnx"
HEARTBEAT = 0
FLIGHTS = {
    "plain": ((), 7),
    "noise_wind_gust": (("--imu-noise", "--estimator-noise", "--wind=1,-0.5,0", "--gust=0.5"), 3),
}
# The policy's products run in OpenBLAS, whose kernel (chosen for the CPU at run time) rounds the last
# bits differently from one kernel to another, so the digests are pinned per kernel, as threadpoolctl
# names it. "Cooperlake": the machine of the speed work (an AMD EPYC, family 25, with AVX-512 and
# BF16, the CPU its benchmark JSONs record; OpenBLAS takes its Cooperlake kernel for such a CPU), the
# code at 8e01231. "Haswell": an AMD EPYC without AVX-512, taken with the code at 3a1bf4b, which held the
# Cooperlake pins on the machine of the speed work. A machine with another kernel fails with its digests
# printed: pin them from a run of the reference code there (`python tests/sitl/test_lockstep_identity.py`).
PINNED_BY_KERNEL = {
    "Cooperlake": {
        "plain": {
            "flight": "10e35ad35ad92eb30c5efacbba5efa7bc509458542f3f0038da2557960a261e1",
            "from_simulator": "cccf3e46f613dcc105bbb0c206945d508e532cab9179ca7b4e5df58b43ff7498",
            "from_node": "6d2a389b6397e7b6d601238ee1a7fe890d4bfc02f9a1e6162f1b7cc8642a9745",
            "simulator": "82e462a5e56e20b8a442acb5e04b804e26ba3d23fc4041994e675583078c3752",
        },
        "noise_wind_gust": {
            "flight": "ea9cff33e1ffdf0237b81545e5bbad7ff1ac30d2bca28aa05090c1b40aa548ea",
            "from_simulator": "746bf0a724c89bdc2d59b631afb3de4c9fefd0fc487d106573a6fce332fd46b6",
            "from_node": "bcb05481b8f3062f536f66874252067dd74a23746d3a3d199d36fa857dfbd551",
            "simulator": "d5f21fee77c488aa497aa06cc990c9b8a5da9b6c980e443c4b288261dc419f22",
        },
    },
    "Haswell": {
        "plain": {
            "flight": "6dcb066faefe9944c6a540024d0ac429d3b3c65a59e8fc9a20cbb6d077e427f7",
            "from_simulator": "92e7a33997b37fd366e44d7bd0c9d07e7aa844ebe9475b97a4440ebb7c9c2fc8",
            "from_node": "b11aba315a4dedf326361ca03f82597d7e8187f190b2aa1524ebc67ac56ba91c",
            "simulator": "05598bc260ff73ca0877252f549ddc8a57dbeade42d9ef6a93ba5a3a582dd7f2",
        },
        "noise_wind_gust": {
            "flight": "e8ef32f7a55498caed655761083ab5eaad4fd30266684c693f73e6f6afe9d3f3",
            "from_simulator": "2d24e02a4f555867a5bf0cba8994c99dbb599666eed1cadf853dad5d03736d83",
            "from_node": "40e9e589bf17a567852725a52e506b0fceda4aa725e67d88a2ec48a1746c6f86",
            "simulator": "1b5597640df3967bcf3ec8248e586654c79b0a4a8afbdfa45c795573995dc211",
        },
    },
}


def _msgid(raw: bytes) -> int:
    return raw[5] if raw[0] == 0xFE else int.from_bytes(raw[7:10], "little")


def fly(flags: tuple, seed: int, duration_s: float = 3.0) -> dict:
    """Fly one episode; the four digests of the module docstring."""
    record = Path(tempfile.mkdtemp(prefix="lockstep-identity-")) / "sim.json"
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", "tcp:127.0.0.1:0"]
    proc, address = start_simulator([*cmd, "--episodes", "1", "--seed", str(seed), "--json", str(record), *flags])
    assert proc is not None, address
    frames: list[tuple[str, bytes]] = []
    try:
        monitor = SafetyMonitor(load_policy(POLICY, "numpy"))
        node = Node(NodeConfig(connect=address, duration_s=duration_s, gcs=None))
        log = node.fly(monitor, tap=lambda direction, raw: frames.append((direction, bytes(raw))))
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert log.failsafe is None and log.steps == round(duration_s * 100)
    summary = episode_summary(log, monitor.policy.info.control_period_s)
    flight = hashlib.sha256()
    for part in (log.states, log.targets, log.commands):
        flight.update(np.asarray(part).tobytes())
    flight.update(json.dumps(summary, sort_keys=True).encode())
    sim = hashlib.sha256(b"".join(raw for d, raw in frames if d == "in"))
    node = hashlib.sha256()
    for d, raw in frames:
        if d == "out" and _msgid(raw) != HEARTBEAT:
            node.update(raw[:4] + raw[5:-2])  # MAVLink 2: all but the sequence number (and the CRC over it)
    (episode,) = json.loads(record.read_text())["records"]
    shutil.rmtree(record.parent)
    for host_dependent in ("peer", "wall_time_s"):
        episode.pop(host_dependent)
    # fields the record gained after the pins (the landing, the fastest descent, motors off in the air,
    # the optional truth): what the pinned fields already determine, left out so the pins still hold
    for added in ("touchdown", "max_descent_speed", "motors_off_airborne_steps", "truth"):
        episode.pop(added, None)
    own = hashlib.sha256(json.dumps(episode, sort_keys=True).encode())
    return {
        "flight": flight.hexdigest(),
        "from_simulator": sim.hexdigest(),
        "from_node": node.hexdigest(),
        "simulator": own.hexdigest(),
    }


@pytest.fixture(scope="module")
def flown() -> tuple[str, dict]:
    """Both flights, flown by a fresh interpreter (this file run as a script): what earlier tests left
    in this process (a BLAS thread limit, an imported library's settings) cannot reach the node."""
    done = subprocess.run([sys.executable, __file__], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


@pytest.mark.sitl
@pytest.mark.parametrize("name", sorted(FLIGHTS))
def test_a_lockstep_flight_is_the_same_flight_and_the_same_bytes(name, flown):
    kernel, got = flown["kernel"], flown["flights"][name]
    assert kernel in PINNED_BY_KERNEL, f"no digests pinned for OpenBLAS kernel {kernel!r}; this machine's: {got}"
    assert got == PINNED_BY_KERNEL[kernel][name]


def blas_kernel() -> str:
    """The OpenBLAS kernel numpy runs on this CPU (threadpoolctl's `architecture`)."""
    from threadpoolctl import threadpool_info

    # numpy's own OpenBLAS (scipy or torch, once imported, bring others)
    (blas,) = [i for i in threadpool_info() if i["internal_api"] == "openblas" and "numpy" in i["filepath"]]
    return blas["architecture"]


if __name__ == "__main__":  # print the digests of the code on the import path (to pin them)
    print(json.dumps({"kernel": blas_kernel(), "flights": {name: fly(*FLIGHTS[name]) for name in FLIGHTS}}, indent=1))

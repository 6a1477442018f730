"""A flight of quad-sitl's: the node set up and flown (`fly`, the one place that builds the safety
monitor, the node's configuration, the MAVLink log and the impairment proxy, for quad-sitl's own
simulator and for `--node-only` alike), the episodes flown against quad-sitl's own simulator process
and their summary (`fly_with_simulator`), and the pictures (`draw`)."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from quadpilot.atomic_files import atomic_write
from quadpilot.console import os_error_line
from quadpilot.sitl import simulator_process
from quadpilot.sitl.options import COMMANDED_DURATION_S, LOCKSTEP_COMMANDED_WARNING, commanded
from quadpilot.sitl.summary import commanded_summary, maneuver_summary, print_summary, summarise


@dataclasses.dataclass
class Flown:
    """What `fly` flew: the episodes' logs, with the safety monitor, the node's configuration, the
    impairment proxy (stopped) and the MAVLink log (closed) they were flown with."""

    monitor: object
    config: object
    proxy: object | None
    tlog: object | None = None
    logs: list = dataclasses.field(default_factory=list)
    interrupted: bool = False
    """Ctrl-C during an episode: the episodes before it are in `logs`."""


def _os_error(e: OSError) -> int:
    print(f"quad-sitl: error: {os_error_line(e)}", file=sys.stderr)
    return 1


def fly(args, policy, key: bytes | None, connect: str, duration_s: float, targets, episodes: int = 1, **config):
    """Fly `episodes` episodes of `duration_s` s against the simulator at `connect`, through the
    impairment proxy with --link-impair, logging every MAVLink message to --tlog: a `Flown`, or the
    exit code after one line (a NodeError, an output that cannot be written, a proxy that cannot
    relay). `targets(k)`: episode k's targets (None: the node's own); `config`: NodeConfig fields
    beyond those every flight takes from the flags."""
    from quadpilot.autopilot.node import Node, NodeError
    from quadpilot.autopilot.node_config import NodeConfig
    from quadpilot.link.impair import ImpairSpecError
    from quadpilot.runtime import SafetyMonitor

    monitor = SafetyMonitor(policy)
    try:
        proxy, connect = start_impair(args, connect)  # --link-impair: the node talks through it
    except ImpairSpecError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 2
    cfg = NodeConfig(
        connect=connect,
        duration_s=duration_s,
        lockstep=args.lockstep,
        gcs=None if args.gcs.lower() == "none" else args.gcs,
        signing_key=key,
        spin_s=args.spin_us / 1e6,
        state_loss=args.state_loss,
        **config,
    )
    flown = Flown(monitor, cfg, proxy)
    try:
        if args.tlog is not None:
            from quadpilot.link.tlog import TlogWriter

            flown.tlog = TlogWriter(args.tlog)
        node = Node(cfg)
        tap = None if flown.tlog is None else flown.tlog.tap
        try:
            for k in range(episodes):
                flown.logs.append(node.fly(monitor, tap=tap, targets=targets(k)))
        except KeyboardInterrupt:
            flown.interrupted = True
    except NodeError as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # an output that could be written a moment ago cannot now (disk full, removed)
        return _os_error(e)
    finally:
        if flown.tlog is not None:
            flown.tlog.close()
        if proxy is not None:
            proxy.stop()
    return flown


def fly_with_simulator(args, rest: list[str], policy, policy_path: Path, task: str, key: bytes | None) -> int:
    """Start the simulator process, fly, summarise. The simulator is stopped on every way out of here
    (return, exception, Ctrl-C, SIGTERM: `cli.main` raises on it)."""
    from quadpilot.core.mission import default_duration_s, plan_episode

    is_commanded = commanded(args)
    if is_commanded and args.lockstep:
        print(LOCKSTEP_COMMANDED_WARNING, file=sys.stderr)
    maneuver = args.maneuver
    duration = args.duration or (
        COMMANDED_DURATION_S if is_commanded else maneuver.duration_s if maneuver else default_duration_s(task)
    )

    def targets(k: int):
        mission = plan_episode(task, args.seed, k, policy.info.control_period_s)
        return None if is_commanded else (maneuver or mission).target_at  # commanded: the ground station's

    sim = None
    try:
        listen = args.listen or f"tcp:127.0.0.1:{simulator_process.free_port()}"
        sim = simulator_process.SimulatorProcess(simulator_process.simulator_command(args, listen, task, rest))
        ok, address = sim.wait_listening(30.0)
        if not ok:
            print(f"quad-sitl: error: the simulator did not start: {address}", file=sys.stderr)
            return 1
        start = "landed" if is_commanded else "air"
        flown = fly(args, policy, key, address, duration, targets, args.episodes, command=is_commanded, start=start)
    except OSError as e:  # the simulator process or the proxy could not start
        return _os_error(e)
    finally:
        if sim is not None:
            sim.stop()
    if isinstance(flown, int):
        return flown
    if flown.interrupted:
        print("quad-sitl: interrupted; summary of the episodes flown so far", file=sys.stderr)
    logs, monitor, proxy, tlog = flown.logs, flown.monitor, flown.proxy, flown.tlog
    refused = next((log.failsafe for log in logs if (log.failsafe or "").startswith("refusing to arm")), None)
    if refused is not None:  # nothing was flown: one line, not a summary of nothing
        print(f"quad-sitl: {refused} (HIL_SENSOR arrives, HIL_STATE_QUATERNION does not)", file=sys.stderr)
        return 1
    summary = summarise(logs, policy.info.control_period_s, task)
    summary["task"] = task
    if maneuver is not None:
        summary.update(maneuver_summary(maneuver, logs, policy.info.control_period_s))
    summary["policy"] = str(policy_path)
    summary["backend"] = args.backend
    summary["monitor_events"] = dict(monitor.events)
    if proxy is not None:
        summary["link_impair"] = proxy.summary()
    if is_commanded:
        summary["commanded"] = commanded_summary(logs)
    print_summary(summary, policy_path)
    if maneuver is not None:
        from quadpilot.core.maneuver import summary_line

        print(summary_line(summary))
    try:
        if args.json:
            atomic_write(args.json, lambda f: f.write((json.dumps(summary, indent=2) + "\n").encode()))
    except OSError as e:
        print(f"quad-sitl: error: {args.json}: {e.strerror or e}", file=sys.stderr)
        return 1
    if tlog is not None:
        print(f"  MAVLink log             {args.tlog} ({tlog.messages:,} messages; read it with mavlogdump.py)")
    code = draw(args, logs, policy.info.control_period_s)
    rate = summary["success_rate"]
    if code == 0 and args.min_success > 0 and not rate >= args.min_success:  # NaN (nothing flown) fails too
        what = f"{rate:.0%}" if math.isfinite(rate) else "nothing"
        print(
            f"quad-sitl: success rate {what} of {summary['episodes']} episodes is below "
            f"--min-success {args.min_success:g}",
            file=sys.stderr,
        )
        return 1
    return code


def flight_traces(logs):
    from quadpilot.viz import FlightTrace

    return [
        FlightTrace.from_episode_log(log, np.asarray(log.targets), label=f"episode {i}")
        for i, log in enumerate(logs)
        if log.states
    ]


def draw(args, logs, period: float) -> int:
    if args.plot is None and args.video is None:
        return 0
    from quadpilot.viz import VizUnavailable, plot_flight, render_flight_video

    traces = flight_traces(logs)
    if not traces:
        print("quad-sitl: nothing flown, nothing to draw", file=sys.stderr)
        return 1
    try:
        if args.plot is not None:
            plot_flight(traces, args.plot, title=f"quad-sitl: {args.policy}")
            print(f"  plot                    {args.plot}")
        if args.video is not None:
            render_flight_video(traces[0], args.video)
            print(f"  video                   {args.video}")
    except VizUnavailable as e:
        print(f"quad-sitl: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # the picture could not be written (the disk filled since the check)
        print(f"quad-sitl: error: {os_error_line(e)}", file=sys.stderr)
        return 1
    return 0


def start_impair(args, address: str):
    """(proxy, the address the node connects to): with --link-impair, `link.impair.start_proxy`
    relaying to `address`, seeded by the spec or --seed; else (None, address)."""
    if args.link_impair is None:
        return None, address
    from quadpilot.link.impair import start_proxy

    return start_proxy(args.link_impair, address, getattr(args, "seed", 0))

"""quad-sitl's simulator process: `python -m quadpilot.simulator --sim-only`, started so that it dies
with quad-sitl, waited for until it listens, and stopped on every way out."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys


def simulator_command(args, listen: str, task: str, rest: list[str]) -> list[str]:
    """The simulator process's command line: quad-sitl's flags that the simulator shares (the
    episodes, the seed, the task, the clock, the spin, the key) and `rest`, its own flags."""
    cmd = [sys.executable, "-m", "quadpilot.simulator", "--sim-only", "--listen", listen]
    cmd += ["--episodes", str(args.episodes), "--seed", str(args.seed), "--task", task]
    cmd += ["--lockstep" if args.lockstep else "--realtime", f"--spin-us={args.spin_us}", *rest]
    if args.key is not None:
        cmd += ["--key", str(args.key)]
    return cmd


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def die_with_parent():
    """A preexec_fn (Linux) that has the kernel SIGKILL the simulator when quad-sitl dies, however
    it dies (prctl(2) PR_SET_PDEATHSIG): the second net under `SimulatorProcess.stop` in a finally, for a
    kill -9 that runs no Python. None elsewhere."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here: the child only calls it
    except (OSError, AttributeError):
        return None
    parent = os.getpid()
    pr_set_pdeathsig = 1  # <linux/prctl.h>

    def child() -> None:
        prctl(pr_set_pdeathsig, signal.SIGKILL, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the prctl took effect
            os.kill(os.getpid(), signal.SIGKILL)

    return child


class SimulatorProcess:
    """The simulator process (`python -m quadpilot.simulator`), started so that it dies with
    this one: `stop()` in a finally on every exit path, and PR_SET_PDEATHSIG for the paths that run
    no Python (kill -9)."""

    def __init__(self, cmd: list[str]) -> None:
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=die_with_parent()
        )
        self._drains: list = []

    def wait_listening(self, timeout_s: float) -> tuple[bool, str]:
        """(True, address it listens on) once it says so; (False, why not) if it exits first (e.g.
        its port is taken) or stays silent for `timeout_s`."""
        import select
        import threading

        proc = self.proc
        ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
        line = proc.stdout.readline() if ready else ""
        if "listening on" not in line:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
            err = proc.stderr.read().strip()  # it has exited: its last words are all there
            self._close_pipes()
            last = err.splitlines()[-1] if err else f"no answer within {timeout_s:g} s"
            return False, last.removeprefix("quad-sitl: error: ")

        def drain(stream):  # per-episode lines: read them so the pipe never fills and blocks it
            for _ in stream:
                pass

        for stream in (proc.stdout, proc.stderr):
            t = threading.Thread(target=drain, args=(stream,), daemon=True)
            t.start()
            self._drains.append(t)
        return True, line.split("listening on ", 1)[1].split()[0]

    def stop(self) -> None:
        """Terminate it (SIGTERM, then SIGKILL after 5 s) and wait for it; idempotent."""
        proc = self.proc
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for t in self._drains:
            t.join(timeout=1)
        if not self._drains or not any(t.is_alive() for t in self._drains):
            self._close_pipes()

    def _close_pipes(self) -> None:
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None and not stream.closed:
                stream.close()


def start_simulator(cmd: list[str], timeout_s: float = 30.0):
    """Start the simulator process and wait until it listens: (process, address it listens on),
    or (None, why not) if it exits first (e.g. its port is taken) or stays silent for `timeout_s`.
    It dies with this process (see `SimulatorProcess`)."""
    sim = SimulatorProcess(cmd)
    ok, what = sim.wait_listening(timeout_s)
    return (sim.proc, what) if ok else (None, what)

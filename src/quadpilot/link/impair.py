"""A link we can make bad: a MAVLink impairment proxy between the node and the simulator, on loopback.

    quad-sitl --realtime --link-impair loss=5%,delay=20ms,jitter=5ms,reorder=1%,duplicate=1%,burst=0.5%,seed=3

The proxy listens on a loopback TCP port, and for every connection it accepts (the node, one per
episode) it opens one to the simulator and relays both ways; for a simulator on UDP it listens on a
loopback UDP port, relays to the simulator from one socket of its own, and back to whoever sent
last (a node's new episode is a new socket), each datagram parsed on its own. What it relays are whole MAVLink
frames, as on a serial or UDP MAVLink link: the byte stream is cut into frames by pymavlink's parser
(either version, signed or not: a frame is relayed byte for byte, its signature included), and each
frame is lost, delayed, duplicated or held back whole. Bytes the parser cannot make a frame of
(garbage, a bad CRC) are relayed as they came, unimpaired, and counted as `unparsed`.

The spec, comma-separated KEY=VALUE (`parse_spec`; each impairment applies to each direction alone):

- `loss=P`: each frame is dropped with probability P (`5%` or `0.05`), independently.
- `burst=P`, `burst-len=N`: burst loss, the Gilbert model (E. N. Gilbert, "Capacity of a burst-noise
  channel", Bell System Technical Journal 39, 1960; the two-state chain Elliott later generalised):
  in the good state frames pass, in the bad state every frame is lost; good → bad with probability
  P per frame, bad → good with probability 1/N, so bursts last N frames on average (default 5).
- `delay=T`: every frame arrives T later (`20ms`, `0.02s`, `500us`).
- `jitter=T`: plus a delay uniform in [−T, +T] per frame (the total never below 0). Frames keep their
  order (a frame never overtakes the one before it, as on a serial line): jitter alone does not
  reorder. `reorder` does.
- `reorder=P`: a frame is held back with probability P and sent right after the next frame of its
  direction (or after `REORDER_HOLD_S` if none comes).
- `duplicate=P`: a frame is sent twice with probability P.
- `seed=N`: the seed of the random draws (default: the caller's, quad-sitl's --seed). Each direction
  draws from its own generator, so the same frames in the same order meet the same fate.

`Proxy.counts` says what it did, per direction (`up`: node → simulator, `down`: simulator → node).
Only loopback addresses, on both sides: the proxy is a test instrument, not a router. A duplicated
frame goes out as two (two datagrams over UDP).
"""

from __future__ import annotations

import dataclasses
import heapq
import ipaddress
import random
import re
import select
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, fields

from pymavlink.dialects.v20 import common as mavlink2

from .transport import Address, parse_address

REORDER_HOLD_S = 0.05
"""s, longest a frame held back for reordering waits for the next frame of its direction."""
MAX_DELAY_S = 10.0
"""s, the largest delay (plus jitter) the spec accepts."""
STOP_CHECK_S = 0.05
"""s, longest the relay loop goes without looking at `stop()`."""
DIRECTIONS = ("up", "down")
"""`up`: node → simulator (actuator commands, heartbeats); `down`: simulator → node (states, sensors)."""
COUNTERS = ("frames", "relayed", "lost", "lost_burst", "delayed", "duplicated", "reordered", "unparsed")
"""What `Proxy.counts` counts per direction: frames parsed, frames sent on (duplicates included),
lost at random, lost in a burst, delayed (delay or jitter > 0), sent twice, held back, and chunks
of bytes relayed unparsed."""
EXPECTED = (
    "expected KEY=VALUE[,KEY=VALUE...] with loss=P, burst=P, burst-len=N, delay=T, jitter=T, reorder=P, "
    "duplicate=P, seed=N (P: 5% or 0.05; T: 20ms, 0.02s or 500us), e.g. loss=5%,delay=20ms,jitter=5ms"
)


class ImpairSpecError(ValueError):
    """A --link-impair spec that cannot be used: one line naming what was wrong and what is expected."""


@dataclass(frozen=True)
class Impairment:
    """What the proxy does to every frame (see the module docstring)."""

    loss: float = 0.0
    burst: float = 0.0
    burst_len: float = 5.0
    delay_s: float = 0.0
    jitter_s: float = 0.0
    reorder: float = 0.0
    duplicate: float = 0.0
    seed: int | None = None

    def __str__(self) -> str:
        parts = []
        for f in fields(self):
            v = getattr(self, f.name)
            if v == f.default or v is None:
                continue
            key = f.name.removesuffix("_s").replace("_", "-")
            if f.name in ("loss", "burst", "reorder", "duplicate"):
                parts.append(f"{key}={v * 100:g}%")
            elif f.name.endswith("_s"):
                parts.append(f"{key}={v * 1e3:g}ms")
            else:
                parts.append(f"{key}={v:g}")
        return ",".join(parts) or "none"


_NUMBER = r"[0-9]+(?:\.[0-9]*)?(?:[eE][-+]?[0-9]+)?|\.[0-9]+(?:[eE][-+]?[0-9]+)?"
_TIME = re.compile(rf"^({_NUMBER})(ms|s|us|µs)$")
_PROB = re.compile(rf"^({_NUMBER})(%?)$")
_KEYS = {
    "loss": "loss",
    "burst": "burst",
    "burst-len": "burst_len",
    "delay": "delay_s",
    "jitter": "jitter_s",
    "reorder": "reorder",
    "duplicate": "duplicate",
    "seed": "seed",
}


def _probability(key: str, text: str) -> float:
    m = _PROB.match(text)
    if not m:
        raise ImpairSpecError(f"{key}={text!r} is not a probability (5% or 0.05)")
    v = float(m.group(1)) / (100.0 if m.group(2) else 1.0)
    if not 0.0 <= v <= 1.0:
        raise ImpairSpecError(f"{key}={text} is outside 0..100 %")
    return v


def _time(key: str, text: str) -> float:
    m = _TIME.match(text)
    if not m:
        raise ImpairSpecError(f"{key}={text!r} is not a time with its unit (20ms, 0.02s or 500us)")
    v = float(m.group(1)) * {"ms": 1e-3, "s": 1.0, "us": 1e-6, "µs": 1e-6}[m.group(2)]
    if not v <= MAX_DELAY_S:
        raise ImpairSpecError(f"{key}={text} is beyond {MAX_DELAY_S:g} s")
    return v


def parse_spec(text: str, default_seed: int | None = None) -> Impairment:
    """`loss=5%,delay=20ms,...` → Impairment; ImpairSpecError (one line: what, and what is expected)."""
    values: dict = {}
    try:
        if not text.strip():
            raise ImpairSpecError("empty spec")
        for item in text.split(","):
            key, sep, value = item.strip().partition("=")
            key, value = key.strip().lower(), value.strip()
            if not sep or not key or not value:
                raise ImpairSpecError(f"{item.strip()!r} is not KEY=VALUE")
            if key not in _KEYS:
                raise ImpairSpecError(f"unknown impairment {key!r}")
            name = _KEYS[key]
            if name in values:
                raise ImpairSpecError(f"{key} given twice")
            if name == "seed":
                if not value.isdigit() or int(value) >= 2**63:
                    raise ImpairSpecError(f"seed={value!r} is not an integer in 0..2^63-1")
                values[name] = int(value)
            elif name == "burst_len":
                try:
                    n = float(value)
                except ValueError:
                    n = float("nan")
                if not 1.0 <= n <= 1e6:  # False for NaN too
                    raise ImpairSpecError(f"burst-len={value!r} is not a mean burst length of 1 to 1e6 frames")
                values[name] = n
            elif name.endswith("_s"):
                values[name] = _time(key, value)
            else:
                values[name] = _probability(key, value)
    except ImpairSpecError as e:
        raise ImpairSpecError(f"--link-impair {text!r}: {e}; {EXPECTED}") from None
    values.setdefault("seed", default_seed)
    return Impairment(**values)


def check_loopback(address: Address, what: str) -> None:
    """ImpairSpecError unless `address` is a loopback address (127.0.0.0/8, ::1, localhost)."""
    host = address.host
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise ImpairSpecError(
            f"--link-impair: {what} {address} is not a loopback address; the impairment proxy relays "
            "only between processes on this machine (tcp:127.0.0.1:PORT or udp:127.0.0.1:PORT)"
        )


class _Direction:
    """One direction of one connection: parser, fate of each frame, and the schedule of what is due.
    `send(raw)` sends one frame (or chunk of unparsed bytes) on."""

    def __init__(self, imp: Impairment, rng: random.Random, counts: Counter, send) -> None:
        self.imp, self.rng, self.counts, self.send = imp, rng, counts, send
        self.parser = _parser()
        self.bad = False  # the Gilbert chain's state
        self.last_due = 0.0
        self.held: tuple[bytes, int] | None = None  # (frame, copies)
        self.held_until = 0.0

    def frames(self, data: bytes, datagram: bool = False) -> list[tuple[bytes, bool]]:
        """(raw bytes, is a frame) for what `data` completes; a `datagram` ends where it ends (a torn
        frame at its end is passed on as unparsed bytes, and the next datagram starts afresh)."""
        out = []
        for m in self.parser.parse_buffer(data) or ():
            if m.get_type() == "BAD_DATA":
                out.append((bytes(m.data), False))
            else:
                out.append((bytes(m.get_msgbuf()), True))
        if datagram and self.parser.buf_len():
            out.append((bytes(self.parser.buf[self.parser.buf_index :]), False))
            self.parser = _parser()
        return out

    def fate(self, raw: bytes, now: float, queue: list, seq) -> None:
        """Decide what happens to one frame and put what is to be sent on `queue` (due time, seq, ...)."""
        imp, rng, c = self.imp, self.rng, self.counts
        c["frames"] += 1
        # every draw is made for every frame, whatever the earlier ones decided: the same frames
        # meet the same fate whatever the spec's other settings are
        u_loss, u_gilbert, u_jitter, u_reorder, u_dup = (rng.random() for _ in range(5))
        if imp.burst > 0.0:
            self.bad = (u_gilbert >= 1.0 / imp.burst_len) if self.bad else (u_gilbert < imp.burst)
        if self.bad:
            c["lost_burst"] += 1
            return
        if u_loss < imp.loss:
            c["lost"] += 1
            return
        delay = imp.delay_s + (2.0 * u_jitter - 1.0) * imp.jitter_s
        due = max(now + max(delay, 0.0), self.last_due)  # never overtakes the frame before it
        if delay > 0.0:
            c["delayed"] += 1
        self.last_due = due
        copies = 2 if u_dup < imp.duplicate else 1
        c["duplicated"] += copies - 1
        if self.held is None and u_reorder < imp.reorder:
            c["reordered"] += 1
            self.held, self.held_until = (raw, copies), due + REORDER_HOLD_S
            return
        heapq.heappush(queue, (due, next(seq), self, raw, copies))
        self.release(due, queue, seq)

    def release(self, due: float, queue: list, seq) -> None:
        """Send the frame held back (after the one just scheduled at `due`)."""
        if self.held is not None:
            heapq.heappush(queue, (due, next(seq), self, *self.held))
            self.held = None

    def pass_through(self, raw: bytes, now: float, queue: list, seq) -> None:
        self.counts["unparsed"] += 1
        due = max(now, self.last_due)
        heapq.heappush(queue, (due, next(seq), self, raw, 0))  # 0 copies: sent once, counted as no frame


def _parser():
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    return parser


class Proxy:
    """The impairment proxy: `start()` listens on a free loopback port (`address`) and relays to
    `upstream` in a thread, one connection at a time; `stop()` ends it. `counts[direction]` are the
    `COUNTERS`, over every connection so far."""

    def __init__(self, upstream: str | Address, impairment: Impairment) -> None:
        self.upstream = upstream if isinstance(upstream, Address) else parse_address(upstream, "simulator address")
        check_loopback(self.upstream, "the simulator address")
        self.impairment = impairment
        seed = impairment.seed or 0
        self._rngs = {d: random.Random(f"{seed}/{d}") for d in DIRECTIONS}
        self.counts = {d: Counter({k: 0 for k in COUNTERS}) for d in DIRECTIONS}
        self.connections = 0
        self.errors: list[str] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: socket.socket | None = None
        self.address: Address | None = None

    def start(self) -> Address:
        host = "::1" if ":" in self.upstream.host else "127.0.0.1"
        family = socket.AF_INET6 if host == "::1" else socket.AF_INET
        if self.upstream.protocol == "tcp":
            sock = socket.socket(family, socket.SOCK_STREAM)
            sock.bind((host, 0))
            sock.listen(1)
            run = self._run
        else:
            sock = socket.socket(family, socket.SOCK_DGRAM)
            sock.bind((host, 0))
            run = self._run_udp
        self._listener = sock
        self.address = Address(self.upstream.protocol, host, sock.getsockname()[1])
        self._thread = threading.Thread(target=run, name="link-impair", daemon=True)
        self._thread.start()
        return self.address

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def __enter__(self) -> Proxy:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def summary(self) -> dict:
        """What it did: the spec and the counts per direction (JSON-ready)."""
        return {"spec": str(self.impairment), "connections": self.connections} | {
            d: dict(self.counts[d]) for d in DIRECTIONS
        }

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], STOP_CHECK_S)
            if not ready:
                continue
            try:
                client, _ = self._listener.accept()
            except OSError:
                continue
            try:
                server = socket.create_connection((self.upstream.host, self.upstream.port), timeout=5.0)
            except OSError as e:
                self.errors.append(f"cannot reach {self.upstream}: {e.strerror or e}")
                client.close()
                continue
            self.connections += 1
            try:
                self._relay(client, server)
            finally:
                client.close()
                server.close()

    def _relay(self, client: socket.socket, server: socket.socket) -> None:
        for sock in (client, server):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(1.0)  # a send to a peer that has stopped reading ends the connection
        imp = self.impairment
        ways = {
            client: _Direction(imp, self._rngs["up"], self.counts["up"], server.sendall),
            server: _Direction(imp, self._rngs["down"], self.counts["down"], client.sendall),
        }

        def recv(sock):
            data = sock.recv(65536)
            return data or None  # b"": that side closed, and the episode is over

        self._loop(ways, recv, datagram=False)

    def _run_udp(self) -> None:
        """UDP: one socket faces the node (the latest sender is the node: a new episode is a new
        socket), one is connected to the simulator; each datagram is parsed on its own."""
        front = self._listener
        back = socket.socket(front.family, socket.SOCK_DGRAM)
        back.bind((self.address.host, 0))
        back.connect((self.upstream.host, self.upstream.port))
        client: list = [None]
        imp = self.impairment

        def to_node(raw: bytes) -> None:
            if client[0] is not None:
                front.sendto(raw, client[0])

        ways = {
            front: _Direction(imp, self._rngs["up"], self.counts["up"], back.send),
            back: _Direction(imp, self._rngs["down"], self.counts["down"], to_node),
        }

        def recv(sock):
            try:
                data, sender = sock.recvfrom(65536)
            except OSError:  # an ICMP port-unreachable report, say: UDP has no connection to lose
                return b""
            if sock is front and sender != client[0]:
                client[0] = sender
                self.connections += 1
            return data

        try:
            self._loop(ways, recv, datagram=True)
        finally:
            back.close()

    def _loop(self, ways: dict, recv, datagram: bool) -> None:
        """Relay until `stop()` or `recv` says a side closed (None): what is due goes out, what
        arrives is cut into frames and given its fate."""
        queue: list = []
        seq = iter(range(1 << 62))
        while not self._stop.is_set():
            now = time.monotonic()
            while queue and queue[0][0] <= now:
                _, _, way, raw, copies = heapq.heappop(queue)
                try:
                    for _ in range(max(copies, 1)):
                        way.send(raw)
                except OSError:
                    if not datagram:
                        return
                way.counts["relayed"] += copies
            for way in ways.values():  # a frame held back that no next frame came to release
                if way.held is not None and way.held_until <= now:
                    way.release(now, queue, seq)
            due = [queue[0][0]] if queue else []
            due += [w.held_until for w in ways.values() if w.held is not None]
            wait = min([STOP_CHECK_S, *(max(d - now, 0.0) for d in due)])
            ready, _, _ = select.select(list(ways), [], [], wait)
            for sock in ready:
                try:
                    data = recv(sock)
                except OSError:
                    return
                if data is None:
                    return  # what is still queued is lost with the connection
                way, now = ways[sock], time.monotonic()
                for raw, is_frame in way.frames(data, datagram):
                    if is_frame:
                        way.fate(raw, now, queue, seq)
                    else:
                        way.pass_through(raw, now, queue, seq)


def start_proxy(spec: Impairment, address: str, seed: int = 0) -> tuple[Proxy, str]:
    """(a started proxy relaying to `address` (loopback only: ImpairSpecError otherwise), the address
    to connect to instead); the spec's own seed, else `seed`."""
    if spec.seed is None:
        spec = dataclasses.replace(spec, seed=seed)
    proxy = Proxy(address, spec)
    return proxy, str(proxy.start())


def summary_line(s: dict) -> str:
    """What the proxy did (`Proxy.summary()`), for a flight's summary."""
    up, down = s["up"], s["down"]

    def way(c: dict) -> str:
        return (
            f"{c['frames']:,} frames: lost {c['lost']:,} + {c['lost_burst']:,} in bursts, delayed {c['delayed']:,}, "
            f"duplicated {c['duplicated']:,}, reordered {c['reordered']:,}"
        )

    return f"  link impaired ({s['spec']})  node→sim {way(up)}; sim→node {way(down)}"

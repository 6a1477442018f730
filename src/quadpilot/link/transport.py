"""MAVLink over sockets for both sides of SITL: one link per peer, batch reads, optional signing.

PX4's Simulator MAVLink API has the simulator listen (TCP 4560 in PX4's own simulators; UDP as an
option) and the autopilot connect. The simulator serves one episode per connection, which
pymavlink's `tcpin:` endpoint cannot do (it never reports the peer's EOF), and a control loop at
thousands of steps per second cannot afford `mavutil`'s byte-at-a-time reads. So the sockets live
here, and pymavlink does what it is made for: encoding, parsing, CRC and signatures.

- `Link.recv(timeout)` returns the next message: everything the socket holds is read in one
  system call and parsed in one go, and the messages are handed out one at a time. Garbage
  becomes BAD_DATA messages (`bad_data_reason` names why), never an exception.
- Outgoing messages are queued by the encoder and leave on `flush()`: one step, one TCP send.
- Links speak MAVLink 2 with the common message set from the first byte: pymavlink's automatic
  version switch would otherwise change the dialect of the whole process (`mavutil.set_dialect`
  and the `MAVLINK20` environment variable) the moment a MAVLink 2 byte arrives. A link can instead
  answer in the version its peer speaks (`Link.speak_as_peer`, for the autopilot facing a simulator
  it did not choose): MAVLink 1 until the peer's first message, then whatever the peer sends. It
  parses both versions either way (a MAVLink 2 parser reads MAVLink 1 frames; mavlink.io,
  "MAVLink 2", backwards compatibility), and its MAVLink 1 frames come from pymavlink's own
  MAVLink 1 codec, which leaves out the extension fields MAVLink 1 has no room for.
- A UDP link is pinned to one peer; datagrams from anyone else are counted and dropped, and a
  datagram is parsed on its own (a truncated one cannot swallow the start of the next).
- Signing (MAVLink 2 message signing, HMAC-SHA-256 truncated to 48 bits, per-stream timestamps
  for replay protection) with pymavlink's forged-timestamp lock-out fixed: see `SigningMAVLink`.
"""

from __future__ import annotations

import errno
import hashlib
import hmac
import ipaddress
import select
import socket
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink2

from .spin import SPIN_BACKOFF_MAX

SIM_SYSTEM_ID = 200
"""MAVLink system id of the simulator's messages: a system of its own, not the autopilot's (system 1,
`autopilot.node.NODE_SYSTEM_ID`), so a .tlog or a router tells the two apart; 200 stays clear of the
vehicle numbers (1, 2, ...) and of a ground station's 255."""
SIM_COMPONENT_ID = 200
"""MAVLink component id of the simulator's messages: MAV_COMP_ID_IMU (200), the component PX4's
Gazebo plugins send HIL_SENSOR as (PX4-SITL_gazebo-classic, src/mavlink_interface.cpp)."""
SEND_TIMEOUT_S = 1.0
"""s, a TCP peer that has not taken one step's messages in this long is treated as gone."""
READ_SIZE = 65536
"""Bytes read per system call (a datagram's maximum)."""
MAX_DATAGRAM = 4096
"""Bytes: a longer UDP datagram is dropped unparsed. MAVLink 2 frames are at most 280 bytes and
simulators send one or a few per datagram; parsing 64 KiB of junk in Python would stall a step."""
SIGNING_EPOCH_S = 1420070400
"""MAVLink 2 signing timestamps count 10 µs units since 2015-01-01 00:00 UTC."""


class SimulatorError(RuntimeError):
    """The simulator cannot do what it was asked (e.g. its listen address is taken)."""


class PeerClosed(Exception):
    """The peer closed the connection (TCP EOF or reset), or stopped taking our messages."""


@dataclass(frozen=True)
class Address:
    """A parsed address, `tcp:HOST:PORT` or `udp:HOST:PORT`."""

    protocol: str
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.protocol}:{self.host}:{self.port}"


def parse_address(text: str, what: str = "listen address") -> Address:
    """'tcp:127.0.0.1:4560' → Address('tcp', '127.0.0.1', 4560); a clear ValueError otherwise.
    Port 0 asks the operating system for a free port (see `Listener.address` after `bind`).
    pymavlink's `udpout:` is accepted as `udp:`."""
    parts = str(text).split(":")
    if len(parts) == 3 and parts[0] == "udpout":
        parts[0] = "udp"
    if len(parts) != 3 or parts[0] not in ("tcp", "udp") or not parts[1]:
        raise ValueError(f"{what} {text!r}: expected tcp:HOST:PORT or udp:HOST:PORT, e.g. tcp:127.0.0.1:4560")
    try:
        port = int(parts[2])
    except ValueError:
        raise ValueError(f"{what} {text!r}: port {parts[2]!r} is not an integer") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{what} {text!r}: port {port} is outside 0..65535")
    return Address(parts[0], parts[1], port)


# --- signing ---------------------------------------------------------------------------------
class SigningError(ValueError):
    """A signing key file that cannot be used; the message says what was expected."""


def read_key(path: str | Path) -> bytes:
    """A MAVLink 2 signing key from a file: 32 bytes raw, or 64 hex digits (whitespace ignored)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise SigningError(f"signing key {path}: {e.strerror or e}") from None
    if len(data) == 32:
        return data
    text = data.decode("ascii", "replace").strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text)
        except ValueError:
            pass
    raise SigningError(
        f"signing key {path}: expected 32 raw bytes or 64 hex digits, found {len(data)} bytes; "
        'make one with: python -c "import secrets; print(secrets.token_hex(32))" > key.hex'
    )


def signing_timestamp_now() -> int:
    """The current MAVLink 2 signing timestamp (10 µs units since 2015-01-01)."""
    return int((max(time.time(), SIGNING_EPOCH_S) - SIGNING_EPOCH_S) * 100_000)


class SigningMAVLink(mavlink2.MAVLink):
    """pymavlink's MAVLink 2 codec with its incoming-signature check fixed.

    pymavlink (2.4.50, `MAVLink.check_signature`) records a stream's timestamp *before* it checks
    the signature. One forged packet with a new (link id, system, component) and a timestamp far in
    the future is then enough to make every genuine packet of that stream "old" and rejected for
    good. Here the signature is verified first (constant-time comparison), and only an authentic
    packet moves the stream's timestamp. The rules themselves are the MAVLink 2 signing spec's
    (mavlink.io/en/guide/message_signing.html): a known stream's timestamp must increase (replay
    protection); a new stream's may be at most one minute behind ours.
    """

    last_reject = ""

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:
        signing = self.signing
        expected = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
            self.last_reject = "bad"
            return False
        tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
        timestamp = tlow + (thigh << 32)
        stream = (msgbuf[-13], srcSystem, srcComponent)
        last = signing.stream_timestamps.get(stream)
        if last is not None and timestamp <= last:
            self.last_reject = "replayed"
            return False
        if last is None and timestamp + 6_000_000 < signing.timestamp:  # 60 s in 10 µs units
            self.last_reject = "stale"
            return False
        signing.stream_timestamps[stream] = timestamp
        signing.timestamp = max(signing.timestamp, timestamp)
        return True


def new_codec(file, system: int, component: int) -> SigningMAVLink:
    """A MAVLink 2 common-dialect encoder/parser writing to `file`, parsing robustly (garbage
    becomes BAD_DATA messages instead of exceptions)."""
    mav = SigningMAVLink(file, srcSystem=system, srcComponent=component)
    mav.robust_parsing = True
    return mav


def bad_data_reason(msg) -> str:
    """Why pymavlink refused some bytes (a BAD_DATA message), as a counter name."""
    reason = str(getattr(msg, "reason", "")).lower()
    if reason.startswith("signature: "):  # set by Link: unsigned, bad, replayed or stale
        return "signature_" + reason[len("signature: ") :]
    if "signature" in reason:
        return "signature_bad"
    if "crc" in reason:
        return "bad_crc"
    if "prefix" in reason:
        return "garbage"  # one per run of stray bytes, as pymavlink reports them
    if "unknown" in reason:
        return "unknown_message_id"
    return "bad_data"


# --- links -----------------------------------------------------------------------------------
class Link:
    """A MAVLink connection to one peer over one socket (see the module docstring).

    `mav` is the pymavlink codec messages are sent with: `link.mav.heartbeat_send(...)` queues a
    message, `flush()` sends the queue. `recv(timeout)` returns the next message or None. `tap`, if
    set, is called with (direction "in"/"out", raw message bytes) for every message sent or received
    (a .tlog writer). `version` is the MAVLink version sent (2 unless `speak_as_peer`), `peer_version`
    the version of the peer's last message (None before its first).
    """

    def __init__(self, sock: socket.socket, label: str, system: int, component: int) -> None:
        sock.setblocking(False)
        self.port = sock
        self.peer_label = label
        self.system, self.component = system, component
        self.bytes_sent = 0
        self.tap = None
        self._out = bytearray()
        self._pending: deque = deque()
        self._codec = new_codec(self, system, component)  # parses both versions; sends MAVLink 2
        self._codec1 = None  # pymavlink's MAVLink 1 codec, made when first needed
        self.version = 2
        self.peer_version: int | None = None
        self._follow = False
        self.spin_s = 0.0
        self._spin_skip = self._spin_backoff = 0
        self._answer_due = False  # sent since the last message arrived: the next one answers it

    @property
    def mav(self):
        """The codec to send with: MAVLink 1 or 2 (`version`)."""
        return self._codec1 if self.version == 1 else self._codec

    def speak_as_peer(self) -> None:
        """Send MAVLink 1 until the peer's first message, then the version of its messages (and
        follow it if it changes). MAVLink 1 first because every MAVLink 2 parser reads it, and a
        PX4-API simulator (RotorPy's PX4Multirotor) waits for our HEARTBEAT before it sends
        anything. Not for a signed link: signing needs MAVLink 2 (ValueError)."""
        if self._codec.signing.sign_outgoing:
            raise ValueError("a signed link speaks MAVLink 2 only")
        self._follow = True
        self._use_version(self.peer_version or 1)

    def _use_version(self, version: int) -> None:
        if version == self.version:
            return
        if version == 1 and self._codec1 is None:
            self._codec1 = mavlink1.MAVLink(self, srcSystem=self.system, srcComponent=self.component)
        seq = self.mav.seq  # one sequence per sender, whatever the version of its frames
        self.version = version
        self.mav.seq = seq

    # The codec calls write() for every message it encodes.
    def write(self, buf) -> None:
        self._answer_due = True
        self._out += buf
        if self.tap is not None:
            self.tap("out", bytes(buf))

    def sign(self, key: bytes, link_id: int = 0, state=None) -> None:
        """Sign what we send and accept only authentic, fresh, signed messages (no unsigned
        fallback: pymavlink's `allow_unsigned_callback` would also admit badly signed ones).
        `state`: the `signing_state` of an earlier link to the same peer, carried over so that a
        packet recorded on that link cannot be replayed on this one."""
        if self._follow:
            raise ValueError("a link that speaks as its peer cannot sign: signing needs MAVLink 2")
        s = self._codec.signing if state is None else state
        self._codec.signing = s
        s.secret_key = bytes(key)
        s.sign_outgoing = True
        s.link_id = link_id
        s.allow_unsigned_callback = None
        s.timestamp = max(s.timestamp, signing_timestamp_now())

    @property
    def signing_state(self):
        return self._codec.signing

    def recv(self, timeout: float = 0.0):
        """The next message (possibly a BAD_DATA), or None if none arrived within `timeout` s.

        With a timeout it waits for the socket first and then reads: in lockstep the peer's answer
        is never there yet when the last message has been handled, and reading first would cost a
        system call (and an exception) that finds nothing, every step. With `spin_s` > 0 it polls
        first (`_spin`, `link.spin`)."""
        if self._pending:
            return self._pending.popleft()
        if timeout <= 0:
            self._fill()
            return self._pending.popleft() if self._pending else None
        deadline = time.monotonic() + timeout
        if self.spin_s > 0:
            if self._spin_skip:
                self._spin_skip -= 1
            else:
                msg = self._spin(min(deadline, time.monotonic() + self.spin_s))
                if msg is not None:
                    return msg
        left = deadline - time.monotonic()
        while left > 0:
            try:
                ready, _, _ = select.select([self.port], [], [], left)
            except (ValueError, OSError):  # a closed socket: reading says how (PeerClosed for TCP)
                self._fill()
                return self._pending.popleft() if self._pending else None
            if not ready:
                return None
            self._fill()
            if self._pending:
                return self._pending.popleft()
            left = deadline - time.monotonic()
        return None

    def _spin(self, end: float):
        """Read without sleeping until a message comes or the clock passes `end`. Only an answer to what
        was sent resets the backoff, not the tail of a step sent in two writes (RotorPy's PX4Multirotor)."""
        answer = self._answer_due
        while True:
            self._fill()
            if self._pending:
                if answer:
                    self._spin_backoff = 0
                return self._pending.popleft()
            if time.monotonic() >= end:
                self._spin_backoff = min(2 * self._spin_backoff or 1, SPIN_BACKOFF_MAX)
                self._spin_skip = self._spin_backoff
                return None

    def send_message(self, cls, args) -> None:
        """Queue one message: `mav.<message>_send(*args)` for pymavlink's MAVLink 2 message class `cls`
        (`args` in the order of its constructor, the order of `link.wire`'s `*_args`)."""
        getattr(self.mav, cls.msgname.lower() + "_send")(*args)

    def next_parsed(self):
        """The next message already read and parsed, or None: `recv` without a system call."""
        return self._pending.popleft() if self._pending else None

    def _parse(self, data: bytes) -> None:
        msgs = self._codec.parse_buffer(data)
        if msgs:
            self._answer_due = False
            for m in msgs:
                if m.get_type() != "BAD_DATA":
                    raw = m.get_msgbuf()
                    self.peer_version = 1 if raw[0] == mavlink2.PROTOCOL_MARKER_V1 else 2
                    if self.tap is not None:
                        self.tap("in", bytes(raw))
                elif m.reason == "Invalid signature":
                    raw = m.data
                    signed = len(raw) > 2 and raw[0] == mavlink2.PROTOCOL_MARKER_V2 and raw[2] & 0x01
                    m.reason = "signature: " + (self._codec.last_reject if signed else "unsigned")
            if self._follow and self.peer_version is not None:
                self._use_version(self.peer_version)
            self._pending.extend(msgs)

    def _fill(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def flush(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:
        try:
            self.port.close()
        except OSError:
            pass


class StreamLink(Link):
    """A TCP connection (accepted by a Listener, or made by `connect`). EOF or a reset raises
    PeerClosed out of `recv` once every message that arrived before it has been handed out."""

    def __init__(self, sock: socket.socket, label: str, system: int, component: int) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        super().__init__(sock, label, system, component)
        self._closed: str | None = None

    def _fill(self) -> None:
        if self._closed:
            raise PeerClosed(self._closed)
        try:
            data = self.port.recv(READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:  # ECONNRESET and friends
            self._closed = f"{self.peer_label}: {e.strerror or e}"
            raise PeerClosed(self._closed) from None
        if not data:
            self._closed = f"{self.peer_label} closed the connection"
            raise PeerClosed(self._closed)
        self._parse(data)

    def flush(self) -> None:
        """Send everything queued, waiting at most SEND_TIMEOUT_S for a peer that reads slowly."""
        if not self._out:
            return
        view, deadline = memoryview(bytes(self._out)), None
        self._out.clear()
        while view:
            try:
                n = self.port.send(view)
            except (BlockingIOError, InterruptedError):
                n = 0
            except OSError as e:
                raise PeerClosed(f"{self.peer_label}: {e.strerror or e}") from None
            view = view[n:]
            self.bytes_sent += n
            if view:
                deadline = deadline or time.monotonic() + SEND_TIMEOUT_S
                left = deadline - time.monotonic()
                if left <= 0:
                    raise PeerClosed(f"{self.peer_label} stopped reading (send blocked for {SEND_TIMEOUT_S} s)")
                select.select([], [self.port], [], left)


class DatagramLink(Link):
    """A UDP socket pinned to one peer. A listener pins the first sender of a valid message; a
    client is pinned to the address it connects to. Datagrams from anyone else are discarded and
    counted in `foreign_datagrams`. Each datagram is sent as it is written."""

    def __init__(self, sock: socket.socket, label: str, system: int, component: int, peer=None) -> None:
        super().__init__(sock, label, system, component)
        self.address = label
        self.peer: tuple | None = None
        self.last_sender: tuple | None = None
        self.foreign_datagrams = 0
        self.truncated_datagrams = 0
        self.oversized_datagrams = 0
        if peer is not None:
            self.pin(peer)

    def _fill(self) -> None:
        for _ in range(64):  # a bounded batch per call: a flood cannot starve the caller
            try:
                data, sender = self.port.recvfrom(READ_SIZE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. an ICMP port-unreachable report: UDP has no connection to lose
                return
            if self.peer is not None and sender[:2] != self.peer[:2]:
                self.foreign_datagrams += 1
                continue
            if len(data) > MAX_DATAGRAM:
                self.oversized_datagrams += 1
                continue
            self.last_sender = sender
            self._parse(data)
            if self._codec.buf_len():  # a datagram ends where its messages end: drop a torn tail
                self.truncated_datagrams += 1
                self._reset_parser()
            if self._pending and self.peer is None:
                return  # let the listener pin this sender before anything else is read

    def _reset_parser(self) -> None:
        signing, seq = self._codec.signing, self._codec.seq
        self._codec = new_codec(self, self.system, self.component)
        self._codec.signing, self._codec.seq = signing, seq

    def pin(self, peer: tuple | None) -> None:
        """Talk only to `peer`; None: wait for a new one, with a fresh parser (nothing half-read
        from the last peer carries over)."""
        if peer is None:
            self._reset_parser()
            self._pending.clear()
            self.spin_s, self._spin_skip, self._spin_backoff = 0.0, 0, 0  # a new peer starts afresh
        self.peer = peer
        self.peer_label = "udp:{}:{}".format(*peer[:2]) if peer else self.address

    def write(self, buf) -> None:
        self._answer_due = True
        if self.tap is not None:
            self.tap("out", bytes(buf))
        if self.peer is None:
            return
        try:
            self.port.sendto(buf, self.peer)
            self.bytes_sent += len(buf)
        except OSError:  # best effort, like any UDP simulator; timeouts notice a dead peer
            pass

    def flush(self) -> None:
        pass


def _bind_socket(a: Address, kind: int, listen: bool) -> socket.socket:
    try:
        infos = socket.getaddrinfo(a.host, a.port, socket.AF_UNSPEC, kind)
    except socket.gaierror as e:
        raise SimulatorError(f"cannot listen on {a}: unknown host {a.host!r} ({e.strerror})") from None
    family, _, _, _, sockaddr = infos[0]
    sock = socket.socket(family, kind)
    try:
        if kind == socket.SOCK_STREAM:
            # Rebinding while old connections sit in TIME_WAIT is fine; a live listener on the
            # port still makes bind fail. (Not for UDP: there it would let two sockets share it.)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(sockaddr)
        if listen:
            sock.listen(1)
    except OSError as e:
        sock.close()
        if e.errno == errno.EADDRINUSE:
            raise SimulatorError(
                f"cannot listen on {a}: address already in use (another simulator, or PX4's own, is "
                f"probably running; stop it or choose another port, e.g. --listen {a.protocol}:{a.host}:"
                f"{a.port + 1 if a.port else 4561})"
            ) from None
        raise SimulatorError(f"cannot listen on {a}: {e.strerror or e}") from None
    sock.setblocking(False)
    return sock


class Listener:
    """The simulator's listening endpoint. `bind()` claims the address (SimulatorError if it
    cannot); `accept()` waits for the next peer; `close()` releases everything."""

    def __init__(self, address: str | Address, system: int = SIM_SYSTEM_ID, component: int = SIM_COMPONENT_ID):
        self.requested = address if isinstance(address, Address) else parse_address(address)
        self.system, self.component = system, component
        self.sock: socket.socket | None = None
        self.address: Address | None = None
        self._udp: DatagramLink | None = None

    def bind(self) -> Address:
        a = self.requested
        kind = socket.SOCK_STREAM if a.protocol == "tcp" else socket.SOCK_DGRAM
        self.sock = _bind_socket(a, kind, listen=a.protocol == "tcp")
        self.address = Address(a.protocol, a.host, self.sock.getsockname()[1])
        if a.protocol == "udp":
            self._udp = DatagramLink(self.sock, str(self.address), self.system, self.component)
        return self.address

    def accept(self, poll_s: float, should_stop) -> tuple[Link | None, list]:
        """Wait for the next peer until `should_stop()`; returns (link, first messages). For UDP
        the first valid message pins its sender as the peer and is returned for dispatch; BAD_DATA
        and the like before that are returned too, so the caller can count them."""
        assert self.sock is not None, "bind() first"
        if self.requested.protocol == "tcp":
            while not should_stop():
                ready, _, _ = select.select([self.sock], [], [], poll_s)
                if ready:
                    try:
                        conn, peer = self.sock.accept()
                    except (BlockingIOError, InterruptedError, ConnectionAbortedError):
                        continue
                    return StreamLink(conn, f"tcp:{peer[0]}:{peer[1]}", self.system, self.component), []
            return None, []
        link = self._udp
        link.pin(None)
        early = []
        while not should_stop():
            msg = link.recv(poll_s)
            if msg is None:
                continue
            early.append(msg)
            if msg.get_type() != "BAD_DATA" and link.last_sender is not None:
                link.pin(link.last_sender)
                early.extend(link._pending)
                link._pending.clear()
                return link, early
        return None, early

    def close(self) -> None:
        if self.sock is not None:
            try:
                self.sock.close()
            finally:
                self.sock = None


def connect(address: str | Address, system: int, component: int, timeout_s: float = 10.0) -> Link:
    """The autopilot side: connect to a simulator at `address` (tcp:HOST:PORT, or udp:HOST:PORT
    where the simulator listens on UDP), retrying until `timeout_s` while it starts.
    ConnectionError with the reason if it never answers."""
    a = address if isinstance(address, Address) else parse_address(address, "simulator address")
    if a.protocol == "udp":
        family, _, _, _, sockaddr = socket.getaddrinfo(a.host, a.port, socket.AF_UNSPEC, socket.SOCK_DGRAM)[0]
        sock = socket.socket(family, socket.SOCK_DGRAM)
        # A socket bound to loopback cannot reach another host, so bind to loopback only for a
        # loopback peer; otherwise to every interface (the link still takes datagrams only from
        # its peer: `DatagramLink` drops and counts the rest).
        loopback = ipaddress.ip_address(sockaddr[0]).is_loopback
        v4 = family == socket.AF_INET
        sock.bind((("127.0.0.1" if v4 else "::1") if loopback else ("0.0.0.0" if v4 else "::"), 0))
        return DatagramLink(sock, str(a), system, component, peer=sockaddr)
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            sock = socket.create_connection((a.host, a.port), timeout=max(0.05, deadline - time.monotonic()))
            return StreamLink(sock, str(a), system, component)
        except OSError as e:
            if time.monotonic() > deadline:
                raise ConnectionError(f"no simulator at {a} after {timeout_s:g} s ({e.strerror or e})") from None
            time.sleep(0.05)

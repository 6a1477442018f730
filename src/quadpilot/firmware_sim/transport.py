"""The simulator's sockets: a listening endpoint and one pymavlink link per peer.

PX4's Simulator MAVLink API has the simulator listen (TCP 4560 in PX4's own simulators; UDP as an
option) and the autopilot connect. pymavlink's `tcpin:` endpoint cannot serve one episode per
connection: it never reports the peer's EOF and keeps reading from the closed socket. So the
sockets live here, and each accepted peer is wrapped in a small `mavutil.mavfile` subclass, which
keeps pymavlink's own parser and its `recv_match(blocking=True, timeout=...)` loop.

Links speak MAVLink 2 with the common message set from the first byte: pymavlink's automatic
version switch would otherwise change the dialect of the whole process (`mavutil.set_dialect` and
the `MAVLINK20` environment variable) the moment a MAVLink 2 byte arrives.
"""

from __future__ import annotations

import errno
import select
import socket
import time
from dataclasses import dataclass

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

SIM_SYSTEM_ID = 1
"""MAVLink system id of the simulator's messages (the vehicle it simulates)."""
SIM_COMPONENT_ID = 1
"""MAVLink component id of the simulator's messages."""
SEND_TIMEOUT_S = 1.0
"""s, a TCP peer that has not taken one step's messages in this long is treated as gone."""


class SimulatorError(RuntimeError):
    """The simulator cannot do what it was asked (e.g. its listen address is taken)."""


class PeerClosed(Exception):
    """The peer closed the connection (TCP EOF or reset), or stopped taking our messages."""


@dataclass(frozen=True)
class Address:
    """A parsed listen address, `tcp:HOST:PORT` or `udp:HOST:PORT`."""

    protocol: str
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.protocol}:{self.host}:{self.port}"


def parse_address(text: str) -> Address:
    """'tcp:127.0.0.1:4560' → Address('tcp', '127.0.0.1', 4560); a clear ValueError otherwise.
    Port 0 asks the operating system for a free port (see `Listener.address` after `bind`)."""
    parts = str(text).split(":")
    if len(parts) != 3 or parts[0] not in ("tcp", "udp") or not parts[1]:
        raise ValueError(f"listen address {text!r}: expected tcp:HOST:PORT or udp:HOST:PORT, e.g. tcp:127.0.0.1:4560")
    try:
        port = int(parts[2])
    except ValueError:
        raise ValueError(f"listen address {text!r}: port {parts[2]!r} is not an integer") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"listen address {text!r}: port {port} is outside 0..65535")
    return Address(parts[0], parts[1], port)


def use_mavlink2(link: mavutil.mavfile, system: int | None = None, component: int | None = None) -> None:
    """Give a pymavlink connection its own MAVLink 2 common-dialect parser and encoder, with no
    process-wide dialect switch (see the module docstring). Works on any `mavutil.mavfile`."""
    link.mav = mavlink2.MAVLink(
        link,
        srcSystem=link.source_system if system is None else system,
        srcComponent=link.source_component if component is None else component,
    )
    link.mav.robust_parsing = True  # garbage becomes BAD_DATA messages instead of exceptions
    link.WIRE_PROTOCOL_VERSION = "2.0"
    link.first_byte = False


class _Link(mavutil.mavfile):
    """A pymavlink connection to one peer. Outgoing messages are queued by `write` (which the
    MAVLink encoder calls) and sent by `flush`, so one simulation step leaves as one TCP send."""

    def __init__(self, sock: socket.socket, address: str) -> None:
        self.port = sock
        self.peer_label = address
        self.bytes_sent = 0
        super().__init__(sock.fileno(), address, SIM_SYSTEM_ID, SIM_COMPONENT_ID, input=False)
        use_mavlink2(self)

    def flush(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def close(self) -> None:  # the socket is owned by whoever made the link
        pass


class StreamLink(_Link):
    """An accepted TCP connection. EOF or a reset raises PeerClosed out of `recv_match`."""

    def __init__(self, sock: socket.socket, peer: tuple) -> None:
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._out = bytearray()
        super().__init__(sock, f"tcp:{peer[0]}:{peer[1]}")

    def recv(self, n=None) -> bytes:
        try:
            data = self.port.recv(n or self.mav.bytes_needed())
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as e:  # ECONNRESET and friends
            raise PeerClosed(f"{self.peer_label}: {e.strerror or e}") from None
        if not data:
            raise PeerClosed(f"{self.peer_label} closed the connection")
        return data

    def write(self, buf) -> None:
        self._out += buf

    def flush(self) -> None:
        """Send everything queued, waiting at most SEND_TIMEOUT_S for a peer that reads slowly."""
        view, deadline = memoryview(bytes(self._out)), time.monotonic() + SEND_TIMEOUT_S
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
                left = deadline - time.monotonic()
                if left <= 0:
                    raise PeerClosed(f"{self.peer_label} stopped reading (send blocked for {SEND_TIMEOUT_S} s)")
                select.select([], [self.port], [], left)

    def close(self) -> None:
        try:
            self.port.close()
        except OSError:
            pass


class DatagramLink(_Link):
    """The UDP socket, pinned to one peer: the first sender of a valid message. Datagrams from
    anyone else are discarded and counted in `foreign_datagrams`."""

    def __init__(self, sock: socket.socket, label: str) -> None:
        self.peer: tuple | None = None
        self.last_sender: tuple | None = None
        self.foreign_datagrams = 0
        super().__init__(sock, label)

    def recv(self, n=None) -> bytes:
        try:
            data, sender = self.port.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:  # e.g. an ICMP port-unreachable report: UDP has no connection to lose
            return b""
        if self.peer is not None and sender != self.peer:
            self.foreign_datagrams += 1
            return b""
        self.last_sender = sender
        return data

    def recv_msg(self):
        # One whole datagram per read, as pymavlink's own mavudp does (a stream-style read of
        # `bytes_needed` would truncate datagrams).
        self.pre_message()
        msg = self.mav.parse_char(self.recv())
        if msg is not None:
            self.post_message(msg)
        return msg

    def pin(self, peer: tuple | None) -> None:
        """Talk only to `peer`; None: wait for a new one, with a fresh parser (nothing half-read
        from the last peer carries over)."""
        if peer is None:
            use_mavlink2(self)
        self.peer = peer
        self.peer_label = "udp:{}:{}".format(*peer) if peer else self.address

    def write(self, buf) -> None:
        if self.peer is None:
            return
        try:
            self.port.sendto(buf, self.peer)
            self.bytes_sent += len(buf)
        except OSError:  # best effort, like any UDP simulator; the lockstep timeout notices a dead peer
            pass

    def flush(self) -> None:
        pass


class Listener:
    """The listening endpoint. `bind()` claims the address (SimulatorError if it cannot);
    `accept()` waits for the next peer; `close()` releases everything."""

    def __init__(self, address: str | Address) -> None:
        self.requested = address if isinstance(address, Address) else parse_address(address)
        self.sock: socket.socket | None = None
        self.address: Address | None = None
        self._udp: DatagramLink | None = None

    def bind(self) -> Address:
        a = self.requested
        kind = socket.SOCK_STREAM if a.protocol == "tcp" else socket.SOCK_DGRAM
        try:
            infos = socket.getaddrinfo(a.host, a.port, socket.AF_UNSPEC, kind)
        except socket.gaierror as e:
            raise SimulatorError(f"cannot listen on {a}: unknown host {a.host!r} ({e.strerror})") from None
        family, _, _, _, sockaddr = infos[0]
        sock = socket.socket(family, kind)
        try:
            if a.protocol == "tcp":
                # Rebinding while old connections sit in TIME_WAIT is fine; a live listener on the
                # port still makes bind fail. (Not for UDP: there it would let two sockets share it.)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(sockaddr)
            if a.protocol == "tcp":
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
        self.sock = sock
        self.address = Address(a.protocol, a.host, sock.getsockname()[1])
        if a.protocol == "udp":
            self._udp = DatagramLink(sock, str(self.address))
        return self.address

    def accept(self, poll_s: float, should_stop) -> tuple[_Link | None, list]:
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
                    return StreamLink(conn, peer), []
            return None, []
        link = self._udp
        link.pin(None)
        early = []
        while not should_stop():
            msg = link.recv_match(blocking=True, timeout=poll_s)
            if msg is None:
                continue
            early.append(msg)
            if msg.get_type() != "BAD_DATA" and link.last_sender is not None:
                link.pin(link.last_sender)
                return link, early
        return None, early

    def close(self) -> None:
        if self.sock is not None:
            try:
                self.sock.close()
            finally:
                self.sock = None

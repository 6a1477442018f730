"""A TCP proxy between the node and a simulator that spoils chosen states, for the hand-back flights.

    proxy = StateFaultProxy(sim_port, bad_steps={100})   # the 101st HIL_STATE_QUATERNION spoiled
    ... connect the node to tcp:127.0.0.1:{proxy.port} ...
    proxy.join(); proxy.spoiled                           # how many it spoiled

It accepts one connection (the node), connects to the simulator, and forwards both directions byte
for byte, except that the HIL_STATE_QUATERNION of each step in `bad_steps` (counted from 0, in the
order the simulator sent them) goes out with a zero quaternion, re-encoded with the simulator's
system, component and sequence number: a well-formed MAVLink message with a state no vehicle can
be in, as the colleague's probe sent. `on_state(k)` (optional) is called as state k passes."""

import socket
import threading

from pymavlink.dialects.v20 import common as mavlink2


class _Sink:
    def __init__(self) -> None:
        self.buf = b""

    def write(self, b) -> None:
        self.buf = bytes(b)


def _shut(*socks: socket.socket) -> None:
    """Both directions end when one does: the other side sees the link close."""
    for s in socks:
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class StateFaultProxy:
    def __init__(self, sim_port: int, bad_steps=(), on_state=None) -> None:
        self.sim_port, self.bad_steps, self.on_state = sim_port, set(bad_steps), on_state
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.states = 0
        self.spoiled = 0
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            self.server.settimeout(30)
            node, _ = self.server.accept()
            sim = socket.create_connection(("127.0.0.1", self.sim_port), timeout=10)
            sim.settimeout(None)
            node.settimeout(None)
            up = threading.Thread(target=self._pump, args=(node, sim), daemon=True)
            up.start()
            self._down(sim, node)
            up.join(5)
        except BaseException as e:  # surfaced by join()
            self.error = e
        finally:
            self.server.close()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            _shut(src, dst)

    def _down(self, sim: socket.socket, node: socket.socket) -> None:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        try:
            while data := sim.recv(65536):
                out = bytearray()
                for msg in parser.parse_buffer(data) or []:
                    raw = bytes(msg.get_msgbuf())
                    if msg.get_type() == "HIL_STATE_QUATERNION":
                        k = self.states
                        self.states += 1
                        if self.on_state is not None:
                            self.on_state(k)
                        if k in self.bad_steps:
                            raw = self._spoil(msg)
                    out += raw
                node.sendall(out)
        except OSError:
            pass
        finally:
            _shut(sim, node)

    def _spoil(self, msg) -> bytes:
        assert msg.get_msgbuf()[0] == 0xFD, "the proxy re-encodes MAVLink 2 only"
        enc = mavlink2.MAVLink(_Sink(), srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
        enc.seq = msg.get_seq()
        fields = {name: getattr(msg, name) for name in msg.get_fieldnames()}
        fields["attitude_quaternion"] = [0.0, 0.0, 0.0, 0.0]
        enc.hil_state_quaternion_send(**fields)
        self.spoiled += 1
        return enc.file.buf

    def join(self) -> None:
        self.thread.join(10)
        assert not self.thread.is_alive(), "the proxy did not finish"
        if self.error is not None:
            raise self.error

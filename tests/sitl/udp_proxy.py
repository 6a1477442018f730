"""A noisy UDP link for the fault tests, run as its own process:

    python udp_proxy.py SIM_PORT GARBAGE_TOTAL SECONDS

It listens on a free loopback port (printed as the first stdout line, `listening PORT`), forwards
datagrams between the first peer that talks to it (the node) and the simulator at SIM_PORT, and
meanwhile sends GARBAGE_TOTAL junk datagrams, half to each side, spread over SECONDS: random bytes,
truncated messages, bad CRCs, unknown message ids and oversized datagrams, in turn. Both sides see
the junk come from their pinned peer, so it reaches their parsers. On stdin EOF or SIGTERM it prints
a JSON line of what it sent and exits."""

import json
import random
import select
import signal
import socket
import sys
import time

from pymavlink.dialects.v20 import common as mavlink2


class _Sink:
    def __init__(self):
        self.buf = b""

    def write(self, b):
        self.buf = bytes(b)


def junk_factory(seed: int):
    rng = random.Random(seed)
    enc = mavlink2.MAVLink(_Sink(), srcSystem=1, srcComponent=1)
    kinds = ["random", "truncated", "bad_crc", "unknown_id", "oversized"]

    def valid() -> bytes:
        enc.hil_actuator_controls_send(0, [0.0] * 16, 128, 1)  # would be a real command: must not act
        return enc.file.buf

    def make(i: int) -> tuple[str, bytes]:
        kind = kinds[i % len(kinds)]
        if kind == "random":
            return kind, rng.randbytes(rng.randint(1, 280))
        m = bytearray(valid())
        if kind == "truncated":
            return kind, bytes(m[: rng.randint(1, len(m) - 1)])
        if kind == "bad_crc":
            m[-1] ^= 0x5A
            return kind, bytes(m)
        if kind == "unknown_id":
            m[7:10] = (0xFE, 0xFF, 0x00)
            return kind, bytes(m)
        return kind, rng.randbytes(60_000)

    return make


def main() -> None:
    sim_port, total, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the node talks to this
    front.bind(("127.0.0.1", 0))
    back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the simulator pins this
    back.bind(("127.0.0.1", 0))
    sim = ("127.0.0.1", sim_port)
    print(f"listening {front.getsockname()[1]}", flush=True)
    stop = []
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    node = None
    make = junk_factory(1)
    sent = {"to_sim": {}, "to_node": {}, "forwarded": 0}
    i, t_start, interval = 0, None, seconds / max(total, 1)
    while not stop:
        ready, _, _ = select.select([front, back, sys.stdin], [], [], 0.0005)
        for s in ready:
            if s is sys.stdin:
                if not sys.stdin.readline():
                    stop.append(1)
                continue
            data, addr = s.recvfrom(65536)
            if s is front:
                node = addr
                back.sendto(data, sim)
            elif node is not None:
                front.sendto(data, node)
            sent["forwarded"] += 1
        if node is not None and t_start is None:
            t_start = time.monotonic() + 0.3  # let the flight start first
        while t_start is not None and i < total and time.monotonic() >= t_start + i * interval:
            kind, junk = make(i)
            side = "to_sim" if i % 2 == 0 else "to_node"
            (back.sendto(junk, sim) if side == "to_sim" else front.sendto(junk, node))
            sent[side][kind] = sent[side].get(kind, 0) + 1
            i += 1
    print(json.dumps(sent), flush=True)


if __name__ == "__main__":
    main()

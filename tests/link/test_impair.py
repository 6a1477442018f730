"""The impairment proxy (`link.impair`): each impairment does what it says to whole MAVLink frames,
seeded runs repeat, the counts add up, and a bad spec or a non-loopback address is one line.

A client sends numbered frames (SYSTEM_TIME, time_boot_ms = its number) through the proxy to a server
socket, which reads until the client's side closes; every frame the server gets must be one that was
sent, byte for byte."""

from __future__ import annotations

import contextlib
import itertools
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from quadpilot.link.impair import REORDER_HOLD_S, Impairment, ImpairSpecError, Proxy, parse_spec
from quadpilot.link.transport import parse_address
from quadpilot.sitl import main as quad_sitl

N = 2000


def frames(n: int = N) -> list[bytes]:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    return [bytes(mav.system_time_encode(0, i).pack(mav)) for i in range(n)]


def relay(imp: Impairment, sent: list[bytes], extra: bytes = b"", pace_s: float = 0.0):
    """Send `sent` (and `extra` raw bytes after the first frame) through a proxy with `imp`; returns
    (frame numbers received in order, raw frames received, arrival times by number, send times, proxy counts)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    got = bytearray()
    arrivals: dict[int, float] = {}
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    received: list = []

    def serve():
        conn, _ = server.accept()
        conn.settimeout(10)
        with conn:
            while data := conn.recv(65536):
                now = time.monotonic()
                got.extend(data)
                for m in parser.parse_buffer(data) or ():
                    received.append(m)
                    if m.get_type() == "SYSTEM_TIME":
                        arrivals.setdefault(m.time_boot_ms, now)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    sent_at: dict[int, float] = {}
    with Proxy(f"tcp:127.0.0.1:{server.getsockname()[1]}", imp) as proxy:
        client = socket.create_connection((proxy.address.host, proxy.address.port))
        for i, raw in enumerate(sent):
            sent_at[i] = time.monotonic()
            client.sendall(raw + (extra if i == 0 else b""))
            if pace_s:
                time.sleep(pace_s)
        time.sleep(imp.delay_s + imp.jitter_s + REORDER_HOLD_S + 0.2)  # what is scheduled goes out
        client.close()
        t.join(10)
        counts = {d: dict(proxy.counts[d]) for d in ("up", "down")}
    server.close()
    good = [m for m in received if m.get_type() == "SYSTEM_TIME"]
    assert all(bytes(m.get_msgbuf()) == sent[m.time_boot_ms] for m in good)  # whole frames, byte for byte
    return [m.time_boot_ms for m in good], received, arrivals, sent_at, counts["up"]


def test_nothing_impaired_relays_every_frame_in_order():
    order, _, _, _, c = relay(Impairment(), frames())
    assert order == list(range(N))
    assert c["frames"] == c["relayed"] == N and c["lost"] == c["delayed"] == 0


def test_loss_drops_whole_frames_at_the_rate_asked_and_counts_them():
    order, received, _, _, c = relay(Impairment(loss=0.2, seed=1), frames())
    assert all(m.get_type() == "SYSTEM_TIME" for m in received)  # no torn frame: lost frames are whole
    assert order == sorted(order) and len(set(order)) == len(order)
    assert c["lost"] == N - len(order) and c["relayed"] == len(order) and c["frames"] == N
    assert abs(c["lost"] - 0.2 * N) < 4 * (N * 0.2 * 0.8) ** 0.5  # binomial, 4 sigma


def test_burst_loss_loses_runs_of_frames_of_the_mean_length_asked():
    order, _, _, _, c = relay(Impairment(burst=0.02, burst_len=5, seed=2), frames(4000))
    missing = sorted(set(range(4000)) - set(order))
    runs, k = [], 0
    for i, m in enumerate(missing):
        k += 1
        if i + 1 == len(missing) or missing[i + 1] != m + 1:
            runs.append(k)
            k = 0
    assert c["lost_burst"] == len(missing) and c["lost"] == 0
    assert len(runs) > 30  # about 4000 × 0.02 / (1 + 0.02 × 5) ≈ 70 bursts
    assert 3.0 < sum(runs) / len(runs) < 8.0  # geometric, mean 5 frames


def test_delay_holds_every_frame_at_least_that_long_and_keeps_their_order():
    order, _, arrivals, sent_at, c = relay(Impairment(delay_s=0.03), frames(200), pace_s=0.001)
    assert order == list(range(200)) and c["delayed"] == 200
    assert min(arrivals[i] - sent_at[i] for i in order) >= 0.03


def test_jitter_spreads_the_delay_but_never_reorders():
    order, _, arrivals, sent_at, c = relay(Impairment(delay_s=0.02, jitter_s=0.015, seed=3), frames(300), pace_s=0.001)
    assert order == list(range(300)) and c["delayed"] == 300
    lags = [arrivals[i] - sent_at[i] for i in order]
    assert min(lags) >= 0.005 - 1e-3 and max(lags) - min(lags) > 0.01


def test_duplicate_sends_the_same_frame_twice_in_a_row():
    order, _, _, _, c = relay(Impairment(duplicate=0.1, seed=4), frames())
    twice = [a for a, b in itertools.pairwise(order) if a == b]
    assert sorted(set(order)) == list(range(N))
    assert len(order) == N + c["duplicated"] and len(twice) == c["duplicated"] > 100
    assert c["relayed"] == len(order)


def test_reorder_sends_a_held_frame_after_the_next_one():
    order, _, _, _, c = relay(Impairment(reorder=0.1, seed=5), frames())
    assert sorted(order) == list(range(N))
    swaps = [i for i in range(N - 1) if order[i] > order[i + 1]]
    assert all(order[i] == order[i + 1] + 1 for i in swaps)  # each held frame went right after its successor
    assert c["reordered"] - 1 <= len(swaps) <= c["reordered"] and len(swaps) > 100


def test_the_same_seed_repeats_the_same_fate_and_another_does_not():
    sent = frames(1000)
    imp = Impairment(loss=0.1, duplicate=0.05, reorder=0.05, burst=0.01, seed=7)
    a, b = relay(imp, sent)[0], relay(imp, sent)[0]
    c = relay(Impairment(loss=0.1, duplicate=0.05, reorder=0.05, burst=0.01, seed=8), sent)[0]
    assert a == b and a != c


def test_bytes_that_are_no_frame_pass_unimpaired_and_are_counted():
    junk = b"\x00garbage bytes, no MAVLink here\x01"
    _, received, _, _, c = relay(Impairment(loss=1.0), frames(50), extra=junk)
    assert c["lost"] == 50 and c["unparsed"] >= 1
    assert [m.get_type() for m in received] == ["BAD_DATA"] * len(received) and received


def test_the_proxy_refuses_a_non_loopback_address_in_one_line():
    for address in ("tcp:10.1.2.3:4560", "tcp:example.org:4560", "udp:192.0.2.1:4560", "tcp:0.0.0.0:4560"):
        with pytest.raises(ImpairSpecError) as e:
            Proxy(parse_address(address), Impairment())
        assert "\n" not in str(e.value) and "loopback" in str(e.value)


def test_over_udp_each_frame_is_a_datagram_and_meets_its_fate_alone():
    """A simulator on UDP: the node's datagrams go to the simulator from the proxy's own socket, the
    simulator's come back to the node's; a lost frame is a lost datagram, a duplicate two."""
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    server.settimeout(0.5)
    got: list[bytes] = []
    peer: list = []

    def serve():  # read as it comes: a socket's buffer holds a few hundred datagrams only
        with contextlib.suppress(TimeoutError):
            while True:
                data, sender = server.recvfrom(4096)
                got.append(data)
                peer[:] = [sender]

    sent = frames(500)
    with Proxy(f"udp:127.0.0.1:{server.getsockname()[1]}", Impairment(loss=0.1, duplicate=0.1, seed=6)) as proxy:
        t = threading.Thread(target=serve, daemon=True)
        t.start()
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.settimeout(2.0)
        for raw in sent:
            client.sendto(raw, (proxy.address.host, proxy.address.port))
            time.sleep(0.0005)
        t.join(10)
        server.sendto(sent[0], peer[0])  # and back: to the node's socket
        echoed, _ = client.recvfrom(4096)
        up, down = dict(proxy.counts["up"]), dict(proxy.counts["down"])
    assert echoed == sent[0] and down["frames"] == 1 and proxy.connections == 1
    assert all(g in sent for g in got)  # one whole frame per datagram
    # a datagram the kernel drops before the proxy reads it (a full socket buffer) is none of its frames
    assert len(got) == up["frames"] - up["lost"] + up["duplicated"] == up["relayed"] and up["frames"] > 250
    assert up["lost"] > 0.05 * up["frames"] and up["duplicated"] > 0.05 * up["frames"]


# --- the spec ---------------------------------------------------------------------------------
def test_a_spec_reads_every_impairment_and_its_units():
    imp = parse_spec("loss=5%,delay=20ms,jitter=500us,reorder=0.01,duplicate=2%,burst=1%,burst-len=4,seed=9")
    assert imp == Impairment(0.05, 0.01, 4.0, 0.02, 0.0005, 0.01, 0.02, 9)
    assert parse_spec("delay=0.05s", default_seed=3) == Impairment(delay_s=0.05, seed=3)
    assert parse_spec(str(imp)) == imp  # its own text reads back


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("", "empty spec"),
        ("loss", "is not KEY=VALUE"),
        ("loss=", "is not KEY=VALUE"),
        ("loss=150%", "outside 0..100 %"),
        ("loss=nan", "is not a probability"),
        ("loss=-1%", "is not a probability"),
        ("delay=20", "is not a time with its unit"),
        ("delay=-5ms", "is not a time"),
        ("delay=1e9s", "beyond"),
        ("lag=20ms", "unknown impairment 'lag'"),
        ("seed=-1", "seed='-1' is not an integer"),
        ("burst-len=0", "mean burst length"),
        ("loss=1%,loss=2%", "loss given twice"),
        ("loss=1%;delay=2ms", "is not a probability"),
    ],
)
def test_a_bad_spec_is_one_line_naming_what_was_wrong_and_what_is_expected(spec, says):
    with pytest.raises(ImpairSpecError) as e:
        parse_spec(spec)
    text = str(e.value)
    assert "\n" not in text and says in text and "expected KEY=VALUE" in text


def test_quad_sitl_refuses_a_bad_spec_and_a_remote_simulator_in_one_line(capsys):
    assert quad_sitl(["--link-impair", "loss=lots"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--link-impair" in err and "not a probability" in err and "Traceback" not in err
    remote = ["--node-only", "--connect", "tcp:192.0.2.1:4560", "--link-impair", "loss=1%"]
    assert quad_sitl(remote) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not a loopback address" in err
    assert quad_sitl(["--listen", "udp:0.0.0.0:0", "--link-impair", "delay=5ms"]) == 2
    assert "not a loopback address" in capsys.readouterr().err

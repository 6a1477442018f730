"""`Link.recv` with a timeout waits for the socket before it reads (in lockstep the peer's answer is
never there yet): a message that arrives during the wait is returned, one that does not come ends
the wait on time, the peer's EOF and a link closed here are PeerClosed, and a zero timeout polls.

A lockstep link polls its socket before it sleeps (`Link.spin_s`): an answer that comes within the
window is taken without select(), a window that finds nothing backs off (the next 1, 2, 4, ... waits
sleep at once) until an answer is caught again, the window counts against the timeout, the peer's
EOF still ends the wait, and with one usable CPU there is no window."""

import socket
import threading
import time

import pytest

from quadpilot.link import spin, transport


def _pair():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    client = socket.create_connection(server.getsockname())
    conn, _ = server.accept()
    server.close()
    here = transport.StreamLink(conn, "tcp:peer", 200, 200)
    there = transport.StreamLink(client, "tcp:here", 1, 1)
    return here, there


def test_a_message_sent_during_the_wait_is_returned():
    here, there = _pair()
    try:

        def later():
            time.sleep(0.05)
            there.mav.heartbeat_send(2, 0, 0, 0, 4)
            there.mav.heartbeat_send(2, 0, 0, 0, 5)
            there.flush()

        threading.Thread(target=later).start()
        t0 = time.monotonic()
        first = here.recv(2.0)
        assert first is not None and first.get_type() == "HEARTBEAT" and first.system_status == 4
        assert time.monotonic() - t0 < 1.0
        second = here.recv(0.0)  # already read with the first: handed out without waiting
        assert second is not None and second.system_status == 5
    finally:
        here.close()
        there.close()


def test_a_message_split_across_reads_is_waited_for_whole():
    """Half a frame makes the socket readable but holds no message: the wait goes on for the rest."""
    here, there = _pair()
    try:
        there.mav.heartbeat_send(2, 0, 0, 0, 4)
        frame = bytes(there._out)
        there._out.clear()
        raw = there.port

        def halves():
            raw.sendall(frame[:7])
            time.sleep(0.05)
            raw.sendall(frame[7:])

        threading.Thread(target=halves).start()
        msg = here.recv(2.0)
        assert msg is not None and msg.get_type() == "HEARTBEAT"
    finally:
        here.close()
        there.close()


def test_silence_ends_the_wait_on_time_and_a_zero_timeout_polls():
    here, there = _pair()
    try:
        t0 = time.monotonic()
        assert here.recv(0.1) is None
        assert 0.09 <= time.monotonic() - t0 < 1.0
        t0 = time.monotonic()
        assert here.recv(0.0) is None
        assert time.monotonic() - t0 < 0.05
    finally:
        here.close()
        there.close()


def test_the_peers_eof_and_a_closed_link_are_peer_closed():
    here, there = _pair()
    there.close()
    with pytest.raises(transport.PeerClosed, match="closed the connection"):
        here.recv(1.0)
    here2, there2 = _pair()
    here2.close()  # closed on this side: not a ValueError out of select()
    with pytest.raises(transport.PeerClosed):
        here2.recv(0.5)
    there2.close()


def _send_later(link, delay_s, status=4):
    def later():
        time.sleep(delay_s)
        link.mav.heartbeat_send(2, 0, 0, 0, status)
        link.flush()

    t = threading.Thread(target=later)
    t.start()
    return t


class _Selects:
    """Counts select() calls made by the transport module (the link sleeping)."""

    def __init__(self, monkeypatch):
        self.calls = 0
        real = transport.select.select

        def counting(*a):
            self.calls += 1
            return real(*a)

        monkeypatch.setattr(transport.select, "select", counting)


def test_an_answer_within_the_window_is_taken_without_sleeping(monkeypatch):
    here, there = _pair()
    selects = _Selects(monkeypatch)
    try:
        here.spin_s = 1.0
        t = _send_later(there, 0.02)
        msg = here.recv(2.0)
        t.join()
        assert msg is not None and msg.get_type() == "HEARTBEAT" and msg.system_status == 4
        assert selects.calls == 0
        here.spin_s = 0.0  # the same wait without a window sleeps in select
        t = _send_later(there, 0.02, 5)
        msg = here.recv(2.0)
        t.join()
        assert msg is not None and msg.system_status == 5
        assert selects.calls >= 1
    finally:
        here.close()
        there.close()


def test_an_empty_window_backs_off_and_a_caught_answer_resumes_spinning(monkeypatch):
    here, there = _pair()
    selects = _Selects(monkeypatch)
    fills = []
    real_fill = here._fill
    here._fill = lambda: (fills.append(1), real_fill())[1]
    try:
        here.spin_s = 0.005
        spun = []
        for _ in range(12):  # silence: which waits polled before sleeping?
            fills.clear()
            assert here.recv(0.01) is None
            spun.append(len(fills) > 1)  # a window polls many times; a sleep reads only after select
        # windows at waits 0, 2, 5, 10: each empty one skips the next 1, 2, 4, ... waits
        assert spun == [True, False, True, False, False, True, False, False, False, False, True, False]
        assert here._spin_skip == 7
        for _ in range(7):  # sleep out the backoff
            assert here.recv(0.001) is None
        assert here._spin_skip == 0
        calls = selects.calls
        here.spin_s = 1.0  # a window the sender thread surely answers within (it needs the GIL too)
        here.mav.heartbeat_send(2, 0, 0, 0, 3)  # a question: what comes next answers it
        here.flush()
        t = _send_later(there, 0.001)
        assert here.recv(2.0) is not None  # caught in the window
        t.join()
        assert selects.calls == calls
        assert here._spin_backoff == 0 and here._spin_skip == 0
    finally:
        here.close()
        there.close()


def test_the_window_counts_against_the_timeout():
    here, there = _pair()
    try:
        here.spin_s = 5.0
        t0 = time.monotonic()
        assert here.recv(0.1) is None
        assert 0.09 <= time.monotonic() - t0 < 0.5
    finally:
        here.close()
        there.close()


def test_the_peers_eof_ends_a_spinning_wait():
    here, there = _pair()
    here.spin_s = 1.0
    there.close()
    t0 = time.monotonic()
    with pytest.raises(transport.PeerClosed, match="closed the connection"):
        here.recv(2.0)
    assert time.monotonic() - t0 < 0.5
    here.close()


def test_no_window_with_one_usable_cpu(monkeypatch):
    monkeypatch.setattr(spin.os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert spin.spin_window(0.0005) == 0.0
    monkeypatch.setattr(spin.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert spin.spin_window(0.0005) == 0.0005


def test_the_backoff_stops_at_its_cap():
    here, there = _pair()
    try:
        here.spin_s = 0.0001
        for _ in range(600):  # windows at waits 0, 2, 5, 10, ...: 9 empty ones reach the cap
            assert here.recv(0.0002) is None
        assert here._spin_backoff == spin.SPIN_BACKOFF_MAX
    finally:
        here.close()
        there.close()


def test_the_tail_of_a_step_sent_in_two_writes_does_not_reset_the_backoff():
    """A slow lockstep peer that sends each step in two writes (RotorPy's PX4Multirotor:
    hil_state_quaternion_send, then hil_sensor_send): a window may catch the second write, but that
    answers nothing sent, and the empty windows before the first write must still back off."""
    here, there = _pair()
    try:
        here.spin_s = 0.002
        empty = 0
        for _ in range(20):
            here.mav.heartbeat_send(2, 0, 0, 0, 3)  # the answer to the last step
            here.flush()
            spins = here._spin_skip == 0
            t = _send_later(there, 0.01, 4)  # the peer's slow physics step, then the step's first write
            assert here.recv(1.0).system_status == 4
            t.join()
            empty += spins
            there.mav.heartbeat_send(2, 0, 0, 0, 5)  # its second write
            there.flush()
            assert here.recv(1.0).system_status == 5
        assert empty <= 5  # the waits for a step spin at 0, 2, 5, 10, 19 (each empty, backing off)
    finally:
        here.close()
        there.close()


def test_a_udp_listener_unpinned_for_its_next_peer_starts_without_a_window():
    """The simulator's UDP link serves every episode: between peers it waits for a first message
    at no window, and the last peer's backoff does not carry over."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    link = transport.DatagramLink(sock, "udp:127.0.0.1:0", 200, 200, peer=("127.0.0.1", 9))
    try:
        link.spin_s, link._spin_backoff, link._spin_skip = 0.0005, 8, 3
        link.pin(None)
        assert (link.spin_s, link._spin_backoff, link._spin_skip) == (0.0, 0, 0)
    finally:
        link.close()

"""`Link.recv` with a timeout waits for the socket before it reads (in lockstep the peer's answer is
never there yet): a message that arrives during the wait is returned, one that does not come ends
the wait on time, the peer's EOF and a link closed here are PeerClosed, and a zero timeout polls."""

import socket
import threading
import time

import pytest

from quadpilot.link import transport


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

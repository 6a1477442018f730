"""MAVLink FTP through packed MAVLink bytes: every request answered at once (ACK, or NAK with the
error code), sessions, sequence numbers, burst reads, the in-memory SD card and its bounds."""

import errno
import io
import struct
import tarfile
import zlib
from pathlib import Path

import pytest
from commander_gcs import GCS_COMPONENT, GCS_SYSTEM, Gcs, of_type
from hypothesis import given, settings
from hypothesis import strategies as st

from quadpilot.autopilot import ftp_protocol as F
from quadpilot.autopilot.param_protocol import INT32, PARAMS
from quadpilot.autopilot.policy_upload import fly_uploaded
from quadpilot.runtime.rltools_tar import policy_tar_bytes, read_policy_tar, sha256_hex


class Ftp:
    """A client speaking FILE_TRANSFER_PROTOCOL to the commander, one request at a time."""

    def __init__(self, g: Gcs | None = None) -> None:
        self.g = g or Gcs()
        self.seq = 0

    def request(self, opcode, session=0, data=b"", offset=0, size=None, seq=None) -> list:
        seq = self.seq if seq is None else seq
        self.seq = seq + 1
        head = F.HEADER.pack(seq, session, opcode, len(data) if size is None else size, 0, 0, 0, offset)
        payload = list((head + data).ljust(F.PAYLOAD_LEN, b"\0"))
        out = of_type(self.g.send(self.g.tx.file_transfer_protocol_encode(0, 1, 1, payload)), "FILE_TRANSFER_PROTOCOL")
        return [reply(m) for m in out]

    def one(self, *a, **k) -> dict:
        (r,) = self.request(*a, **k)
        return r


def reply(m) -> dict:
    assert (m.target_system, m.target_component) == (GCS_SYSTEM, GCS_COMPONENT)
    raw = bytes(m.payload)
    seq, session, opcode, size, req, burst, _, offset = F.HEADER.unpack_from(raw)
    return dict(seq=seq, session=session, opcode=opcode, req=req, burst=burst, offset=offset, data=raw[12 : 12 + size])


def nak(r: dict) -> tuple:
    assert r["opcode"] == F.OP_NAK, r
    return tuple(r["data"])


def upload(c: Ftp, path: str, content: bytes, block: int = 239) -> int:
    r = c.one(F.OP_CREATE_FILE, data=path.encode())
    assert r["opcode"] == F.OP_ACK, r
    s = r["session"]
    for off in range(0, len(content), block):
        w = c.one(F.OP_WRITE_FILE, s, content[off : off + block], off)
        assert w["opcode"] == F.OP_ACK and w["offset"] == off, w
    assert c.one(F.OP_TERMINATE_SESSION, s)["opcode"] == F.OP_ACK
    return s


def download(c: Ftp, path: str) -> bytes:
    r = c.one(F.OP_OPEN_FILE_RO, data=path.encode())
    assert r["opcode"] == F.OP_ACK, r
    s, size = r["session"], struct.unpack("<I", r["data"])[0]
    got, off = b"", 0
    while True:
        packets = c.request(F.OP_BURST_READ_FILE, s, size=F.MAX_DATA, offset=off)
        for p in packets:
            if p["opcode"] == F.OP_NAK:
                assert nak(p) == (F.ERR_EOF,)
                break
            assert p["offset"] == len(got)
            got += p["data"]
        last = packets[-1]
        if last["opcode"] == F.OP_NAK or len(last["data"]) < F.MAX_DATA:
            break
        assert last["burst"] == 1
        off = len(got)
    c.one(F.OP_TERMINATE_SESSION, s)
    assert len(got) == size
    return got


@pytest.mark.parametrize("opcode", range(0, 256))
def test_every_opcode_is_answered_once_with_the_next_sequence_number(opcode):
    c = Ftp()
    out = c.request(opcode, session=7, seq=41)
    if opcode in (F.OP_ACK, F.OP_NAK):  # an answer sent to the vehicle is not a request
        assert out == [] and c.g.commander.dropped["ftp_reply_to_vehicle"] == 1
        return
    assert len(out) == 1, out
    r = out[0]
    assert r["seq"] == 42 and r["req"] == opcode
    assert r["opcode"] in (F.OP_ACK, F.OP_NAK)
    if opcode > F.OP_BURST_READ_FILE:
        assert nak(r) == (F.ERR_UNKNOWN_COMMAND,)
    assert not [k for k in c.g.commander.dropped if k.startswith("unexpected")]


def test_mavproxy_first_request_for_the_parameter_file_and_a_missing_file():
    c = Ftp()
    # the commander alone (no parameter file given to its server here): a missing file
    c.g.commander.ftp.param_file = None
    r = c.one(F.OP_OPEN_FILE_RO, session=137, data=b"@PARAM/param.pck?withdefaults=1")
    assert nak(r) == (F.ERR_FILE_NOT_FOUND,) and r["session"] == 137 and r["seq"] == 1
    assert nak(c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/nothing.bin")) == (F.ERR_FILE_NOT_FOUND,)
    assert nak(c.one(F.OP_TERMINATE_SESSION, session=137)) == (F.ERR_INVALID_SESSION,)
    assert nak(c.one(F.OP_READ_FILE, session=3)) == (F.ERR_INVALID_SESSION,)
    assert nak(c.one(F.OP_BURST_READ_FILE, session=3)) == (F.ERR_INVALID_SESSION,)


def test_bad_fields_are_refused_with_their_code():
    c = Ftp()
    assert nak(c.one(F.OP_OPEN_FILE_RO, data=b"x", size=240)) == (F.ERR_INVALID_DATA_SIZE,)
    assert nak(c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/../etc/passwd")) == (F.ERR_FAIL_ERRNO, errno.EINVAL)
    assert nak(c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/\xff")) == (F.ERR_FAIL_ERRNO, errno.EINVAL)
    assert nak(c.one(F.OP_CREATE_FILE, data=b"/etc/passwd")) == (F.ERR_FILE_PROTECTED,)
    assert nak(c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/no/dir.bin")) == (F.ERR_FILE_NOT_FOUND,)
    assert nak(c.one(F.OP_LIST_DIRECTORY, data=b"/nowhere")) == (F.ERR_FILE_NOT_FOUND,)
    assert nak(c.one(F.OP_REMOVE_DIRECTORY, data=b"/fs/microsd/raptor")) == (F.ERR_FILE_PROTECTED,)
    # a payload shorter than the header (a truncated message pymavlink pads) is still answered
    g = c.g
    out = of_type(g.send(g.tx.file_transfer_protocol_encode(0, 1, 1, [9] * 5 + [0] * 246)), "FILE_TRANSFER_PROTOCOL")
    assert len(out) == 1


def test_upload_download_list_crc_rename_remove():
    c = Ftp()
    content = bytes(range(256)) * 9 + b"end"  # 2307 bytes: not a multiple of 239
    upload(c, "/fs/microsd/raptor/a.bin", content)
    assert download(c, "/fs/microsd/raptor/a.bin") == content
    listing = c.one(F.OP_LIST_DIRECTORY, data=b"/fs/microsd/raptor")["data"]
    assert listing == b"Fa.bin\t2307\0"
    assert nak(c.one(F.OP_LIST_DIRECTORY, data=b"/fs/microsd/raptor", offset=1)) == (F.ERR_EOF,)
    assert c.one(F.OP_LIST_DIRECTORY, data=b"/fs/microsd")["data"] == b"Draptor\0"
    crc = struct.unpack("<I", c.one(F.OP_CALC_FILE_CRC32, data=b"/fs/microsd/raptor/a.bin")["data"])[0]
    assert crc == zlib.crc32(content, 0xFFFFFFFF) ^ 0xFFFFFFFF  # PX4's crc32part
    assert c.one(F.OP_RENAME, data=b"/fs/microsd/raptor/a.bin\0/fs/microsd/raptor/b.bin")["opcode"] == F.OP_ACK
    assert c.one(F.OP_REMOVE_FILE, data=b"/fs/microsd/raptor/b.bin")["opcode"] == F.OP_ACK
    assert nak(c.one(F.OP_REMOVE_FILE, data=b"/fs/microsd/raptor/b.bin")) == (F.ERR_FILE_NOT_FOUND,)
    assert c.one(F.OP_CREATE_DIRECTORY, data=b"/fs/microsd/logs")["opcode"] == F.OP_ACK
    assert nak(c.one(F.OP_CREATE_DIRECTORY, data=b"/fs/microsd/logs")) == (F.ERR_FILE_EXISTS,)
    assert c.one(F.OP_REMOVE_DIRECTORY, data=b"/fs/microsd/logs")["opcode"] == F.OP_ACK


def test_a_file_ending_on_a_packet_boundary_ends_its_burst_with_eof():
    c = Ftp()
    upload(c, "/fs/microsd/x", b"a" * (2 * F.MAX_DATA))
    s = c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/x")["session"]
    packets = c.request(F.OP_BURST_READ_FILE, s, size=F.MAX_DATA, seq=100)
    assert [p["seq"] for p in packets] == [101, 102, 103]
    assert [p["opcode"] for p in packets] == [F.OP_ACK, F.OP_ACK, F.OP_NAK] and nak(packets[-1]) == (F.ERR_EOF,)
    assert nak(c.one(F.OP_READ_FILE, s, offset=2 * F.MAX_DATA)) == (F.ERR_EOF,)
    assert c.one(F.OP_READ_FILE, s, offset=10, size=5)["data"] == b"aaaaa"  # the size asked for


def test_a_long_burst_stops_after_its_packets_and_goes_on_when_asked():
    c = Ftp()
    upload(c, "/fs/microsd/big", bytes(F.MAX_DATA * (F.BURST_PACKETS + 3)))
    s = c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/big")["session"]
    first = c.request(F.OP_BURST_READ_FILE, s, size=F.MAX_DATA)
    assert len(first) == F.BURST_PACKETS and [p["burst"] for p in first] == [0] * (F.BURST_PACKETS - 1) + [1]


def test_sessions_are_bounded_and_keep_the_id_asked_for_when_free():
    c = Ftp()
    upload(c, "/fs/microsd/f", b"abc")
    ids = [c.one(F.OP_OPEN_FILE_RO, session=9, data=b"/fs/microsd/f")["session"] for _ in range(F.MAX_SESSIONS)]
    assert ids == [9, 0, 1]  # MAVProxy's own id when free, else the lowest free (PX4, MAVSDK read it back)
    assert nak(c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/f")) == (F.ERR_NO_SESSIONS_AVAILABLE,)
    assert c.one(F.OP_RESET_SESSIONS)["opcode"] == F.OP_ACK
    s = c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/f")["session"]
    c.g.run(F.IDLE_CLOSE_S + 0.5)  # idle sessions close (PX4: 10 s)
    assert nak(c.one(F.OP_READ_FILE, s)) == (F.ERR_INVALID_SESSION,)


def test_a_repeated_request_gets_the_same_answer_and_is_not_done_twice():
    c = Ftp()
    first = c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/r", seq=5)
    again = c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/r", seq=5)  # the ACK was lost: sent again
    assert again == first and len(c.g.commander.ftp.sessions) == 1


def test_sizes_are_bounded():
    c = Ftp()
    s = c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/huge")["session"]
    assert nak(c.one(F.OP_WRITE_FILE, s, b"x", F.MAX_FILE_BYTES)) == (F.ERR_FAIL_ERRNO, errno.EFBIG)
    assert c.one(F.OP_WRITE_FILE, s, b"x", F.MAX_FILE_BYTES - 1)["opcode"] == F.OP_ACK
    c.one(F.OP_TERMINATE_SESSION, s)
    for i in range(F.MAX_CARD_BYTES // F.MAX_FILE_BYTES - 1):
        s = c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/h%d" % i)["session"]
        c.one(F.OP_WRITE_FILE, s, b"x", F.MAX_FILE_BYTES - 1)
        c.one(F.OP_TERMINATE_SESSION, s)
    s = c.one(F.OP_CREATE_FILE, data=b"/fs/microsd/more")["session"]
    assert nak(c.one(F.OP_WRITE_FILE, s, b"xx", 0)) == (F.ERR_FAIL_ERRNO, errno.ENOSPC)


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


@pytest.mark.parametrize("query", ["", "?withdefaults=1"])
def test_the_parameter_file_is_the_table_in_mavproxys_reading(query):
    from MAVProxy.modules.lib.param_ftp import ftp_param_decode  # MAVProxy's own decoder (dev extra)

    c = Ftp()
    c.g.param_set("MIS_TAKEOFF_ALT", 3.0)
    c.g.param_set("NAV_DLL_ACT", 1.0)  # a whole float for an INT32: how MAVProxy sets it after the file
    pdata = ftp_param_decode(download(c, "@PARAM/param.pck" + query))
    assert pdata is not None
    table = c.g.commander.params
    assert [(n.decode(), v) for n, v, _ in pdata.params] == [(p.name, f32(table[p.name])) for p in PARAMS]
    assert [t for _, _, t in pdata.params] == [3 if p.kind == INT32 else 4 for p in PARAMS]
    if query:
        defaults = {n.decode(): v for n, v, _ in pdata.defaults}
        assert defaults == {p.name: f32(p.default) for p in PARAMS}
    else:
        assert pdata.defaults is None
    assert nak(c.one(F.OP_CREATE_FILE, data=b"@PARAM/param.pck")) == (F.ERR_FILE_PROTECTED,)
    assert nak(c.one(F.OP_OPEN_FILE_RO, data=b"@PARAM/other.pck")) == (F.ERR_FILE_NOT_FOUND,)


RAPTOR_TAR = Path(__file__).parents[2] / "models" / "hover_px4_raptor_sih" / "policy.tar"


def renamed(name: str) -> bytes:
    tar = read_policy_tar(RAPTOR_TAR)
    return policy_tar_bytes(tar.weights, tar.example_in, tar.example_out, name)


def statustexts(msgs) -> list:
    return [(m.text, m.id, m.chunk_seq) for m in of_type(msgs, "STATUSTEXT")]


def test_a_damaged_policy_upload_is_refused_with_the_reason_in_statustext_chunks():
    c = Ftp()
    data = bytearray(renamed("x"))
    with tarfile.open(fileobj=io.BytesIO(bytes(data))) as archive:
        at = archive.getmember("actor/layers/2/biases/parameters/data").offset_data
    data[at + 3] ^= 0x01  # a weight's exponent bit: the stored example no longer replays
    c.g.received.clear()
    upload(c, F.POLICY_PATH, bytes(data))
    chunks = statustexts(c.g.received)
    assert (
        len(chunks) >= 2 and {i for _, i, _ in chunks} != {0} and [k for _, _, k in chunks] == list(range(len(chunks)))
    )
    text = "".join(t for t, _, _ in chunks)
    assert text.startswith("policy.tar refused: ") and "does not replay" in text, text
    assert c.g.commander.new_policy is None and c.g.commander.policies[-1]["sha256"] is None
    upload(c, "/fs/microsd/raptor/other.tar", bytes(data))  # another name on the card: not checked
    assert len(c.g.commander.policies) == 1


def test_a_good_policy_upload_is_loaded_into_a_raptor_monitor_only():
    from quadpilot.runtime.backends import load_policy
    from quadpilot.runtime.raptor import load_raptor
    from quadpilot.runtime.safety import SafetyMonitor
    from quadpilot.sitl import SHIPPED_HOVER

    c = Ftp()
    good = renamed("new-one")
    upload(c, F.POLICY_PATH, good)
    commander = c.g.commander
    assert statustexts(c.g.received)[-1] == ("policy.tar checked: new-one", 0, 0)
    assert commander.new_policy is not None and commander.new_policy.checkpoint_name == "new-one"
    onnx = SafetyMonitor(load_policy(SHIPPED_HOVER, "numpy"))
    assert not fly_uploaded(commander, onnx) and commander.new_policy is None
    assert commander.policies[-1]["text"] == "policy.tar not loaded: not flying a RAPTOR policy"
    upload(c, F.POLICY_PATH, good)
    monitor = SafetyMonitor(load_raptor(RAPTOR_TAR))
    before = monitor.policy
    assert fly_uploaded(commander, monitor)
    assert monitor.policy is not before and monitor.policy.info.source_sha256 == sha256_hex(good)
    assert commander.policies[-1] == {
        "at_s": commander.now,
        "text": "Policy loaded: new-one",
        "sha256": sha256_hex(good),
    }
    with pytest.raises(ValueError, match="same contract"):
        monitor.replace_policy(load_policy(SHIPPED_HOVER, "numpy"))


def test_a_request_like_an_earlier_one_but_not_the_last_is_done_again():
    c = Ftp()
    upload(c, "/fs/microsd/f", b"abc")
    first = c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/f", seq=0)
    assert c.one(F.OP_TERMINATE_SESSION, first["session"], seq=1)["opcode"] == F.OP_ACK
    again = c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/f", seq=0)  # a client that starts each transfer at 0
    assert again["opcode"] == F.OP_ACK and len(c.g.commander.ftp.sessions) == 1  # opened, not replayed


PATHS = [b"/fs/microsd/raptor/a.bin", b"/fs/microsd/raptor", b"/fs/microsd/new", b"@PARAM/param.pck", b"/", b"../x"]
PAYLOADS = st.builds(
    lambda seq, session, opcode, size, offset, data: (
        F.HEADER.pack(seq, session, opcode, size, 0, 0, 0, offset) + data
    ).ljust(F.PAYLOAD_LEN, b"\0")[: F.PAYLOAD_LEN],
    st.integers(0, 0xFFFF),
    st.sampled_from([0, 1, 2, 9, 255]) | st.integers(0, 255),
    st.integers(0, 16) | st.sampled_from([F.OP_ACK, F.OP_NAK, 200]),
    st.integers(0, 255),
    st.integers(0, 4000) | st.integers(0, 2**32 - 1),
    st.sampled_from(PATHS)
    | st.binary(max_size=F.MAX_DATA)
    | st.builds(lambda a, b: a + b"\0" + b, *[st.sampled_from(PATHS)] * 2),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(PAYLOADS | st.binary(min_size=F.PAYLOAD_LEN, max_size=F.PAYLOAD_LEN), min_size=1, max_size=8))
def test_any_ftp_payload_is_answered_at_once_and_never_raises(payloads):
    c = Ftp()
    upload(c, "/fs/microsd/raptor/a.bin", bytes(range(200)) * 3)  # something to read, rename, remove
    c.one(F.OP_OPEN_FILE_RO, data=b"/fs/microsd/raptor/a.bin")
    for raw in payloads:
        g = c.g
        out = of_type(g.send(g.tx.file_transfer_protocol_encode(0, 1, 1, list(raw))), "FILE_TRANSFER_PROTOCOL")
        opcode = raw[3]
        if opcode in (F.OP_ACK, F.OP_NAK):
            assert out == []
        else:
            assert 1 <= len(out) <= F.BURST_PACKETS + 1
            assert all(reply(m)["req"] == opcode for m in out)
        ftp = g.commander.ftp
        assert len(ftp.sessions) <= F.MAX_SESSIONS and ftp.card.used() <= F.MAX_CARD_BYTES
        assert ftp.card.entries() <= F.MAX_ENTRIES
    assert not [k for k in c.g.commander.dropped if k != "ftp_reply_to_vehicle"]

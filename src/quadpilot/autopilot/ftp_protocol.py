"""MAVLink FTP on the vehicle side: FILE_TRANSFER_PROTOCOL requests answered as PX4's MavlinkFTP does.

As https://mavlink.io/en/services/ftp.html defines it and PX4 answers it
(src/modules/mavlink/mavlink_ftp.cpp). Every request gets an answer at once: an ACK, or a NAK whose
first data byte is the error code (`ERR_*`; FailErrno adds the errno as a second byte), so a client
never waits out a time-out. The reply carries the request's header with `seq_number + 1`,
`req_opcode` = the request's opcode and `opcode` = ACK (128) or NAK (129), addressed to the sender.

What is served:
- `@PARAM/param.pck` (with or without `?withdefaults=1`), read-only: the parameter table in
  ArduPilot's packed form (`param_pack`), which MAVProxy asks for before PARAM_REQUEST_LIST. PX4 does
  not serve it: to PX4 it is a missing file (NAK FileNotFound), and MAVProxy then falls back to the
  parameter protocol; served here, MAVProxy has the whole table in one transfer.
- `/fs/microsd/...`: an SD card in memory (nothing is written to the host's disk), with the
  directory `/fs/microsd/raptor` in it, where PX4's mc_raptor finds `policy.tar`. Files are created,
  written, read, listed, renamed, truncated, removed and checksummed (CRC32 as PX4's `crc32part`:
  the reflected 0xEDB88320 table, initial value 0, no final inversion) through the usual opcodes.
  Anything else is read-only or absent: writing outside the card is NAK FileProtected.

Opcodes: TerminateSession, ResetSessions, ListDirectory, OpenFileRO, ReadFile, CreateFile, WriteFile,
RemoveFile, CreateDirectory, RemoveDirectory, OpenFileWO, TruncateFile, Rename, CalcFileCRC32,
BurstReadFile; None (0) is ACKed, as PX4 does; anything else is NAK UnknownCommand (MAVProxy's
ListDirectoryWithTime, 16, falls back to ListDirectory on it).

Sessions: at most `MAX_SESSIONS` open files (PX4 has one); another open is NAK NoSessionsAvailable. A
session's id is the one the request carried when that id is free (MAVProxy picks its own ids and
routes replies by them, as ArduPilot answers), else the lowest free id (what PX4 and MAVSDK expect:
the id comes back in the open's ACK). A session idle for `IDLE_CLOSE_S` is closed (PX4: 10 s). A
request repeated byte for byte, sequence number included (its answer was lost), gets the same answer
again without being done twice, when it is the last request of its sender on that session field and
its answer carried no data (PX4 keeps its one last reply for this).

Burst read: one BurstReadFile request is answered with up to `BURST_PACKETS` data ACKs (sequence
numbers counting up from the request's + 1); the last has `burst_complete` = 1 and the client asks for
the next burst at the offset that follows. The end of the file is a short last packet, or NAK
EndOfFile when the file ends on a packet boundary (PX4 streams until it sends that NAK).

Bounds: a file holds at most `MAX_FILE_BYTES` (a write beyond is NAK FailErrno EFBIG), the card
`MAX_CARD_BYTES` in all (ENOSPC) and `MAX_ENTRIES` files and directories (ENOSPC). Every field comes
from the wire and is checked before use: a size over 239 is NAK InvalidDataSize, a name that is not
ASCII or holds `..` is NAK FailErrno EINVAL, a session not open is NAK InvalidSession; a message
that is not a request at all (an ACK or NAK sent to the vehicle) is counted, not answered.

`handle(msg, now)` returns the messages to send (built with `mav`); `tick(now)` closes idle sessions;
`finished` lists the card files whose writing session was closed by TerminateSession since the
owner last emptied it (the commander checks an uploaded policy.tar from there).
"""

from __future__ import annotations

import errno
import struct
import zlib
from collections import Counter, OrderedDict
from dataclasses import dataclass, field

HEADER = struct.Struct("<HBBBBBBI")
"""seq_number, session, opcode, size, req_opcode, burst_complete, padding, offset."""
PAYLOAD_LEN = 251
MAX_DATA = PAYLOAD_LEN - HEADER.size  # 239

OP_NONE = 0
OP_TERMINATE_SESSION = 1
OP_RESET_SESSIONS = 2
OP_LIST_DIRECTORY = 3
OP_OPEN_FILE_RO = 4
OP_READ_FILE = 5
OP_CREATE_FILE = 6
OP_WRITE_FILE = 7
OP_REMOVE_FILE = 8
OP_CREATE_DIRECTORY = 9
OP_REMOVE_DIRECTORY = 10
OP_OPEN_FILE_WO = 11
OP_TRUNCATE_FILE = 12
OP_RENAME = 13
OP_CALC_FILE_CRC32 = 14
OP_BURST_READ_FILE = 15
OP_ACK = 128
OP_NAK = 129

ERR_NONE = 0
ERR_FAIL = 1
ERR_FAIL_ERRNO = 2
ERR_INVALID_DATA_SIZE = 3
ERR_INVALID_SESSION = 4
ERR_NO_SESSIONS_AVAILABLE = 5
ERR_EOF = 6
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_EXISTS = 8
ERR_FILE_PROTECTED = 9
ERR_FILE_NOT_FOUND = 10

MAX_SESSIONS = 3
IDLE_CLOSE_S = 10.0
BURST_PACKETS = 16
REPLAY_CACHE = 8
"""Senders and sessions whose last answer is kept for a repeated request."""
MAX_FILE_BYTES = 4 << 20
MAX_CARD_BYTES = 16 << 20
MAX_ENTRIES = 64

CARD = "/fs/microsd"
POLICY_DIR = CARD + "/raptor"
POLICY_PATH = POLICY_DIR + "/policy.tar"
"""Where PX4's mc_raptor loads its policy from on hardware (PX4's storage directory, raptor/)."""
PARAM_FILE = "@PARAM/param.pck"


class FtpError(Exception):
    """A request refused: the NAK's error code, and the errno for ERR_FAIL_ERRNO."""

    def __init__(self, code: int, err: int = 0) -> None:
        super().__init__(code, err)
        self.code, self.err = code, err


def crc32(data: bytes) -> int:
    """PX4's crc32part(data, len, 0): CRC-32 without the initial and final inversion (zlib's crc32
    inverts both)."""
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF


@dataclass
class Session:
    path: str
    writable: bool
    data: bytes | bytearray  # a snapshot for reading; the card's file itself for writing
    last: float


@dataclass
class Card:
    """The SD card in memory: files (path → bytes) and directories, bounded."""

    files: dict = field(default_factory=dict)
    dirs: set = field(default_factory=lambda: {"/", "/fs", CARD, POLICY_DIR})

    def used(self) -> int:
        return sum(len(d) for d in self.files.values())

    def entries(self) -> int:
        return len(self.files) + len(self.dirs)


def _parent(path: str) -> str:
    return path.rsplit("/", 1)[0] or "/"


class FtpServer:
    """See the module docstring. `param_file(with_defaults)` gives the bytes of @PARAM/param.pck;
    what is counted and not answered goes into `dropped` (the owner's counter, if given)."""

    def __init__(self, mav, param_file=None, dropped: Counter | None = None) -> None:
        self.mav = mav
        self.param_file = param_file
        self.card = Card()
        self.sessions: dict[int, Session] = {}
        self.finished: list[str] = []
        self.dropped: Counter = Counter() if dropped is None else dropped
        self._last: OrderedDict = OrderedDict()  # (sender, session) → (its last request, the answer)

    # --- the wire ---------------------------------------------------------------------------------
    def handle(self, msg, now: float) -> list:
        """One FILE_TRANSFER_PROTOCOL message → the messages to send."""
        raw = bytes(bytearray(msg.payload))[:PAYLOAD_LEN].ljust(PAYLOAD_LEN, b"\0")
        seq, session, opcode, size, _req, _burst, _pad, offset = HEADER.unpack_from(raw)
        if opcode in (OP_ACK, OP_NAK):  # an answer sent to the vehicle: not a request
            self.dropped["ftp_reply_to_vehicle"] += 1
            return []
        to = (msg.get_srcSystem(), msg.get_srcComponent())
        key = (to, session)
        last = self._last.pop(key, None)
        if last is not None and last[0] == raw:  # the same request again: its answer was lost
            self._last[key] = last
            return [self._message(to, last[1])]
        data = raw[HEADER.size : HEADER.size + size]
        try:
            if size > MAX_DATA:
                raise FtpError(ERR_INVALID_DATA_SIZE)
            if opcode == OP_BURST_READ_FILE:
                return [self._message(to, p) for p in self._burst(seq, session, size, offset, now)]
            session, out, out_offset = self._do(opcode, session, size, offset, data, now)
            reply = self._header(seq + 1, session, OP_ACK, opcode, out_offset, len(out)) + out
        except FtpError as e:
            body = bytes([e.code, e.err]) if e.code == ERR_FAIL_ERRNO else bytes([e.code])
            reply = self._header(seq + 1, session, OP_NAK, opcode, offset, len(body)) + body
        if len(reply) <= HEADER.size + 4:  # answers without data: kept for a repeated request
            self._last[key] = (raw, reply)
            while len(self._last) > REPLAY_CACHE:
                self._last.popitem(last=False)
        return [self._message(to, reply)]

    def tick(self, now: float) -> None:
        """Close sessions idle for IDLE_CLOSE_S (an upload abandoned there is not `finished`)."""
        for sid in [s for s, v in self.sessions.items() if now - v.last > IDLE_CLOSE_S]:
            del self.sessions[sid]

    def _header(self, seq: int, session: int, opcode: int, req: int, offset: int, size: int) -> bytes:
        return HEADER.pack(seq & 0xFFFF, session & 0xFF, opcode, size, req, 0, 0, offset)

    def _message(self, to, payload: bytes):
        body = list(payload.ljust(PAYLOAD_LEN, b"\0"))
        return self.mav.file_transfer_protocol_encode(0, to[0], to[1], body)

    # --- the work ------------------------------------------------------------------------------------
    def _do(self, op: int, sid: int, size: int, offset: int, data: bytes, now: float) -> tuple[int, bytes, int]:
        """(session of the answer, its data, its offset) of one request other than a burst."""
        if op == OP_NONE:
            return sid, b"", offset
        if op == OP_TERMINATE_SESSION:
            s = self._session(sid, now)
            del self.sessions[sid]
            if s.writable and s.path in self.card.files:
                self.finished.append(s.path)
            return sid, b"", offset
        if op == OP_RESET_SESSIONS:
            self.sessions.clear()
            return sid, b"", offset
        if op == OP_LIST_DIRECTORY:
            return sid, self._list(_name(data), offset), offset
        if op in (OP_OPEN_FILE_RO, OP_CREATE_FILE, OP_OPEN_FILE_WO):
            return self._open(op, sid, _name(data), now)
        if op == OP_READ_FILE:
            s = self._session(sid, now)
            if offset >= len(s.data):
                raise FtpError(ERR_EOF)
            return sid, bytes(s.data[offset : offset + (size or MAX_DATA)]), offset
        if op == OP_WRITE_FILE:
            s = self._session(sid, now)
            if not s.writable:
                raise FtpError(ERR_FAIL_ERRNO, errno.EBADF)
            self._write(s.data, offset, data)
            return sid, struct.pack("<I", len(data)), offset
        if op == OP_REMOVE_FILE:
            path = self._card_path(_name(data))
            if path in self.card.dirs:
                raise FtpError(ERR_FAIL_ERRNO, errno.EISDIR)
            if self.card.files.pop(path, None) is None:
                raise FtpError(ERR_FILE_NOT_FOUND)
            return sid, b"", offset
        if op == OP_CREATE_DIRECTORY:
            path = self._card_path(_name(data))
            self._may_create(path)
            self.card.dirs.add(path)
            return sid, b"", offset
        if op == OP_REMOVE_DIRECTORY:
            path = self._card_path(_name(data))
            if path not in self.card.dirs:
                raise FtpError(ERR_FILE_NOT_FOUND)
            if path in (CARD, POLICY_DIR):
                raise FtpError(ERR_FILE_PROTECTED)
            if any(_parent(p) == path for p in [*self.card.files, *self.card.dirs]):
                raise FtpError(ERR_FAIL_ERRNO, errno.ENOTEMPTY)
            self.card.dirs.discard(path)
            return sid, b"", offset
        if op == OP_TRUNCATE_FILE:
            path = self._card_path(_name(data))
            f = self.card.files.get(path)
            if f is None:
                raise FtpError(ERR_FILE_NOT_FOUND)
            if offset > len(f):
                self._write(f, offset, b"")
            del f[offset:]
            return sid, b"", offset
        if op == OP_RENAME:
            old, _, new = data.partition(b"\0")
            src, dst = self._card_path(_name(old)), self._card_path(_name(new))
            if src not in self.card.files:
                raise FtpError(ERR_FILE_NOT_FOUND)
            if dst != src:
                if dst not in self.card.files:
                    self._may_create(dst)
                self.card.files[dst] = self.card.files.pop(src)
            return sid, b"", offset
        if op == OP_CALC_FILE_CRC32:
            return sid, struct.pack("<I", crc32(bytes(self._read_file(_name(data))))), offset
        raise FtpError(ERR_UNKNOWN_COMMAND)

    def _session(self, sid: int, now: float) -> Session:
        s = self.sessions.get(sid)
        if s is None:
            raise FtpError(ERR_INVALID_SESSION)
        s.last = now
        return s

    def _open(self, op: int, asked: int, name: str, now: float) -> tuple[int, bytes, int]:
        if len(self.sessions) >= MAX_SESSIONS:
            raise FtpError(ERR_NO_SESSIONS_AVAILABLE)
        if op == OP_OPEN_FILE_RO:
            data = bytes(self._read_file(name))
            writable = False
            path = name
        else:
            path = self._card_path(name)
            f = self.card.files.get(path)
            if f is None:
                self._may_create(path)
                f = self.card.files[path] = bytearray()
            elif op == OP_CREATE_FILE:
                f.clear()  # O_CREAT | O_TRUNC, as PX4 opens it
            data, writable = f, True
        sid = asked if asked not in self.sessions else min(set(range(256)) - set(self.sessions))
        self.sessions[sid] = Session(path, writable, data, now)
        return sid, struct.pack("<I", len(data)), 0

    def _burst(self, seq: int, sid: int, size: int, offset: int, now: float) -> list[bytes]:
        s = self._session(sid, now)
        chunk = size if 0 < size <= MAX_DATA else MAX_DATA
        packets = []
        while len(packets) < BURST_PACKETS and offset < len(s.data):
            part = bytes(s.data[offset : offset + chunk])
            packets.append([offset, part])
            offset += len(part)
        out = []
        for i, (off, part) in enumerate(packets):
            last = i == len(packets) - 1
            head = HEADER.pack((seq + 1 + i) & 0xFFFF, sid, OP_ACK, len(part), OP_BURST_READ_FILE, int(last), 0, off)
            out.append(head + part)
        if not packets or (offset >= len(s.data) and len(packets[-1][1]) == chunk):
            # the end on a packet boundary (or at the offset asked for): NAK EndOfFile
            head = HEADER.pack((seq + 1 + len(packets)) & 0xFFFF, sid, OP_NAK, 1, OP_BURST_READ_FILE, 1, 0, offset)
            out.append(head + bytes([ERR_EOF]))
        return out

    def _read_file(self, name: str) -> bytes | bytearray:
        if name.lstrip("/").startswith("@PARAM/"):
            base, _, query = name.lstrip("/").partition("?")
            if base != PARAM_FILE or self.param_file is None:
                raise FtpError(ERR_FILE_NOT_FOUND)
            return self.param_file("withdefaults=1" in query.lower())
        path = _path(name)
        if path in self.card.dirs:
            raise FtpError(ERR_FAIL_ERRNO, errno.EISDIR)
        f = self.card.files.get(path)
        if f is None:
            raise FtpError(ERR_FILE_NOT_FOUND)
        return f

    def _list(self, name: str, offset: int) -> bytes:
        path = _path(name)
        if path not in self.card.dirs:
            raise FtpError(ERR_FAIL_ERRNO, errno.ENOTDIR) if path in self.card.files else FtpError(ERR_FILE_NOT_FOUND)
        dirs = [b"D" + d.rsplit("/", 1)[1].encode() for d in self.card.dirs if d != "/" and _parent(d) == path]
        files = [
            b"F%s\t%d" % (p.rsplit("/", 1)[1].encode(), len(f))
            for p, f in self.card.files.items()
            if _parent(p) == path
        ]
        entries = sorted(dirs + files)
        if offset >= len(entries) and offset > 0:
            raise FtpError(ERR_EOF)
        out = b""
        for e in entries[offset:]:
            if len(out) + len(e) + 1 > MAX_DATA:
                break
            out += e + b"\0"
        return out

    def _card_path(self, name: str) -> str:
        """The path of a file on the card that may be changed; FileProtected elsewhere."""
        path = _path(name)
        if not path.startswith(CARD + "/"):
            raise FtpError(ERR_FILE_PROTECTED)
        return path

    def _may_create(self, path: str) -> None:
        if path in self.card.files or path in self.card.dirs:
            raise FtpError(ERR_FILE_EXISTS)
        if _parent(path) not in self.card.dirs:
            raise FtpError(ERR_FILE_NOT_FOUND)
        if self.card.entries() >= MAX_ENTRIES:
            raise FtpError(ERR_FAIL_ERRNO, errno.ENOSPC)

    def _write(self, f: bytearray, offset: int, data: bytes) -> None:
        end = offset + len(data)
        if end > MAX_FILE_BYTES:
            raise FtpError(ERR_FAIL_ERRNO, errno.EFBIG)
        if end > len(f) and self.card.used() + end - len(f) > MAX_CARD_BYTES:
            raise FtpError(ERR_FAIL_ERRNO, errno.ENOSPC)
        if offset > len(f):
            f.extend(bytes(offset - len(f)))  # a write past the end fills the gap with zeros, as lseek does
        f[offset:end] = data


def _name(data: bytes) -> str:
    """The path in a request's data: up to the first NUL, ASCII; EINVAL otherwise."""
    raw = data.split(b"\0", 1)[0]
    try:
        return raw.decode("ascii")
    except UnicodeDecodeError:
        raise FtpError(ERR_FAIL_ERRNO, errno.EINVAL) from None


def _path(name: str) -> str:
    """An absolute path without empty, '.' or '..' parts; EINVAL for '..' or a control character."""
    parts = [p for p in name.split("/") if p not in ("", ".")]
    if ".." in parts or any(c < " " or c == "\x7f" for c in name):
        raise FtpError(ERR_FAIL_ERRNO, errno.EINVAL)
    return "/" + "/".join(parts)

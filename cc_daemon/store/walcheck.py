"""A journal's write-ahead log, checked frame by frame, in bounded memory and once.

SQLite stops reading a `-wal` at its first frame whose checksum is wrong and
says nothing: every row after it is silently missing. This module owns the
check SQLite does not report: it reads the log one frame at a time (never
whole: a log may be anything a stranger put there, see `store.files`), and
`WalCheck` remembers how far it got in each log, so a log that only grew since
(the daemon appending) is checked from where it was left, not from its start.

It never writes, and never opens a log that is not a regular file of at most
`files.WAL_MAX_BYTES`.
"""

from __future__ import annotations

import os
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from cc_daemon.store import files

WAL_MAGIC_LE = 0x377F0682
WAL_MAGIC_BE = 0x377F0683
_WAL_HEADER = 32
_FRAME_HEADER = 24
_ATTEMPTS = 3  # a live log the daemon restarts while we read is read again, this often
_REMEMBERED = 32  # logs whose progress is kept (a process reads one journal, or a few)
# A frame the daemon is writing as we read it reads as bad, and the frames it writes
# next as following a bad one: such a frame is read again, after this, this often.
_REREAD_S = 0.05


def _checksum(data: bytes, s0: int, s1: int, big_endian: bool) -> tuple[int, int]:
    words = struct.unpack(f"{'>' if big_endian else '<'}{len(data) // 4}I", data)
    for i in range(0, len(words), 2):
        s0 = (s0 + words[i] + s1) & 0xFFFFFFFF
        s1 = (s1 + words[i + 1] + s0) & 0xFFFFFFFF
    return s0, s1


@dataclass
class _Progress:
    """How far one log was checked: its header, the frames read, the running checksum."""

    identity: tuple[int, int]  # device, inode
    header: bytes
    size: int  # the bytes of whole frames checked
    frames: int
    s0: int
    s1: int
    bad: int | None = None  # the first frame SQLite will not read
    after_bad: bool = False  # a frame of the current log follows it: damage


def _header_damage(frames: int) -> str:
    return f"the write-ahead log's header is damaged: its {frames} frames are not read"


def _scan(log: BinaryIO, size: int, at: _Progress) -> None:
    """Check the frames of `log` past those `at` has seen, updating it."""
    magic, _, page_size, _, salt1, salt2, _, _ = struct.unpack(">8I", at.header)
    big = magic == WAL_MAGIC_BE
    step = _FRAME_HEADER + page_size
    frames = (size - _WAL_HEADER) // step
    for n in range(at.frames, frames):
        if at.after_bad:
            break
        log.seek(_WAL_HEADER + n * step)
        # Past the bad frame only the headers say whether the log went on.
        frame = log.read(step if at.bad is None else _FRAME_HEADER)
        if len(frame) < (step if at.bad is None else _FRAME_HEADER):
            break  # cut short while we read: the next check goes on from here
        f_salt1, f_salt2, f0, f1 = struct.unpack(">4I", frame[8:24])
        current = (f_salt1, f_salt2) == (salt1, salt2)
        if at.bad is None:
            s0, s1 = _checksum(frame[:8], at.s0, at.s1, big)
            s0, s1 = _checksum(frame[_FRAME_HEADER:], s0, s1, big)
            if not current or (s0, s1) != (f0, f1):
                at.bad = n
            else:
                at.s0, at.s1 = s0, s1
        elif current:
            at.after_bad = True
        at.frames = n + 1
        at.size = _WAL_HEADER + at.frames * step


class WalCheck:
    """The check of every log asked about, resumed where a log only grew. Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: dict[str, _Progress] = {}
        self._header = b""

    def __call__(self, db: Path) -> str | None:
        """What is wrong with `db`'s write-ahead log, if frames SQLite will not read follow
        a bad one (a torn last write, with nothing after it, is not damage)."""
        wal = Path(f"{db}-wal")
        refused = files.wal_refused(wal)
        if refused is not None:
            return refused
        try:
            log = files.open_regular(wal, files.WAL_MAX_BYTES)
        except files.NotAFileError as exc:  # swapped since it was judged
            return f"the write-ahead log is not read: {exc}"
        except OSError:
            return None
        with log, self._lock:
            for _ in range(_ATTEMPTS):
                verdict = self._check(str(wal), log)
                log.seek(0)
                if log.read(_WAL_HEADER) == self._header:
                    return verdict
                # The daemon restarted its log while we read: what we saw mixes two logs.
                self._seen.pop(str(wal), None)
        return None  # rewritten under us every time: a live log, which SQLite reads whole

    def _check(self, name: str, log: BinaryIO) -> str | None:
        st = os.fstat(log.fileno())
        log.seek(0)
        self._header = header = log.read(_WAL_HEADER)
        if len(header) < _WAL_HEADER:
            return None
        magic, _, page_size, _, _, _, c0, c1 = struct.unpack(">8I", header)
        step = _FRAME_HEADER + page_size
        frames = (st.st_size - _WAL_HEADER) // step if page_size else 0
        if magic not in (WAL_MAGIC_LE, WAL_MAGIC_BE) or page_size < 512:
            return _header_damage(frames)
        if _checksum(header[:24], 0, 0, magic == WAL_MAGIC_BE) != (c0, c1):
            return _header_damage(frames)
        at = self._seen.get(name)
        identity = (st.st_dev, st.st_ino)
        if at is None or (at.identity, at.header) != (identity, header) or at.size > st.st_size:
            s0, s1 = _checksum(header[:24], 0, 0, magic == WAL_MAGIC_BE)
            at = _Progress(identity, header, _WAL_HEADER, 0, s0, s1)
            self._seen.pop(name, None)
            while len(self._seen) >= _REMEMBERED:
                del self._seen[next(iter(self._seen))]  # the oldest
            self._seen[name] = at
        _scan(log, st.st_size, at)
        for _ in range(_ATTEMPTS):
            if at.bad is None or not at.after_bad:
                break
            _settle()  # a frame in flight is whole a moment later; a damaged one is not
            at.frames, at.size = at.bad, _WAL_HEADER + at.bad * step
            at.bad, at.after_bad = None, False
            _scan(log, os.fstat(log.fileno()).st_size, at)
        if at.bad is not None and at.after_bad:
            return (
                f"the write-ahead log is damaged at frame {at.bad + 1} of {frames}:"
                f" the last {frames - at.bad} frames (the newest rows) are not read"
            )
        return None


def _settle() -> None:
    time.sleep(_REREAD_S)


def wal_damage(db: Path) -> str | None:
    """`WalCheck` once, remembering nothing (for a command that checks one file once)."""
    return WalCheck()(db)

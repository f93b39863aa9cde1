"""The result journal: every answer of the service, in order, on disk, for listeners to resume from.

A journal is a folder::

    journal.json                  format, version and the journal's random id
    lock                          held (flock) by the one service writing the journal
    00000000000000000001.journal  segments, named by the sequence number of their first answer
    00000000000000004097.journal

A segment is a run of records, each a 16-byte header (payload length, CRC-32 of
the sequence number and payload, sequence number; little-endian) and the
payload: the answer exactly as it was published on the results channel.
Sequence numbers are consecutive across segments. Records are only ever
appended; a new segment starts when the current one reaches its size, and the
oldest segments are deleted to keep the journal within its bound.

One thread appends, flushes and commits while another reads (a lock keeps the
segment index whole). Flushing makes the appended answers survive a crash;
committing makes them visible: readers see only what is committed. The service
commits a batch of answers only once everything that goes with it is on disk
too (the states of its streams, :mod:`lostx.stream.states`), so what a reader
sees is never taken back, and a batch that cannot be completed is rolled back
(cut off the file) as if it had never been appended.

A record is written with one ``write`` call, so a killed service leaves whole
records behind; a crash of the machine can leave a torn record at the end,
which the next open finds by its CRC and cuts off. Damage anywhere else is
reported, never skipped: it would lose answers silently.
"""

from __future__ import annotations

import fcntl
import json
import os
import secrets
import struct
import threading
import zlib
from array import array
from bisect import bisect_right
from dataclasses import dataclass, field
from pathlib import Path

from lostx.core.outputs import sync_folder

from .errors import StreamError

FORMAT = "lostx-journal"
VERSION = 1
HEADER = struct.Struct("<IIQ")
"""Payload length, CRC-32 of (sequence number, payload), sequence number."""
SUFFIX = ".journal"


class JournalError(StreamError):
    """A journal folder that cannot be used: damaged, in use by another service, or not a journal."""


@dataclass
class _Segment:
    first: int
    """Sequence number of the segment's first record."""
    path: Path
    offsets: array = field(default_factory=lambda: array("q"))
    """Byte offset of each record; record i holds sequence number first + i."""
    size: int = 0

    @property
    def count(self) -> int:
        return len(self.offsets)


class Journal:
    """Append answers with their sequence numbers, make them durable, read them back from any point."""

    def __init__(self, folder: str | Path, *, segment_bytes: int = 16 << 20, max_bytes: int = 256 << 20,
                 fsync: bool = True) -> None:
        if segment_bytes < HEADER.size or max_bytes < segment_bytes:
            raise JournalError(f"journal sizes: need max_bytes ({max_bytes}) >= segment_bytes ({segment_bytes}) "
                               f">= {HEADER.size}")
        self.folder = Path(folder)
        self.segment_bytes = segment_bytes
        self.max_bytes = max_bytes
        self.fsync = fsync
        self._segments: list[_Segment] = []
        self._fd: int | None = None  # the last segment, open for appending
        self._dirty = False
        self._index_lock = threading.Lock()  # the segment index, between the writing and the reading thread
        self.committed = 0
        """The newest answer committed (all those found on opening count): what readers see."""
        self._lock_fd: int | None = None
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise JournalError(f"cannot create the journal folder {self.folder}: {exc.strerror}") from None
        self._lock_folder()
        try:
            self.id = self._identity()
            self._recover()
            self.committed = self.last
        except BaseException:
            self.close()
            raise

    # -- what it holds ---------------------------------------------------------------------------

    @property
    def first(self) -> int:
        """Sequence number of the oldest committed answer held (0 when none)."""
        with self._index_lock:
            held = [s for s in self._segments if s.count]
            return held[0].first if held and held[0].first <= self.committed else 0

    @property
    def last(self) -> int:
        """Sequence number of the newest answer appended (0 when empty)."""
        with self._index_lock:
            return self._last()

    def _last(self) -> int:
        for segment in reversed(self._segments):
            if segment.count:
                return segment.first + segment.count - 1
        return 0

    @property
    def nbytes(self) -> int:
        with self._index_lock:
            return self._nbytes()

    def _nbytes(self) -> int:
        return sum(s.size for s in self._segments)

    @property
    def segments(self) -> int:
        return len(self._segments)

    # -- writing ---------------------------------------------------------------------------------

    def append(self, seq: int, payload: bytes) -> None:
        """Write one answer. ``seq`` must follow the last one (any number >= 1 in an empty journal)."""
        last = self.last
        if (last and seq != last + 1) or seq < 1:
            raise JournalError(f"journal {self.folder}: answer {seq} does not follow answer {last}")
        current = self._segments[-1] if self._segments else None
        if self._fd is None or current is None or current.size >= self.segment_bytes or \
                (current.count == 0 and current.first != seq):
            self._start_segment(seq)
        segment = self._segments[-1]
        record = HEADER.pack(len(payload), _crc(seq, payload), seq) + payload
        _write_all(self._fd, record)
        with self._index_lock:
            segment.offsets.append(segment.size)
            segment.size += len(record)
        self._dirty = True

    def flush(self) -> None:
        """Make everything appended so far survive a crash (fsync, where configured), without showing it to
        readers: :meth:`commit` does that, once what goes with the answers is on disk too."""
        if self._dirty and self._fd is not None and self.fsync:
            os.fdatasync(self._fd)
        self._dirty = False

    def commit(self, seq: int | None = None) -> None:
        """Flush, and show readers the answers up to ``seq`` (default: all appended)."""
        self.flush()
        self.committed = self.last if seq is None else min(seq, self.last)

    def rollback(self) -> None:
        """Forget the answers appended since the last commit, in the index and on disk (in every segment they
        reached): after a failed write (a full disk, say) the journal is as it was committed, and the next answers
        are appended after it."""
        try:
            self._cut(self.committed)
        except OSError as exc:
            raise JournalError(f"journal {self.folder}: cannot cut off a failed write ({exc.strerror or exc})") \
                from None

    def cut_after(self, seq: int) -> None:
        """Delete the answers after ``seq``: written by a service that stopped before it acknowledged or
        published them (their batch never completed)."""
        if self.last > seq:
            self._cut(seq)
            self.committed = self.last

    def _cut(self, seq: int) -> None:
        """The journal as it was with ``seq`` its last answer: later segments deleted, the last one truncated
        (also of a record whose write failed halfway, which the index never counted)."""
        with self._index_lock:
            while len(self._segments) > 1 and self._segments[-1].first > seq:
                if self._fd is not None:
                    os.close(self._fd)
                    self._fd = None
                self._segments.pop().path.unlink(missing_ok=True)
            if not self._segments:
                return
            segment = self._segments[-1]
            keep = max(0, seq + 1 - segment.first)
            if keep < segment.count:
                segment.size = segment.offsets[keep]
                del segment.offsets[keep:]
            if self._fd is None:
                self._fd = os.open(segment.path, os.O_WRONLY | os.O_APPEND)
            os.ftruncate(self._fd, segment.size)
        self._sync_folder()
        self._dirty = False
        self.committed = min(self.committed, self.last)

    def _start_segment(self, seq: int) -> None:
        self.flush()
        with self._index_lock:
            self._rotate(seq)

    def _rotate(self, seq: int) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        if self._segments and self._segments[-1].count == 0:
            self._segments.pop().path.unlink(missing_ok=True)
        path = self.folder / f"{seq:020d}{SUFFIX}"
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self._sync_folder()  # the new file itself must survive a crash of the machine
        self._segments.append(_Segment(seq, path))
        # Room for the new segment to fill up: the journal stays within max_bytes (give or take a record).
        while len(self._segments) > 1 and self._nbytes() + self.segment_bytes > self.max_bytes:
            self._segments.pop(0).path.unlink(missing_ok=True)

    # -- reading ---------------------------------------------------------------------------------

    def read(self, after: int, max_items: int, max_bytes: int) -> list[bytes]:
        """Payloads of the committed answers after ``after``, oldest first: at most ``max_items``, and
        no more than ``max_bytes`` in all (but always one, where there is one)."""
        with self._index_lock:
            return self._read(after, max_items, max_bytes)

    def _read(self, after: int, max_items: int, max_bytes: int) -> list[bytes]:
        held = [s for s in self._segments if s.count]
        seq = max(after + 1, held[0].first if held else 0)
        out: list[bytes] = []
        total = 0
        while seq and seq <= self.committed and len(out) < max_items:
            index = bisect_right([s.first for s in self._segments], seq) - 1
            segment = self._segments[index]
            i = seq - segment.first
            with open(segment.path, "rb") as handle:
                while i < segment.count and seq <= self.committed and len(out) < max_items:
                    handle.seek(segment.offsets[i])
                    length, crc, stored = HEADER.unpack(handle.read(HEADER.size))
                    payload = handle.read(length)
                    if stored != seq or len(payload) != length or crc != _crc(seq, payload):
                        raise JournalError(f"journal {segment.path}: answer {seq} is damaged")
                    if out and total + len(payload) > max_bytes:
                        return out
                    out.append(payload)
                    total += len(payload)
                    i += 1
                    seq += 1
        return out

    def tail(self, n: int) -> list[bytes]:
        """Payloads of the newest ``n`` committed answers, oldest first."""
        return self.read(max(0, self.committed - n), n, 1 << 62)

    # -- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        if self._fd is not None:
            self.flush()
            os.close(self._fd)
            self._fd = None
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the lock
            self._lock_fd = None

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- opening ---------------------------------------------------------------------------------

    def _lock_folder(self) -> None:
        path = self.folder / "lock"
        try:
            self._lock_fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise JournalError(f"cannot write in the journal folder {self.folder}: {exc.strerror}") from None
        try:
            fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._lock_fd, 32, 0).decode(errors="replace").strip() or "another process"
            os.close(self._lock_fd)
            self._lock_fd = None
            raise JournalError(f"journal {self.folder} is in use by another service (pid {holder})") from None
        os.ftruncate(self._lock_fd, 0)
        os.pwrite(self._lock_fd, f"{os.getpid()}\n".encode(), 0)

    def _identity(self) -> str:
        path = self.folder / "journal.json"
        if path.exists():
            try:
                meta = json.loads(path.read_text())
                if meta.get("format") != FORMAT or not isinstance(meta.get("id"), str):
                    raise ValueError("not a lostx journal")
            except (ValueError, OSError) as exc:
                raise JournalError(f"{path}: {exc}") from None
            if meta.get("version") != VERSION:
                raise JournalError(f"{path}: journal version {meta.get('version')} (this lostx reads {VERSION})")
            return meta["id"]
        strangers = [p.name for p in self.folder.iterdir() if p.name not in ("lock", path.name + ".partial")]
        if strangers:
            raise JournalError(f"{self.folder} is not a lostx journal (it holds {', '.join(sorted(strangers)[:3])}); "
                               f"give an empty or new folder")
        journal_id = secrets.token_hex(8)
        tmp = path.with_name(path.name + ".partial")
        tmp.write_text(json.dumps({"format": FORMAT, "version": VERSION, "id": journal_id}) + "\n")
        tmp.replace(path)
        self._sync_folder()
        return journal_id

    def _recover(self) -> None:
        """Index every record; cut a torn record off the end of the last segment."""
        paths = sorted(self.folder.glob(f"*{SUFFIX}"))
        expected: int | None = None
        for n, path in enumerate(paths):
            try:
                first = int(path.name[:-len(SUFFIX)])
            except ValueError:
                raise JournalError(f"{path}: not a journal segment name") from None
            if expected is not None and first != expected:
                raise JournalError(f"journal {self.folder}: {path.name} should start at answer {expected}")
            segment = _Segment(first, path)
            data = path.read_bytes()
            pos = 0
            while pos < len(data):
                seq = first + segment.count
                if pos + HEADER.size > len(data):
                    break
                length, crc, stored = HEADER.unpack_from(data, pos)
                payload = data[pos + HEADER.size:pos + HEADER.size + length]
                if stored != seq or len(payload) != length or crc != _crc(seq, payload):
                    break
                segment.offsets.append(pos)
                pos += HEADER.size + length
            if pos < len(data):
                if n != len(paths) - 1:
                    raise JournalError(f"journal {path} is damaged at byte {pos} (answer {first + segment.count}); "
                                       f"move the journal aside to start a new one")
                os.truncate(path, pos)  # a torn write at the very end: that answer was never acknowledged
            segment.size = pos
            self._segments.append(segment)
            expected = first + segment.count
        if self._segments:
            self._fd = os.open(self._segments[-1].path, os.O_WRONLY | os.O_APPEND)

    def _sync_folder(self) -> None:
        if self.fsync:
            sync_folder(self.folder)


def _crc(seq: int, payload: bytes) -> int:
    return zlib.crc32(payload, zlib.crc32(struct.pack("<Q", seq)))


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]

"""Each stream's localizer state beside the journal, so that a restarted service carries on where it stopped.

A localizer's answer depends on the frames before it (the sequence window, the
tracker, the heading filter, the running query statistics:
:meth:`lostx.core.localizer.Localizer.state`). The journal keeps the answers,
not that state, and the state of a stream is far larger than an answer, so it
is not journaled with every answer. Instead the journal folder holds, in
``states/``, one file per batch of answers, written by the journal thread::

    states/<seq>.batch   after the batch ending at answer seq: the state of each stream it answered whose state
                         changed, and the index of every live stream's newest state (which batch file holds it)

A batch is complete once its answers are flushed to the journal and its batch
file is written (whole, under a temporary name, then renamed, the folder
synced): one file and two syncs a batch, however many streams it answered.
Only then is the journal committed to it, its frames acknowledged and its
answers published; the newest batch file is the mark of what is durable. A
service killed halfway through a batch leaves answers past that mark: the next
service cuts them off (nobody was told of them; their frames come again), reads
the newest batch file's index, takes each live stream's newest state from the
file that holds it, and so answers the next frames as the uninterrupted service
would have. A batch file that no index names any more is deleted: the folder
holds the newest batch and those holding some live stream's newest state,
whatever the length of the traverse.

States are msgpack: numpy arrays as their dtype, shape and bytes (never pickle).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from lostx.core.budget import format_bytes
from lostx.core.config import StreamConfig
from lostx.core.outputs import sync_folder

from .errors import StreamError

SUFFIX = ".batch"
_ARRAY = 1
"""msgpack extension type of a numpy array: [dtype, shape, bytes] or, for float64 values that float32 holds
exactly (most of a state: costs computed in float32), [dtype, shape, float32 bytes, "<f4"]."""


class StateFileError(StreamError):
    """A saved state that cannot be read."""


def pack(state: Any) -> bytes:
    """A state of plain values, lists, string-keyed maps and numpy arrays, as msgpack."""
    return msgpack.packb(state, default=_encode, use_bin_type=True)


def unpack(data: bytes) -> Any:
    return msgpack.unpackb(data, ext_hook=_decode, raw=False, strict_map_key=False)


def _encode(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        fields = [array.dtype.str, list(array.shape), array.tobytes()]
        if array.dtype == np.float64:
            narrow = array.astype(np.float32)
            if np.array_equal(narrow, array, equal_nan=True):
                fields[2:] = [narrow.tobytes(), narrow.dtype.str]
        return msgpack.ExtType(_ARRAY, msgpack.packb(fields, use_bin_type=True))
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"a localizer state holds a {type(value).__name__}, which does not pack")


def _decode(code: int, data: bytes) -> Any:
    if code != _ARRAY:
        raise StateFileError(f"unknown msgpack extension {code} in a saved state")
    dtype, shape, raw, *stored = msgpack.unpackb(data, raw=False)
    if np.dtype(dtype).hasobject or any(np.dtype(s).hasobject for s in stored):
        raise StateFileError("a saved state holds an array of objects")
    return np.frombuffer(raw, dtype=np.dtype(stored[0] if stored else dtype)).reshape(shape).astype(dtype)


@dataclass(frozen=True)
class SavedState:
    """A stream's state after one of its answers: the localizer's, and what the service keeps of the stream."""

    stream: str
    seq: int
    """The service-wide sequence number of the answer after which the state was taken."""
    answers: int
    """The stream's answers so far (that answer's ``stream_seq``)."""
    last_timestamp: float | None
    """The timestamp of the stream's last frame handed to the localizer."""
    localizer: bytes
    """:meth:`lostx.core.localizer.Localizer.state`, packed."""

    def same_as(self, other: "SavedState | None") -> bool:
        """Whether ``other`` holds the same state of the same stream (whatever answers came between)."""
        return (other is not None and other.stream == self.stream and other.last_timestamp == self.last_timestamp
                and other.localizer == self.localizer)


class StateStore:
    """The ``states/`` folder of a journal. Written by the journal thread only; read once, at start."""

    def __init__(self, journal_folder: Path, fsync: bool = True) -> None:
        self.folder = Path(journal_folder) / "states"
        self.fsync = fsync
        self.folder.mkdir(exist_ok=True)
        for path in self.folder.glob("*.partial"):
            path.unlink()  # written by a service killed before it renamed it
        self._batches = sorted(_parse(path.name) for path in self.folder.glob(f"*{SUFFIX}"))
        """The seqs of the batch files on disk, oldest first."""
        self._index: dict[str, int] = {}
        """Each live stream's newest state: the batch (its seq) whose file holds it."""
        self._written: dict[str, SavedState] = {}
        """The newest state written of each live stream, to write a stream only when its state changed."""
        self._bytes: dict[int, int] = {}
        """The size of each batch file written (or found)."""

    def durable(self) -> int | None:
        """The last answer of the last complete batch; None where no batch was ever written."""
        return self._batches[-1] if self._batches else None

    def complete(self, seq: int, states: list[SavedState]) -> int:
        """Mark the batch ending at answer ``seq`` complete with the newest state of each stream it answered (a
        state the stream had already, e.g. after a frame refused before the localizer, is not written again);
        then drop the batch files no index names any more. Returns the bytes written."""
        changed = [state for state in states if not state.same_as(self._written.get(state.stream))]
        index = {**self._index, **{state.stream: seq for state in changed}}
        record = {"seq": seq, "index": index,
                  "states": [[s.stream, s.seq, s.answers, s.last_timestamp, s.localizer] for s in changed]}
        data = msgpack.packb(record, use_bin_type=True)
        _write_whole(self._path(seq), data, self.fsync)
        try:
            self._sync_folder()
        except OSError:
            self._path(seq).unlink(missing_ok=True)
            raise
        self._index = index
        self._written.update((state.stream, state) for state in changed)
        self._batches.append(seq)
        self._bytes[seq] = len(data)
        self._drop_unnamed()
        return len(data)

    def forget(self, stream: str) -> None:
        """Drop the stream's state: it expired, and its next frame starts afresh. The next batch's index leaves it
        out (and its file goes once no index names it)."""
        self._index.pop(stream, None)
        self._written.pop(stream, None)

    def discard_after(self, seq: int) -> None:
        """Delete the batch files after answer ``seq``: their batch was not completed after all."""
        for batch in [b for b in self._batches if b > seq]:
            self._path(batch).unlink(missing_ok=True)
            self._batches.remove(batch)

    def recover(self, durable: int) -> dict[str, SavedState]:
        """Each live stream's newest state as the last batch file at or before answer ``durable`` names it;
        later batch files and those no index names are deleted."""
        self.discard_after(durable)
        if not self._batches:
            return {}
        newest = self._read(self._batches[-1])
        index = newest.get("index")
        if not isinstance(index, dict):
            raise StateFileError(f"{self._path(self._batches[-1])}: not a batch of states (no index)")
        out: dict[str, SavedState] = {}
        files = {self._batches[-1]: newest}
        for stream, batch in index.items():
            if batch not in files:
                files[batch] = self._read(batch)
            for record in files[batch].get("states", []):
                if record[0] == stream:
                    out[stream] = SavedState(*record)
            if stream not in out:
                raise StateFileError(f"{self._path(batch)}: holds no state of stream {stream!r}, which the index of "
                                     f"{self._path(self._batches[-1]).name} names")
        self._index = dict(index)
        self._written = dict(out)
        self._drop_unnamed()
        return out

    def probe(self, nbytes: int) -> None:
        """Write and sync ``nbytes`` in the folder, then delete them: OSError where the disk cannot take them (is it
        still full?)."""
        path = self.folder / "probe"
        try:
            _write_whole(path, bytes(nbytes), self.fsync)
        finally:
            path.unlink(missing_ok=True)

    @property
    def nbytes(self) -> int:
        """Bytes of the batch files held (of those this store wrote or found)."""
        return sum(self._bytes.get(b, 0) for b in self._batches)

    def _drop_unnamed(self) -> None:
        """Delete the batch files neither the newest nor named by the index (best effort: a file left over is
        deleted next time)."""
        named = set(self._index.values()) | set(self._batches[-1:])
        for batch in [b for b in self._batches if b not in named]:
            try:
                self._path(batch).unlink(missing_ok=True)
            except OSError:
                continue
            self._batches.remove(batch)
            self._bytes.pop(batch, None)

    def _read(self, seq: int) -> dict:
        path = self._path(seq)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise StateFileError(f"{path}: {exc.strerror}") from None
        self._bytes[seq] = len(data)
        try:
            record = msgpack.unpackb(data, raw=False)
        except (ValueError, TypeError) as exc:
            raise StateFileError(f"{path}: not a batch of states ({exc})") from None
        if not isinstance(record, dict) or record.get("seq") != seq:
            raise StateFileError(f"{path}: not a batch of states")
        return record

    def _path(self, seq: int) -> Path:
        return self.folder / f"{seq:020d}{SUFFIX}"

    def _sync_folder(self) -> None:
        if self.fsync:
            sync_folder(self.folder)


def _parse(name: str) -> int:
    seq = name[: -len(SUFFIX)]
    if not seq.isdigit():
        raise StateFileError(f"{name}: not a batch file name (the number of its last answer)")
    return int(seq)


def _write_whole(path: Path, data: bytes, fsync: bool) -> None:
    """Write ``data`` under a temporary name and rename it: the file is there whole or not at all."""
    tmp = path.with_name(path.name + ".partial")
    try:
        with open(tmp, "wb") as handle:
            handle.write(data)
            handle.flush()
            if fsync:
                os.fsync(handle.fileno())
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def journal_space(config: StreamConfig, state_bytes: int) -> str | None:
    """Whether the journal folder's disk has room for the journal at its bound (``journal_max_bytes``) and the
    states of ``max_streams`` streams (each at most ``state_bytes``, twice over while a batch replaces them): None
    where it does, else a line saying what is needed and what is free. What the journal holds already counts as
    room."""
    assert config.journal is not None
    folder = Path(config.journal)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    held = sum(p.stat().st_size for p in Path(config.journal).rglob("*") if p.is_file()) \
        if Path(config.journal).is_dir() else 0
    free = shutil.disk_usage(folder).free + held
    states = 2 * config.max_streams * state_bytes
    need = config.journal_max_bytes + states
    if free >= need:
        return None
    return (f"the journal {config.journal} may need {format_bytes(need)} (journal_max_bytes "
            f"{format_bytes(config.journal_max_bytes)}, and the states of {config.max_streams} streams, "
            f"{format_bytes(state_bytes)} each at most, twice over while a batch replaces them), and its disk has "
            f"{format_bytes(free)}: when the disk is full, frames are refused (journal_unwritable) until there is "
            f"room again; lower journal_max_bytes or max_streams, or free some space")

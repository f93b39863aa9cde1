"""Each stream's localizer state beside the journal, so that a restarted service carries on where it stopped.

A localizer's answer depends on the frames before it (the sequence window, the
tracker, the heading filter, the running query statistics:
:meth:`lostx.core.localizer.Localizer.state`). The journal keeps the answers,
not that state, and the state of a stream is far larger than an answer (the
window's costs of every map frame: about 300 kB over Nordland's 3,576 frames),
so it is not journaled with every answer. Instead the journal folder holds, in
``states/``, the newest state of each stream, written by the journal thread
after each batch of answers::

    states/<stream id hash>-<seq>.state   the stream's state after its answer number seq (msgpack)
    states/durable                        the last answer whose batch is complete: journal and states on disk

A batch is complete once its answers are committed to the journal, the state
of every stream it answered is written (each file written whole under a
temporary name, then renamed), and ``durable`` names the batch's last answer;
only then are its frames acknowledged and its answers published. A service
killed halfway through a batch leaves answers and states past ``durable``: the
next service cuts them off (nobody was told of them; their frames come again),
takes each stream's newest state at or before ``durable``, and so answers the
next frames as the uninterrupted service would have. Old states are deleted as
newer ones complete: the folder holds one state per live stream (two during a
batch), whatever the length of the traverse.

States are msgpack: numpy arrays as their dtype, shape and bytes (never pickle).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from lostx.core.outputs import sync_folder

from .errors import StreamError

SUFFIX = ".state"
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


class StateStore:
    """The ``states/`` folder of a journal. Written by the journal thread only; read once, at start."""

    def __init__(self, journal_folder: Path, fsync: bool = True) -> None:
        self.folder = Path(journal_folder) / "states"
        self.fsync = fsync
        self.folder.mkdir(exist_ok=True)
        self._files: dict[str, list[int]] = {}
        """The seqs of each stream's state files (by the hash of its id), oldest first."""
        for path in self.folder.glob("*.partial"):
            path.unlink()  # written by a service killed before it renamed it
        for path in self.folder.glob(f"*{SUFFIX}"):
            key, seq = _parse(path.name)
            self._files.setdefault(key, []).append(seq)
        for seqs in self._files.values():
            seqs.sort()

    def durable(self) -> int | None:
        """The last answer of the last complete batch; None in a journal written without states."""
        try:
            return int((self.folder / "durable").read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            raise StateFileError(f"{self.folder / 'durable'}: {exc}") from None

    def write(self, states: list[SavedState]) -> None:
        """The states of one batch, each under a new name (the older ones stay until :meth:`complete`)."""
        for state in states:
            key = _key(state.stream)
            record = [state.stream, state.seq, state.answers, state.last_timestamp, state.localizer]
            _write_whole(self._path(key, state.seq), msgpack.packb(record, use_bin_type=True), self.fsync)
            self._files.setdefault(key, []).append(state.seq)

    def holds(self, state: SavedState) -> bool:
        """Whether this state is written already (a batch tried again)."""
        return state.seq in self._files.get(_key(state.stream), ())

    def complete(self, seq: int) -> None:
        """Mark the batch ending at answer ``seq`` complete, and drop the states it superseded."""
        self._sync_folder()
        _write_whole(self.folder / "durable", f"{seq}\n".encode(), self.fsync)
        self._sync_folder()
        for key, seqs in self._files.items():
            while len(seqs) > 1:
                self._path(key, seqs.pop(0)).unlink(missing_ok=True)

    def forget(self, stream: str) -> None:
        """Drop the stream's states: it expired, and its next frame starts afresh."""
        key = _key(stream)
        for seq in self._files.pop(key, []):
            self._path(key, seq).unlink(missing_ok=True)

    def recover(self, durable: int) -> dict[str, SavedState]:
        """Each stream's newest state at or before answer ``durable``; those after it are deleted."""
        out: dict[str, SavedState] = {}
        for key, seqs in list(self._files.items()):
            for seq in [s for s in seqs if s > durable]:
                self._path(key, seq).unlink(missing_ok=True)
                seqs.remove(seq)
            for seq in seqs[:-1]:
                self._path(key, seq).unlink(missing_ok=True)
            del seqs[:-1]
            if not seqs:
                del self._files[key]
                continue
            path = self._path(key, seqs[-1])
            try:
                saved = SavedState(*msgpack.unpackb(path.read_bytes(), raw=False))
            except OSError as exc:
                raise StateFileError(f"{path}: {exc.strerror}") from None
            except (ValueError, TypeError) as exc:
                raise StateFileError(f"{path}: not a saved state ({exc})") from None
            out[saved.stream] = saved
        return out

    def _path(self, key: str, seq: int) -> Path:
        return self.folder / f"{key}-{seq:020d}{SUFFIX}"

    def _sync_folder(self) -> None:
        if self.fsync:
            sync_folder(self.folder)


def _key(stream: str) -> str:
    """A file name for any stream id (up to 256 characters of any kind)."""
    return hashlib.sha256(stream.encode()).hexdigest()[:32]


def _parse(name: str) -> tuple[str, int]:
    key, _, seq = name[: -len(SUFFIX)].partition("-")
    if len(key) != 32 or not seq.isdigit():
        raise StateFileError(f"{name}: not a state file name (the stream's hash, then the answer number)")
    return key, int(seq)


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

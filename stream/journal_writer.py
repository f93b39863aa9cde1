"""The service's journal thread: answers and stream states written and made durable off the I/O loop, in batches.

An fsync takes milliseconds (4.5 ms measured on the shared development disk),
and the I/O loop must keep reading frames, serving listeners and publishing
meanwhile. So the loop hands each numbered answer (with its stream's state
after it) to this thread, which appends everything handed to it since its last
flush and flushes once (a group commit: the slower the disk, the larger the
batches), writes the batch's file of states (:mod:`lostx.stream.states`), then
commits the journal to the batch and tells the loop how far it is durable. The
loop acknowledges and publishes an answer only once it is.

A write that fails with an OS error (a full disk, a failing one) is undone:
the journal is cut back to its last complete batch and the batch's file
deleted, so nothing that was not durable is ever read back, served or kept
across a restart. The thread then drops every answer handed over before it
heard of the failure (:attr:`epoch` counts the failures; the loop withdraws
those answers and refuses their frames, which come again) and reports the
failure through :attr:`failure` until a write of the failed batch's size
succeeds (tried every :data:`RETRY_S` seconds): then the loop takes frames again.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass

import zmq

from .journal import Journal
from .states import SavedState, StateStore

RETRY_S = 1.0
"""Seconds between tries of a disk that could not be written."""
PROBE_BYTES = 4096
"""Least size of a trial write (the failed batch's size where larger)."""


@dataclass(frozen=True)
class _Answer:
    epoch: int
    """The failures the I/O loop had heard of when it numbered the answer."""
    seq: int
    payload: bytes
    state: SavedState | None


@dataclass(frozen=True)
class _Forget:
    """The stream expired: its saved state goes (its next frame starts afresh)."""

    stream: str


_Item = _Answer | _Forget


class JournalWriter(threading.Thread):
    """Appends and commits the answers :meth:`write` hands over; :attr:`durable` tells how far it got."""

    def __init__(self, journal: Journal, states: StateStore, context: zmq.Context, wake_endpoint: str) -> None:
        super().__init__(name="lostx-journal", daemon=True)
        self.journal = journal
        self.states = states
        self.durable = journal.committed
        """The newest answer written and flushed, with the states of its batch: only ever grows."""
        self.epoch = 0
        """How many writes have failed: answers handed over in an earlier epoch than this are dropped, unwritten."""
        self.failure: str | None = None
        """Why the last write failed (the disk is full, say), until a trial write succeeds; None when writing."""
        self.error: BaseException | None = None
        """What stopped the writing (a damaged journal, say); nothing is written after it."""
        self.written = 0
        """Bytes written to the disk so far (answers and states)."""
        self._items: queue.SimpleQueue[_Item | None] = queue.SimpleQueue()
        self._context = context
        self._wake_endpoint = wake_endpoint
        self._probe_bytes = PROBE_BYTES

    def write(self, seq: int, payload: bytes, state: SavedState | None, epoch: int) -> None:
        """Hand over answer ``seq`` (and its stream's state after it), numbered in failure epoch ``epoch``."""
        self._items.put(_Answer(epoch, seq, payload, state))

    def forget(self, stream: str) -> None:
        self._items.put(_Forget(stream))

    def close(self) -> None:
        """Write and flush everything handed over so far (where the disk takes it), then end the thread."""
        self._items.put(None)
        if self.is_alive():
            self.join()

    def run(self) -> None:
        # The wake-up socket is made here: a ZeroMQ socket belongs to the thread that uses it.
        wake = self._context.socket(zmq.PAIR)
        wake.connect(self._wake_endpoint)
        try:
            done = False
            while not done:
                try:
                    item = self._items.get(timeout=RETRY_S if self.failure is not None else None)
                except queue.Empty:
                    item = False  # time to try the disk again
                batch: list[_Item] = []
                while item is not None and item is not False:
                    batch.append(item)
                    try:
                        item = self._items.get_nowait()
                    except queue.Empty:
                        break
                done = item is None
                before = (self.durable, self.epoch, self.failure)
                self._handle(batch)
                if (self.durable, self.epoch, self.failure) != before or self.error is not None:
                    try:
                        wake.send(b"", zmq.NOBLOCK)
                    except zmq.Again:
                        pass  # the loop has a wake-up pending already; it reads durable then
                if self.error is not None:
                    return
        finally:
            wake.close(linger=0)

    def _handle(self, batch: list[_Item]) -> None:
        # Answers numbered before the loop heard of the last failure were withdrawn: they are not written.
        batch = [item for item in batch if isinstance(item, _Forget) or item.epoch == self.epoch]
        answers = [item for item in batch if isinstance(item, _Answer)]
        try:
            if answers:
                self._write(batch)
                self.failure = None
            else:
                for item in batch:
                    self.states.forget(item.stream)  # type: ignore[union-attr]
                if self.failure is not None:
                    self.states.probe(self._probe_bytes)
                    self.failure = None
        except OSError as exc:  # a full or failing disk: undone, and the answers handed over so far dropped
            self.failure = f"{exc.strerror or exc}"
            if answers:
                # The disk is tried again with as many bytes as this batch needed.
                self._probe_bytes = max(PROBE_BYTES, sum(len(a.payload) + len(a.state.localizer if a.state else b"")
                                                         for a in answers))
                self.epoch += 1
                try:
                    self.journal.rollback()
                    self.states.discard_after(self.durable)
                except Exception as fatal:
                    self.error = fatal
        except Exception as exc:  # reported to the I/O loop, which stops the service
            self.error = exc

    def _write(self, batch: list[_Item]) -> None:
        """Append the batch's answers, flush, write its states and so complete it, then commit the journal to it."""
        newest: dict[str, SavedState] = {}
        seq = self.durable
        for item in batch:
            if isinstance(item, _Forget):
                newest.pop(item.stream, None)
                self.states.forget(item.stream)
                continue
            self.journal.append(item.seq, item.payload)
            seq = item.seq
            if item.state is not None:
                newest[item.state.stream] = item.state
        self.journal.flush()
        written = self.states.complete(seq, list(newest.values()))
        self.journal.commit(seq)
        self.durable = seq
        self.written += written + sum(len(item.payload) for item in batch if isinstance(item, _Answer))

"""The service's journal thread: answers and stream states written and made durable off the I/O loop, in batches.

An fsync takes milliseconds (4.5 ms measured on the shared development disk),
and the I/O loop must keep reading frames, serving listeners and publishing
meanwhile. So the loop hands each numbered answer (with its stream's state
after it) to this thread, which appends everything handed to it since its last
flush and flushes once (a group commit: the slower the disk, the larger the
batches), writes the newest state of each stream the batch answered
(:mod:`lostx.stream.states`), then tells the loop how far the journal is
durable. The loop acknowledges and publishes an answer only once it is.

A write that fails with an OS error (a full disk, a failing one) is undone
(:meth:`Journal.rollback`), reported to the loop through :attr:`failure`, and
tried again every :data:`RETRY_S` seconds with everything handed over since,
until it succeeds: the service stays up meanwhile, and nothing is acknowledged
that is not on disk.
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass

import zmq

from .journal import Journal
from .states import SavedState, StateStore

RETRY_S = 1.0
"""Seconds between tries of a write that failed."""


@dataclass(frozen=True)
class _Forget:
    """The stream expired: its saved state goes (its next frame starts afresh)."""

    stream: str


_Item = tuple[int, bytes, SavedState | None] | _Forget


class JournalWriter(threading.Thread):
    """Appends and commits the answers :meth:`write` hands over; :attr:`durable` tells how far it got."""

    def __init__(self, journal: Journal, states: StateStore, context: zmq.Context, wake_endpoint: str) -> None:
        super().__init__(name="lostx-journal", daemon=True)
        self.journal = journal
        self.states = states
        self.durable = journal.committed
        """The newest answer written and flushed, with the states of its batch."""
        self.failure: str | None = None
        """Why the last write failed (the disk is full, say), while it is being tried again; None when writing."""
        self.error: BaseException | None = None
        """What stopped the writing (a damaged journal, say); nothing is written after it."""
        self._items: queue.SimpleQueue[_Item | None] = queue.SimpleQueue()
        self._context = context
        self._wake_endpoint = wake_endpoint

    def write(self, seq: int, payload: bytes, state: SavedState | None = None) -> None:
        self._items.put((seq, payload, state))

    def forget(self, stream: str) -> None:
        self._items.put(_Forget(stream))

    def close(self) -> None:
        """Write and flush everything handed over so far (one more try where writing fails), then end the thread."""
        self._items.put(None)
        if self.is_alive():
            self.join()

    def run(self) -> None:
        # The wake-up socket is made here: a ZeroMQ socket belongs to the thread that uses it.
        wake = self._context.socket(zmq.PAIR)
        wake.connect(self._wake_endpoint)
        pending: list[_Item] = []
        try:
            done = False
            while not done:
                try:
                    item = self._items.get(timeout=RETRY_S if pending else None)
                except queue.Empty:
                    item = False  # time to try the failed write again
                while item is not None and item is not False:
                    pending.append(item)
                    try:
                        item = self._items.get_nowait()
                    except queue.Empty:
                        break
                done = item is None
                if not pending:
                    continue
                try:
                    self._write(pending)
                except OSError as exc:  # a full or failing disk: undone, and tried again
                    self.failure = f"{exc.strerror or exc}"
                    try:
                        self.journal.rollback()
                    except Exception as fatal:
                        self.error, done = fatal, True
                except Exception as exc:  # reported to the I/O loop, which stops the service
                    self.error, done = exc, True
                else:
                    pending, self.failure = [], None
                try:
                    wake.send(b"", zmq.NOBLOCK)
                except zmq.Again:
                    pass  # the loop has a wake-up pending already; it reads durable then
        finally:
            wake.close(linger=0)

    def _write(self, batch: list[_Item]) -> None:
        """Append what is not in the journal yet, commit, then write the batch's states and mark it complete.
        Tried again from the start after a failure: every step is idempotent."""
        last = self.journal.last
        newest: dict[str, SavedState] = {}
        seq = None
        for item in batch:
            if isinstance(item, _Forget):
                newest.pop(item.stream, None)
                self.states.forget(item.stream)
                continue
            seq, payload, state = item
            if seq > last:
                self.journal.append(seq, payload)
            if state is not None:
                newest[state.stream] = state
        self.journal.commit()
        if seq is not None:
            self.states.write([s for s in newest.values() if not self.states.holds(s)])
            self.states.complete(seq)
            self.durable = seq

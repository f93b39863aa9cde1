"""The service's journal thread: answers written and made durable off the I/O loop, in batches.

An fsync takes milliseconds (4.5 ms measured on the shared development disk),
and the I/O loop must keep reading frames, serving listeners and publishing
meanwhile. So the loop hands each numbered answer to this thread, which
appends everything handed to it since its last flush and flushes once (a group
commit: the slower the disk, the larger the batches), then tells the loop how
far the journal is durable. The loop acknowledges and publishes an answer only
once it is.
"""

from __future__ import annotations

import queue
import threading

import zmq

from .journal import Journal


class JournalWriter(threading.Thread):
    """Appends and commits the answers :meth:`write` hands over; :attr:`durable` tells how far it got."""

    def __init__(self, journal: Journal, context: zmq.Context, wake_endpoint: str) -> None:
        super().__init__(name="lostx-journal", daemon=True)
        self.journal = journal
        self.durable = journal.committed
        """The newest answer written and flushed."""
        self.error: BaseException | None = None
        """What stopped the writing (a full disk, say); nothing is written after it."""
        self._items: queue.SimpleQueue[tuple[int, bytes] | None] = queue.SimpleQueue()
        self._context = context
        self._wake_endpoint = wake_endpoint

    def write(self, seq: int, payload: bytes) -> None:
        self._items.put((seq, payload))

    def close(self) -> None:
        """Write and flush everything handed over so far, then end the thread."""
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
                batch: list[tuple[int, bytes]] = []
                item = self._items.get()
                while item is not None:
                    batch.append(item)
                    try:
                        item = self._items.get_nowait()
                    except queue.Empty:
                        break
                done = item is None
                if not batch:
                    continue
                try:
                    for seq, payload in batch:
                        self.journal.append(seq, payload)
                    self.journal.commit()
                except Exception as exc:  # reported to the I/O loop, which stops the service
                    self.error = exc
                    done = True
                else:
                    self.durable = batch[-1][0]
                try:
                    wake.send(b"", zmq.NOBLOCK)
                except zmq.Again:
                    pass  # the loop has a wake-up pending already; it reads durable then
        finally:
            wake.close(linger=0)

"""Where a frame's layout comparison with the map runs while LoST-X searches and verifies the same frame: on a
thread, or in a process of its own that holds a copy of the map's layout grids. Where the frame's grid is not yet
gathered (:class:`lostx.core.layout.grid.Gathering`), it is gathered there too: the process also keeps the frames
its stream keeps, each sent to it once.

Both compute the same numbers with the same code (:meth:`LayoutComparison.compute`). A thread shares the
interpreter with the verification beside it, and each slows the other (on the nuScenes frames against a
1,000-frame map: verification 1.8 ms alone, 4.2 ms beside the comparison on a thread, 2.9 ms beside it in a
process), so maps large enough for the comparison to take milliseconds compare in a process; small maps, where it
takes a fraction of a millisecond, on a thread.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import warnings
import weakref
from concurrent.futures import Future, ThreadPoolExecutor
from multiprocessing.connection import Connection

import numpy as np

from ..layout.grid import Gathering, LayoutGrid, accumulate
from ..layout.projection import FramePoints
from .combined import LayoutComparison

PROCESS_MIN_FRAMES = 200
"""Maps from this many frames compare in a process of their own: there a comparison takes about a millisecond or
more, against the 0.1 ms of handing a grid over and the scores back."""
Answer = tuple[np.ndarray | None, float, tuple[np.ndarray, np.ndarray] | None]
"""The process's reply to a request: the scores (None where it failed), its seconds, and the grid it gathered
(values, mask; None where it was sent one)."""
KEPT_REPLIES = 16
"""Replies kept for comparisons not yet asked for (a frame described ahead); older ones are dropped, and a
comparison whose reply was dropped is computed where it is asked for."""


class ComparisonWarning(UserWarning):
    """The layout's comparison process ended, or could not start; comparisons go on in the matcher's own process."""


class ThreadComparer:
    """Comparisons on one thread beside the caller's (one for the comparer's life: a thread started per frame
    costs 0.5 ms of the frame)."""

    alive = True

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="lostx-layout")

    def submit(self, comparison: LayoutComparison) -> Future[np.ndarray]:
        return self._pool.submit(comparison.compute)


class ComparisonProcess:
    """Comparisons in a process of its own, started with a copy of the map's layout grids and the comparison's
    settings; a frame's grid (or the frames that gather it, those not sent before) goes over a socket, its scores
    (and the grid it gathered) come back.

    The process is a fresh interpreter running this module (not a fork of the caller, whose threads and sockets
    it must not share, nor multiprocessing's ``spawn``, which would run the caller's own script again in it where
    that has no ``if __name__ == "__main__"`` guard). It ignores Ctrl-C: it ends when its owner closes the socket
    (or is garbage-collected, or exits).

    Should the process end (killed, out of memory), the comparisons go on in the caller's process: said once with a
    :class:`ComparisonWarning`, and :attr:`alive` turns False so that the owner can use a thread from then on."""

    def __init__(self, comparison: LayoutComparison) -> None:
        """Started with the map grids and settings of ``comparison`` (those of every comparison it is given).
        Raises OSError where no process can be started."""
        if not sys.executable:
            raise OSError("this interpreter does not know its own executable")
        ours, theirs = socket.socketpair()
        try:
            self._process = subprocess.Popen([sys.executable, "-m", __name__, str(theirs.fileno())],
                                             pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                                             env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, sys.path))})
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._sent = 0
        self._last = -1
        """The latest request replied to (replies come in the order of the requests)."""
        self._replies: dict[int, Answer] = {}
        self._held: set[int] = set()
        """The numbers of the stream's frames the process holds (sent once each, let go as the stream does)."""
        self.alive = True
        self._finalizer = weakref.finalize(self, _stop, self._conn, self._process, os.getpid())
        self._send((comparison.maps, comparison.weights, comparison.shifts, comparison.min_cells, comparison.turns,
                    comparison.opposite))

    def submit(self, comparison: LayoutComparison) -> _Reply:
        # Replies not yet asked for are read first: a process blocked writing them would not read this request.
        try:
            while self.alive and self._conn.poll():
                self._receive()
        except (OSError, EOFError) as exc:
            self._ended(exc)
        request = self._sent
        self._sent += 1
        source = comparison.source
        if isinstance(source, Gathering) and not source.gathered:
            # The process gathers the grid: it is sent the chosen frames it does not hold yet, and which to keep.
            new = {n: f for n, f in zip(source.keys, source.frames) if n not in self._held}
            self._held = {n for n in source.window if n in self._held} | set(new)
            self._send((request, "gather", (new, source.window, source.keys, source.poses, source.current,
                                            source.config)))
        else:
            grid = comparison.views[0]
            self._send((request, "grid", (grid.values, grid.mask)))
        return _Reply(self, request, comparison)

    def close(self) -> None:
        """End the process (also done when the comparer is garbage-collected, or at exit)."""
        self.alive = False
        self._finalizer()

    def _send(self, message: object) -> None:
        if self.alive:
            try:
                self._conn.send(message)
            except (OSError, ValueError) as exc:
                self._ended(exc)

    def _reply(self, request: int) -> Answer | None:
        """The process's reply to ``request``; None where there is none to wait for (the process ended, or the reply
        was dropped unasked for)."""
        try:
            while self.alive and request > self._last:
                self._receive()
        except (OSError, EOFError) as exc:
            self._ended(exc)
        return self._replies.pop(request, None)

    def _receive(self) -> None:
        """One reply, kept until asked for (the oldest of those never asked for dropped)."""
        got, scores, seconds, grid = self._conn.recv()
        self._last = got
        self._replies[got] = (scores, seconds, grid)
        for old in [r for r in self._replies if r < got - KEPT_REPLIES]:
            del self._replies[old]

    def _ended(self, exc: BaseException) -> None:
        self.alive = False
        try:
            code = self._process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            code = None
        warnings.warn(f"the layout's comparison process ended (exit code {code}, {exc!r}); comparing in this "
                      f"process from now on", ComparisonWarning, stacklevel=4)
        self._finalizer()


class _Reply:
    """A comparison handed to a :class:`ComparisonProcess`: its result is the process's reply, or, where the
    process could not give one, the comparison computed here."""

    def __init__(self, process: ComparisonProcess, request: int, comparison: LayoutComparison) -> None:
        self.process, self.request, self.comparison = process, request, comparison

    def result(self) -> np.ndarray:
        reply = self.process._reply(self.request)
        if reply is None or reply[0] is None:
            return self.comparison.compute()
        scores, seconds, grid = reply
        if grid is not None and isinstance(self.comparison.source, Gathering):
            self.comparison.source.received(LayoutGrid(*grid))
        self.comparison.seconds += seconds
        return scores


def _serve(conn: Connection) -> None:
    """The comparison process: the map's grids and the settings first, then one frame at a time, its grid or what
    gathers it, each answered with (request, scores, seconds, the grid it gathered) until the socket closes."""
    try:
        maps, weights, shifts, min_cells, turns, opposite = conn.recv()
        frames: dict[int, FramePoints] = {}
        while True:
            request, kind, body = conn.recv()
            start = time.perf_counter()
            gathered = None
            try:
                if kind == "gather":
                    new, window, keys, poses, current, config = body
                    frames = {n: frames[n] for n in window if n in frames} | new
                    grid = accumulate([frames[n] for n in keys], poses, current, config)
                    gathered = (grid.values, grid.mask)
                else:
                    grid = LayoutGrid(*body)
                scores: np.ndarray | None = LayoutComparison(grid, maps, weights, shifts, min_cells, turns,
                                                                    opposite).compute()
            except Exception:  # noqa: BLE001 (the caller computes it again, and sees the error itself)
                scores, gathered = None, None
            conn.send((request, scores, time.perf_counter() - start, gathered))
    except (EOFError, OSError):
        return


def _stop(conn: Connection, process: subprocess.Popen, owner: int) -> None:
    """Close the socket (the process then returns) and reap it (in the process that started it: a forked child
    holds a copy of the socket, not the process)."""
    conn.close()
    if os.getpid() == owner:
        try:
            process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=1.0)


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _serve(Connection(int(sys.argv[1])))

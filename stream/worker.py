"""The service's worker thread: decodes a frame's image, runs the Localizer, calls the sinks.

The service's I/O loop keeps reading sockets while the worker computes, so in
live mode the newest frame is always known the moment the worker is free, and
producers and listeners are answered even during a long network forward pass.
The worker steps the localizer of the job's stream, one job at a time (the
localizers share one backbone); the I/O loop owns every socket except the
worker's wake-up socket.
"""

from __future__ import annotations

import queue
import threading
import traceback
from dataclasses import dataclass
from typing import Callable, Sequence

import zmq

from lostx.core.decide.estimate import Estimate
from lostx.core.errors import LostxError
from lostx.core.frame import Frame

from .errors import ProtocolError
from .messages import FrameMessage
from .sinks import Sink
from .states import pack
from .streams import StreamState


@dataclass
class Job:
    identity: bytes
    """The producer's ZeroMQ routing id (where its ack or error goes)."""
    message: FrameMessage
    received: float
    """time.monotonic() when the message was read."""
    stream: StreamState
    restart: bool = False
    """Start a new traverse with this frame (its stream's clock was restarted)."""


@dataclass
class Answer:
    job: Job
    frame: Frame | None = None
    """The decoded frame (None where its image did not decode)."""
    estimate: Estimate | None = None
    code: str = ""
    text: str = ""
    """Error code and text where there is no estimate."""
    state: bytes | None = None
    """The stream's localizer state after this frame, packed (where the worker saves states)."""
    state_error: str = ""
    """Why the state could not be saved (then ``state`` is None)."""


class Worker(threading.Thread):
    """Answers one job at a time; posts each answer, then an idle notice, and wakes the I/O loop."""

    def __init__(self, sinks: Sequence[Sink], context: zmq.Context, wake_endpoint: str,
                 log: Callable[[str], None], save_states: bool = False) -> None:
        super().__init__(name="lostx-worker", daemon=True)
        self.sinks = list(sinks)
        self.log = log
        self.save_states = save_states
        """Pack each stream's localizer state after every frame (a service with a journal)."""
        self.jobs: queue.Queue[Job | None] = queue.Queue(maxsize=1)
        self.answers: queue.Queue[Answer | None] = queue.Queue()
        """Answers in order; ``None`` means the worker is idle again (sinks done)."""
        self.sink_failures = 0
        self._context = context
        self._wake_endpoint = wake_endpoint
        self._wake: zmq.Socket | None = None
        self._failed_sinks: set[int] = set()

    def run(self) -> None:
        # The wake-up socket is made here: a ZeroMQ socket belongs to the thread that uses it.
        self._wake = self._context.socket(zmq.PAIR)
        self._wake.connect(self._wake_endpoint)
        try:
            while True:
                job = self.jobs.get()
                if job is None:
                    return
                answer = self._answer(job)
                if self.save_states:
                    self._save_state(answer)
                self._post(answer)
                if answer.estimate is not None and answer.frame is not None:
                    self._run_sinks(answer.frame, answer.estimate)
                self._post(None)
        finally:
            self._wake.close(linger=0)

    def _post(self, item: Answer | None) -> None:
        self.answers.put(item)
        assert self._wake is not None
        try:
            self._wake.send(b"", zmq.NOBLOCK)
        except zmq.Again:
            pass  # the I/O loop has wake-ups pending already; it drains the whole queue

    def _answer(self, job: Job) -> Answer:
        message = job.message
        try:
            frame = message.to_frame()
        except ProtocolError as exc:
            return Answer(job, code=exc.code, text=exc.text)
        localizer = job.stream.localizer
        try:
            if job.restart:
                localizer.reset()
            return Answer(job, frame, estimate=localizer.step(frame))
        except Exception as exc:  # the localizer must not take the service down with it
            if not isinstance(exc, LostxError):  # a bug rather than bad input: show where
                self.log(f"frame {message.id}: unexpected {type(exc).__name__}\n{traceback.format_exc()}")
            # The error carries the frame id in its own field, so the text goes without it.
            text = (str(exc) or type(exc).__name__).removeprefix(f"frame {message.id}: ")
            return Answer(job, frame, code="localizer_failed", text=text)

    @staticmethod
    def _save_state(answer: Answer) -> None:
        # Packed here, off the I/O loop: over a large map a state is megabytes.
        try:
            answer.state = pack(answer.job.stream.localizer.state())
        except LostxError as exc:
            answer.state_error = str(exc)

    def _run_sinks(self, frame: Frame, estimate: Estimate) -> None:
        for sink in self.sinks:
            try:
                sink(frame, estimate)
            except Exception:
                self.sink_failures += 1
                if id(sink) not in self._failed_sinks:  # the first failure in full, then only counted
                    self._failed_sinks.add(id(sink))
                    self.log(f"sink {sink!r} failed on frame {frame.id}:\n{traceback.format_exc()}")

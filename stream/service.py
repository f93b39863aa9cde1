"""The localizer service: frames in over ZeroMQ, one localizer state per stream, answers out.

Two threads. The I/O loop (the thread that calls :meth:`LocalizerService.run`)
owns the sockets, the stream table and the journal: it reads every message as
soon as it arrives, answers bad ones with an error at once, counts listeners,
numbers, journals and publishes answers, serves the journal to listeners that
are catching up, publishes stats, and hands one frame at a time to the
:class:`~lostx.stream.worker.Worker`, which steps the localizer of that
frame's stream and calls the sinks.

``live`` mode answers each stream's newest frame and drops older ones waiting;
``lossless`` mode answers every frame in order (:mod:`lostx.stream.schedule`);
there producers are held back by credit (docs/protocol.md), the queue is
bounded, and answers wait for a slow listener (XPUB_NODROP) instead of being
dropped, which pauses the worker and, through the credit, the producers.

Every answer (a result, or the error that answers a frame) gets the next
sequence number. With a journal, an answer is written there and made durable
(by the :class:`~lostx.stream.journal_writer.JournalWriter` thread, in
batches) before its frame is acknowledged and before it is published, so a
listener that missed answers (it was stopped, killed, or restarted, or the
service was) fetches them from the history socket; the numbers go on across
restarts of the service. Each stream's localizer state is saved with the
answers (:mod:`lostx.stream.states`), so a restarted service carries every
stream on as if it had not stopped. Listeners, the history and the stats see
only durable answers, so no answer anybody could have heard of is ever taken
back or numbered again.

A journal that cannot be written (a full disk) is said at once: the answers
not yet durable are withdrawn (their frames refused with ``journal_unwritable``,
their numbers given again, each stream they advanced put back to its state at
the last durable answer, so that the frames, sent again, are answered exactly
as they would have been), new frames are refused alike until the disk takes a
write again, ``stats`` say why the journal is blocked, and the service stays up.

:meth:`LocalizerService.stop` (from a signal handler or another thread) lets
the worker finish the frame in hand, publishes its answer and the final stats,
and returns.
"""

from __future__ import annotations

import dataclasses
import queue
import secrets
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import msgpack
import zmq

from lostx.core.config import StreamConfig
from lostx.core.errors import LostxError
from lostx.core.localizer import Localizer

from . import wire
from .errors import ProtocolError, StreamError
from .history import HISTORY_LIMITS, serve_history
from .journal import Journal, JournalError
from .journal_writer import RETRY_S, JournalWriter
from .messages import Ack, ErrorMessage, Hello, JournalInfo, Limits, Ready, Stats, Tag
from .schedule import FrameSchedule, frame_key
from .sinks import Sink, close_sink
from .sockets import (
    ServerKeys, apply_server_keys, bind, check_bind_endpoint, history_endpoint, keep_alive, start_authenticator,
)
from .states import SavedState, StateStore, unpack
from .stats import ServiceCounters
from .streams import StreamState, StreamTable, check_time
from .worker import Answer, Job, Worker

READ_BATCH = 10_000
"""Most messages read from the frames socket in one go (keeps the loop responsive)."""
POLL_MS = 100
"""Longest sleep in poll: how soon a stop request or a stats deadline is noticed."""
RETRY_MS = 5
"""How often answers held back by a slow listener are offered to the results socket again."""
PRODUCER_ACTIVE_S = 10.0
"""A producer counts as connected in stats while it sent something this recently."""
JOURNAL_TAIL = 4096
"""Answers read back from the journal at start, to recognise frames the previous service answered."""
MAX_STREAMS = 256
"""Upper limit of max_streams: the per-stream stats must fit one message map."""


@dataclass(frozen=True)
class _Unconfirmed:
    """An answer handed to the journal and not yet durable: what it takes to withdraw it."""

    seq: int
    identity: bytes
    frame_id: int
    stream: str
    stream_seq: int
    key: tuple[str, int] | None
    result: bool
    """A result (else an error that answers the frame, of ``code``)."""
    code: str
    state: SavedState | None
    """The stream's state after it, where saved."""


@dataclass
class _Outgoing:
    """An answer waiting for the results socket; the producer's reply goes once it is out."""

    topic: bytes
    payload: bytes
    reply_to: bytes
    reply: bytes | None
    received: float
    seq: int
    key: tuple[str, int] | None = None
    """(stream, frame id) of an answer whose frame is acknowledged with this reply."""


def check_config(config: StreamConfig) -> None:
    for name in ("window", "queue", "max_message_bytes", "max_pixels", "frame_hwm", "result_hwm", "pending_results",
                 "journal_segment_bytes", "max_streams", "max_streams_per_peer"):
        if getattr(config, name) < 1:
            raise StreamError(f"stream setting {name} must be at least 1, got {getattr(config, name)}")
    if config.wait_listeners < 0:
        raise StreamError(f"stream setting wait_listeners must be 0 or more, got {config.wait_listeners}")
    for name in ("stats_interval", "linger", "stream_expiry", "max_time_jump"):
        if getattr(config, name) <= 0:
            raise StreamError(f"stream setting {name} must be positive, got {getattr(config, name)}")
    if config.queue < config.window:
        raise StreamError(f"stream setting queue ({config.queue}) must be at least window ({config.window})")
    if config.max_streams > MAX_STREAMS:
        raise StreamError(f"stream setting max_streams must be at most {MAX_STREAMS}, got {config.max_streams}")
    if config.journal_max_bytes < config.journal_segment_bytes:
        raise StreamError(f"stream setting journal_max_bytes ({config.journal_max_bytes}) must be at least "
                          f"journal_segment_bytes ({config.journal_segment_bytes})")


class LocalizerService:
    """Serves localizers over ZeroMQ: ``with LocalizerService(new_localizer, config) as s: s.run()``.

    ``new_localizer`` makes the localizer of each new stream (see
    :func:`lostx.stream.streams.localizer_factory`). ``sinks`` are called with ``(frame, estimate)``
    after each answer is published. ``keys`` turns CurveZMQ on; ``insecure`` allows a non-loopback
    bind without it.
    """

    def __init__(
        self,
        new_localizer: Callable[[], Localizer],
        config: StreamConfig | None = None,
        *,
        sinks: Sequence[Sink] = (),
        keys: ServerKeys | None = None,
        insecure: bool = False,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.config = config or StreamConfig()
        check_config(self.config)
        self.sinks = list(sinks)
        self.keys = keys
        self.insecure = insecure
        self.log = log or (lambda text: print(f"lostx serve: {text}", file=sys.stderr, flush=True))
        self.limits = Limits.from_config(self.config)
        self.session = secrets.token_hex(4)
        self.lossless = self.config.mode == "lossless"
        # Lossless never publishes answers into the void: it waits for at least one listener.
        self.min_listeners = max(self.config.wait_listeners, 1 if self.lossless else 0)
        self.counters = ServiceCounters()
        self.streams = StreamTable(new_localizer, self.config.max_streams, self.config.stream_expiry,
                                   self.config.max_streams_per_peer)
        self.journal: Journal | None = None
        self._states: StateStore | None = None
        self._saved: dict[str, SavedState] = {}  # streams of the previous service not seen again yet
        self._unsaved: set[str] = set()  # streams whose state cannot be saved (said once each)
        self._journal_failing = False
        self._epoch = 0  # the journal's failures the loop has withdrawn answers for
        self._withdrawing = False  # a failure to withdraw answers for, once the worker is idle
        self._unconfirmed: deque[_Unconfirmed] = deque()  # answers handed to the journal, not yet durable
        self._durable_states: dict[str, SavedState] = {}  # each stream's state at its last durable answer
        self._durable_answers: dict[str, int] = {}  # each stream's answers up to its last durable one
        self._withdrawn = 0
        self._refused_from: dict[str, int] = {}  # streams with frames refused while the journal failed: the first
        self.endpoints: tuple[str, str] | None = None
        """The frames and results endpoints as bound."""
        self.history_endpoint: str | None = None
        """The history endpoint as bound (with a journal)."""

        self._stop = threading.Event()
        self._stop_reason = ""
        self._context: zmq.Context | None = None
        self._auth: Any = None
        self._frames: zmq.Socket | None = None
        self._results: zmq.Socket | None = None
        self._history: zmq.Socket | None = None
        self._wake: zmq.Socket | None = None
        self._journal_wake: zmq.Socket | None = None
        self._worker: Worker | None = None
        self._writer: JournalWriter | None = None
        self._busy: Job | None = None  # the job the worker has in hand
        self._schedule = FrameSchedule(self.lossless)
        self._outgoing: deque[_Outgoing] = deque()
        # Journaled answers' replies, sent once the answer is durable: (seq, producer, reply, frame key).
        self._acks: deque[tuple[int, bytes, bytes, tuple[str, int] | None]] = deque()
        self._durable = 0  # with a journal: the newest answer made durable
        self._subscriptions: Counter[bytes] = Counter()
        self._producers: dict[bytes, float] = {}
        self._waiting: dict[bytes, int] = {}  # producers owed a ready, and the schema version each spoke
        self._next_seq = 1
        self._published_seq = 0
        self._last_answered: int | None = None
        self._next_stats = 0.0

    # -- lifecycle -----------------------------------------------------------------------------

    def __enter__(self) -> "LocalizerService":
        if self.endpoints is None:
            self.bind()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def bind(self) -> tuple[str, str]:
        """Open the journal and bind the sockets; returns the frames and results endpoints actually
        bound (``:0`` picks a free port)."""
        cfg = self.config
        history = (cfg.history or history_endpoint(cfg.results)) if cfg.journal is not None else None
        for endpoint in (cfg.frames, cfg.results, history):
            if endpoint is not None:
                check_bind_endpoint(endpoint, secure=self.keys is not None, insecure_ok=self.insecure)
        try:
            if cfg.journal is not None:
                self._open_journal()
            self._context = zmq.Context()
            if self.keys is not None:
                self._auth = start_authenticator(self._context, self.keys)
            frames = self._context.socket(zmq.ROUTER)
            frames.setsockopt(zmq.RCVHWM, cfg.frame_hwm)
            frames.setsockopt(zmq.SNDHWM, 1000)
            # Transport-level cap: libzmq reads the length prefix and drops a peer announcing more,
            # before allocating. Up to twice the protocol limit still arrives and gets a polite error.
            frames.setsockopt(zmq.MAXMSGSIZE, 2 * cfg.max_message_bytes)
            results = self._context.socket(zmq.XPUB)
            results.setsockopt(zmq.SNDHWM, cfg.result_hwm)
            results.setsockopt(zmq.XPUB_VERBOSER, 1)  # every (un)subscription, to count listeners
            results.setsockopt(zmq.XPUB_NODROP, 1 if self.lossless else 0)
            results.setsockopt(zmq.MAXMSGSIZE, 4096)  # listeners only send short subscriptions
            sockets = [frames, results]
            if history is not None:
                self._history = self._context.socket(zmq.ROUTER)
                self._history.setsockopt(zmq.MAXMSGSIZE, HISTORY_LIMITS.max_message_bytes)
                self._history.setsockopt(zmq.SNDHWM, 100)
                sockets.append(self._history)
            for socket in sockets:
                socket.setsockopt(zmq.LINGER, 0)
                keep_alive(socket)  # a listener on a vanished host cannot hold the service forever
                if self.keys is not None:
                    apply_server_keys(socket, self.keys)
            self._frames, self._results = frames, results
            self.endpoints = (bind(frames, cfg.frames), bind(results, cfg.results))
            if self._history is not None and history is not None:
                self.history_endpoint = bind(self._history, history)
            wake_endpoint = f"inproc://lostx-wake-{self.session}"
            self._wake = self._context.socket(zmq.PAIR)
            self._wake.bind(wake_endpoint)
            self._worker = Worker(self.sinks, self._context, wake_endpoint, self.log,
                                  save_states=self.journal is not None)
            if self.journal is not None and self._states is not None:
                journal_endpoint = f"inproc://lostx-journal-{self.session}"
                self._journal_wake = self._context.socket(zmq.PAIR)
                self._journal_wake.bind(journal_endpoint)
                self._writer = JournalWriter(self.journal, self._states, self._context, journal_endpoint)
        except BaseException:
            self.close()
            raise
        return self.endpoints

    def _open_journal(self) -> None:
        cfg = self.config
        assert cfg.journal is not None
        self.journal = Journal(cfg.journal, segment_bytes=cfg.journal_segment_bytes,
                               max_bytes=cfg.journal_max_bytes, fsync=cfg.journal_fsync)
        self._states = StateStore(cfg.journal, cfg.journal_fsync)
        durable = self._states.durable()
        if durable is not None:
            # Answers of a batch the previous service never completed were neither acknowledged nor published:
            # they go, and their frames, sent again, are answered from the states that go with the journal.
            self.journal.cut_after(durable)
        else:
            self._states.complete(self.journal.last, [])  # the mark of what is durable, before any answer
        self._saved = self._states.recover(self.journal.last)
        self._next_seq = self.journal.last + 1
        self._durable = self.journal.committed
        self._published_seq = self.journal.last
        # Frames the previous service answered but whose acks it never sent come again: know them.
        answers: dict[str, int] = {}
        for payload in self.journal.tail(JOURNAL_TAIL):
            stream, frame_id, stream_seq = _journaled(payload)
            if stream and isinstance(frame_id, int):
                self._schedule.answered.add((stream, frame_id))
            if stream in self._saved and isinstance(stream_seq, int):
                answers[stream] = stream_seq
        for stream, stream_seq in answers.items():  # answers after its state (refused frames) count too
            saved = self._saved[stream]
            self._saved[stream] = dataclasses.replace(saved, answers=max(saved.answers, stream_seq))

    def stop(self, reason: str = "stop requested") -> None:
        """Finish the frame in hand, flush, and return from :meth:`run`. Safe in signal handlers."""
        self._stop_reason = reason
        self._stop.set()

    def close(self, linger_ms: int = 0) -> None:
        """Close the sockets and the journal; ZeroMQ keeps sending what it already holds for ``linger_ms``."""
        worker, self._worker = self._worker, None
        if worker is not None and worker.is_alive():
            worker.jobs.put(None)
            worker.join(10)
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()
        for socket in (self._results, self._frames, self._history, self._wake, self._journal_wake):
            if socket is not None:
                socket.close(linger=linger_ms)
        self._frames = self._results = self._history = self._wake = self._journal_wake = None
        if self._auth is not None:
            self._auth.stop()
            self._auth = None
        if self._context is not None:
            self._context.term()
            self._context = None
        if self.journal is not None:
            self.journal.close()

    # -- the I/O loop --------------------------------------------------------------------------

    def run(self) -> Stats:
        """Serve until :meth:`stop`; returns the final stats (also published)."""
        if self.endpoints is None:
            self.bind()
        assert self._worker is not None and self.endpoints is not None
        cfg = self.config
        journal = ""
        if self.journal is not None:
            held = f"answers {self.journal.first}-{self.journal.last}" if self.journal.last else "empty"
            journal = f"; journal {cfg.journal} ({held}), history {self.history_endpoint} (ROUTER)"
        self.log(f"{cfg.mode} mode, session {self.session}; frames {self.endpoints[0]} (ROUTER), "
                 f"results {self.endpoints[1]} (XPUB){journal}" + ("; CurveZMQ on" if self.keys else ""))
        self._worker.start()
        if self._writer is not None:
            self._writer.start()
        try:
            while not self._stop.is_set():
                self._turn()
            # Stopping: the frame in hand is finished and its answer published.
            deadline = time.monotonic() + max(60.0, cfg.linger)
            while self._busy is not None and time.monotonic() < deadline:
                self._turn(dispatch=False)
        finally:
            final = self._shutdown()
        return final

    def _turn(self, dispatch: bool = True) -> None:
        """One turn of the loop: wait for something, then read, answer, dispatch, commit, publish."""
        assert self._frames is not None and self._results is not None and self._wake is not None
        poller = zmq.Poller()
        read_frames = not self.lossless or len(self._schedule) < self.config.queue
        if read_frames:
            poller.register(self._frames, zmq.POLLIN)
        poller.register(self._results, zmq.POLLIN)
        poller.register(self._wake, zmq.POLLIN)
        if self._history is not None:
            poller.register(self._history, zmq.POLLIN)
        if self._journal_wake is not None:
            poller.register(self._journal_wake, zmq.POLLIN)
        events = dict(poller.poll(self._sleep_ms()))
        if self._journal_wake is not None and events.get(self._journal_wake):
            self._collect_durable()
        if events.get(self._wake):
            self._collect_answers()
        if read_frames and events.get(self._frames, 0) & zmq.POLLIN:
            self._read_frames()
        if events.get(self._results, 0) & zmq.POLLIN:
            self._read_subscriptions()
        if self._waiting and self._listeners() >= self.min_listeners:
            for identity, version in self._waiting.items():
                self._reply(identity, wire.encode_ready(self._ready(), version))
            self._waiting.clear()
        if self._withdrawing and self._busy is None:
            self._withdraw()
        if dispatch:
            self._dispatch()
        self._release()
        if self._history is not None and events.get(self._history, 0) & zmq.POLLIN:
            self._serve_history()
        self._maybe_stats()

    def _sleep_ms(self) -> int:
        until_stats = max(0.0, self._next_stats - time.monotonic())
        if self._outgoing:
            # Answers wait for a slow listener. An XPUB socket always polls writable, whether or not
            # a listener's queue is full, so retry on a short timer instead of spinning on POLLOUT.
            return int(min(RETRY_MS, 1e3 * until_stats))
        return int(min(POLL_MS, 1e3 * until_stats))

    def _dispatch(self) -> None:
        """Give the worker the next frame if it is free and nothing holds the service back."""
        assert self._worker is not None
        if self._busy is not None or self._withdrawing or self._listeners() < self.min_listeners:
            return
        if len(self._outgoing) >= self.config.pending_results:
            return  # a listener (lossless) or the disk (with a journal) is slow: wait for it, drop nothing
        while True:
            job = self._next_job()
            if job is None:
                return
            if self._admit_time(job):
                break
        self._busy = job
        self._worker.jobs.put(job)

    def _next_job(self) -> Job | None:
        return self._schedule.next(self._resent)

    def _resent(self, job: Job, ack_again: bool) -> None:
        """A producer resent, after a reconnection, a frame already answered: answer it once. If its ack may
        have been lost, acknowledge again; if the ack is still to come, it goes with the answer."""
        self.counters.duplicates += 1
        job.stream.counts.duplicates += 1
        job.stream.in_service -= 1
        if ack_again:
            self._reply(job.identity, self._ack(job))

    def _admit_time(self, job: Job) -> bool:
        """Check the frame's timestamp against its stream's; a refused frame is answered with the error."""
        state, timestamp = job.stream, job.message.timestamp
        try:
            verdict = check_time(state.last_timestamp, timestamp, self.config.max_time_jump)
        except ProtocolError as exc:
            self._answer(Answer(job, code=exc.code, text=exc.text))
            return False
        if verdict == "restart":
            job.restart = True
            state.counts.restarts += 1
            if state.counts.restarts == 1:  # then only counted: a peer cannot flood the log
                self.log(f"stream {state.name!r}: frame {job.message.id} is stamped {timestamp:.17g}, more than "
                         f"max_time_jump before the previous frame; starting a new traverse")
        if timestamp is not None:
            state.last_timestamp = timestamp
        return True

    def _collect_answers(self) -> None:
        assert self._wake is not None and self._worker is not None
        while True:
            try:
                self._wake.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
        while True:
            try:
                answer = self._worker.answers.get_nowait()
            except queue.Empty:
                return
            if answer is None:
                self._busy = None  # idle again (its sinks are done)
            else:
                self._answer(answer)

    def _answer(self, answer: Answer) -> None:
        """Number the answer, journal it, and queue it for the listeners and the producer."""
        job, state = answer.job, answer.job.stream
        state.in_service -= 1
        self._last_answered = job.message.id
        seq = self._next_seq
        self._next_seq += 1
        state.answers += 1
        tag = Tag(state.name, seq, state.answers, self.journal.id if self.journal is not None else None)
        if answer.estimate is not None:
            self.counters.answered += 1
            state.counts.answered += 1
            self.counters.step_ms.add(answer.estimate.latency_ms.get("total", 0.0))
            topic, payload = b"result", wire.encode_result(answer.estimate.summary(), self.session, tag)
            reply = self._ack(job) if self.lossless else None
        else:
            # A frame that was accepted but cannot be answered: its answer is this error, in order.
            # The sender hears of it in both modes; in lossless mode it also returns the credit.
            self.counters.errors[answer.code] += 1
            state.counts.errors += 1
            topic = b"error"
            payload = reply = wire.encode_error(ErrorMessage(answer.code, answer.text, job.message.id, self.session,
                                                             tag))
        key = frame_key(job.message) if self.lossless else None
        if self._writer is not None:
            # Journaled: acknowledged as soon as it is durable, whether or not a listener has it.
            saved = self._saved_state(answer, seq)
            self._writer.write(seq, payload, saved, self._epoch)
            self._unconfirmed.append(_Unconfirmed(seq, job.identity, job.message.id, state.name, state.answers, key,
                                                  answer.estimate is not None, answer.code, saved))
            if reply is not None:
                self._acks.append((seq, job.identity, reply, key))
            reply, key = None, None
        self._outgoing.append(_Outgoing(topic, payload, job.identity, reply, job.received, seq, key))

    def _saved_state(self, answer: Answer, seq: int) -> SavedState | None:
        state = answer.job.stream
        if answer.state is not None:
            return SavedState(state.name, seq, state.answers, state.last_timestamp, answer.state)
        if answer.state_error and state.name not in self._unsaved:
            assert self._writer is not None
            self._unsaved.add(state.name)
            self._writer.forget(state.name)  # an older state must not be taken up after a restart
            self.log(f"stream {state.name!r}: its state is not saved ({answer.state_error}); after a restart of "
                     f"the service it starts afresh")
        return None

    def _collect_durable(self) -> None:
        assert self._journal_wake is not None and self._writer is not None
        while True:
            try:
                self._journal_wake.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
        self._take_durable()

    def _take_durable(self) -> None:
        assert self._writer is not None
        if self._writer.error is not None:
            error = self._writer.error
            text = error.strerror if isinstance(error, OSError) else str(error)
            raise JournalError(f"cannot write the journal {self.config.journal}: {text}")
        epoch, failure = self._writer.epoch, self._writer.failure  # read before durable: it only grows
        self._durable = self._writer.durable
        while self._unconfirmed and self._unconfirmed[0].seq <= self._durable:
            done = self._unconfirmed.popleft()
            if done.state is not None:
                self._durable_states[done.stream] = done.state
            self._durable_answers[done.stream] = done.stream_seq
        if epoch > self._epoch:
            self._withdrawing = True
        if failure is not None and not self._journal_failing:
            self.log(f"cannot write the journal {self.config.journal}: {failure}; the answers not yet on disk are "
                     f"withdrawn and their frames, and new ones, refused (journal_unwritable) until a write "
                     f"succeeds, tried every {RETRY_S:g} s")
        elif failure is None and self._journal_failing:
            self.log(f"the journal {self.config.journal} is written again (answers up to {self._durable}); "
                     f"taking frames again")
        self._journal_failing = failure is not None

    def _withdraw(self) -> None:
        """Take back every answer the journal could not make durable: its frame is refused with
        ``journal_unwritable`` (the producer sends it again), its number given to the next answer, and each stream it
        advanced goes back to its state at its last durable answer. Frames queued behind them are refused alike.
        Runs while the worker is idle, so that no localizer is stepped meanwhile."""
        assert self._writer is not None and self._busy is None
        self._take_durable()
        reason = self._writer.failure or "it failed"
        text = f"the journal cannot be written ({reason}): this frame's answer was not kept; send it again later"
        rewind: set[str] = set()
        for item in self._unconfirmed:
            if item.result:
                self.counters.answered -= 1
            else:
                self.counters.errors[item.code] -= 1
            state = self.streams.peek(item.stream)
            if state is not None:
                if item.result:
                    state.counts.answered -= 1
                else:
                    state.counts.errors -= 1
            self._withdraw_frame(item.identity, item.stream, item.frame_id, item.key, text)
            rewind.add(item.stream)
        self._withdrawn += len(self._unconfirmed)
        withdrawn = len(self._unconfirmed)
        self._unconfirmed.clear()
        self._outgoing = deque(o for o in self._outgoing if o.seq <= self._durable)
        self._acks = deque(a for a in self._acks if a[0] <= self._durable)
        queued = self._schedule.drain()
        for job in queued:
            job.stream.in_service -= 1
            self._withdraw_frame(job.identity, job.stream.name, job.message.id, None,
                                 "the journal cannot be written: this frame was not taken; send it again later")
        for name in rewind:
            state = self.streams.peek(name)
            if state is not None:
                self._rewind(state)
        self._next_seq = self._durable + 1
        self._epoch = self._writer.epoch
        self._withdrawing = False
        self.log(f"{withdrawn} answer(s) after answer {self._durable} withdrawn and {len(queued)} queued frame(s) "
                 f"refused (journal_unwritable): their producers send them again")

    def _withdraw_frame(self, identity: bytes, stream: str, frame_id: int, key: tuple[str, int] | None,
                        text: str) -> None:
        self._refuse(identity, "journal_unwritable", text, frame_id)
        if key is not None:
            self._schedule.answered.discard(key)
            self._schedule.unacked.discard(key)
        first = self._refused_from.get(stream)
        if self.lossless:
            self._refused_from[stream] = frame_id if first is None else min(first, frame_id)

    def _rewind(self, state: StreamState) -> None:
        """Put a stream back to its state at its last durable answer (afresh where it has none)."""
        saved = self._durable_states.get(state.name)
        if saved is not None:
            self._restore(state, saved)
        else:
            state.localizer.reset()
            state.last_timestamp = None
        state.answers = self._durable_answers.get(state.name, 0)

    def _is_durable(self, seq: int) -> bool:
        return self._writer is None or seq <= self._durable

    def _release(self) -> None:
        """Acknowledge the frames whose answers are durable, then publish what may go out."""
        while self._acks and self._is_durable(self._acks[0][0]):
            _, identity, reply, key = self._acks.popleft()
            self._reply(identity, reply)
            if key is not None:
                self._schedule.unacked.discard(key)
        self._flush()

    def _read_frames(self) -> None:
        assert self._frames is not None
        for _ in range(READ_BATCH):
            if self.lossless and len(self._schedule) >= self.config.queue:
                return  # leave the rest in the socket: ZeroMQ and TCP hold the producer back
            try:
                # copy=False: decode straight from ZeroMQ's buffer (frames are megabytes).
                parts = self._frames.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            self._on_request(parts[0].bytes, [part.buffer for part in parts[1:]])

    def _on_request(self, identity: bytes, parts: list[memoryview]) -> None:
        now = time.monotonic()
        self._producers[identity] = now
        try:
            if len(parts) != 1:
                raise ProtocolError("multipart", f"expected one message part, got {len(parts)}")
            message = wire.decode_request(parts[0], self.limits)
        except ProtocolError as exc:
            self._refuse(identity, exc.code, exc.text, exc.frame_id)
            return
        if isinstance(message, Hello):
            if self._listeners() >= self.min_listeners:
                self._reply(identity, wire.encode_ready(self._ready(), message.version))
            else:
                self._waiting[identity] = message.version
            return
        name = message.stream or ""
        if self._refused_from or self._journal_failing:
            if self._hold_back(identity, name, message.id):
                return
        new = name not in self.streams
        if new and len(self.streams) >= self.streams.max_streams:
            for gone in self.streams.expire(now):  # their saved states go with them
                self._forget(gone)
        held = {s.name for s in self.streams.held_by(identity)} if new else set()
        released = self.streams.released
        try:
            state = self.streams.get(name, now, identity)
        except ProtocolError as exc:
            self._refuse(identity, exc.code, exc.text, message.id)
            return
        if self.streams.released > released:
            for gone in held - {s.name for s in self.streams.held_by(identity)}:
                self._forget(gone)
            if released == 0:  # then not again: a peer cannot flood the log
                self.log(f"a producer holding {self.config.max_streams_per_peer} streams (max_streams_per_peer) "
                         f"started stream {state.name!r}: its least recently used stream is forgotten")
        if new and name in self._saved:
            saved = self._saved.pop(name)
            self._restore(state, saved)
            self._durable_states[name], self._durable_answers[name] = saved, state.answers
        self.counters.received += 1
        state.counts.received += 1
        self.counters.missing += state.saw(message.id)
        state.in_service += 1
        if self._schedule.add(Job(identity, message, now, state)) is not None:
            self.counters.dropped += 1
            state.counts.dropped += 1
            state.in_service -= 1

    def _hold_back(self, identity: bytes, name: str, frame_id: int) -> bool:
        """Refuse the frame while the journal cannot be written (an answer that cannot be written could never be
        acknowledged), and after that the stream's frames sent behind a refused one until it comes again: the
        stream's frames are answered in their order."""
        first = self._refused_from.get(name)
        if self._journal_failing:
            failure = self._writer.failure if self._writer is not None else ""
            text = f"the journal cannot be written ({failure}); send it again later"
        elif first is not None and frame_id > first:
            text = f"frame {first} of this stream was refused and comes first; send this one again after it"
        else:
            self._refused_from.pop(name, None)
            return False
        if self.lossless:  # a live producer never sends a frame again: nothing to keep the order of
            self._refused_from[name] = frame_id if first is None else min(first, frame_id)
        if len(self._refused_from) > 4 * MAX_STREAMS:  # a flood of stream ids: the oldest is let go
            del self._refused_from[next(iter(self._refused_from))]
        self._refuse(identity, "journal_unwritable", text, frame_id)
        return True

    def _restore(self, state: StreamState, saved: SavedState) -> None:
        """Give a stream of the previous service its state back: its next answers are those it would have given."""
        try:
            state.localizer.restore(unpack(saved.localizer))
        except (LostxError, ValueError, TypeError, KeyError) as exc:
            state.localizer.reset()
            self.log(f"stream {state.name!r}: its saved state does not fit ({exc}); starting it afresh")
            return
        state.answers, state.last_timestamp = saved.answers, saved.last_timestamp

    def _ready(self) -> Ready:
        window = self.config.window if self.lossless else 0
        return Ready(self.session, self.config.mode, window, self.config.max_message_bytes, self.config.max_pixels,
                     self.journal.id if self.journal is not None else None, self.history_endpoint)

    def _ack(self, job: Job) -> bytes:
        """The frame's acknowledgement, in the schema version its producer spoke."""
        return wire.encode_ack(Ack(self.session, job.message.id, job.message.stream or ""), job.message.version)

    def _read_subscriptions(self) -> None:
        assert self._results is not None
        while True:
            try:
                data = self._results.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if not data or data[0] not in (0, 1):
                continue  # not a subscription message; listeners may only (un)subscribe
            topic = data[1:]
            self._subscriptions[topic] += 1 if data[0] == 1 else -1
            if self._subscriptions[topic] <= 0:
                del self._subscriptions[topic]

    def _listeners(self) -> int:
        """Subscriptions that receive results (a topic that is a prefix of ``result``)."""
        return sum(n for topic, n in self._subscriptions.items() if b"result".startswith(topic))

    def _serve_history(self) -> None:
        assert self._history is not None and self.journal is not None
        serve_history(self._history, self.journal, self.session, self.counters.errors)

    # -- sending -------------------------------------------------------------------------------

    def _refuse(self, identity: bytes, code: str, text: str, frame_id: int | None) -> None:
        """A message that could not be read: tell its sender, and the listeners (best effort)."""
        error = wire.encode_error(ErrorMessage(code, text, frame_id, self.session))
        self.counters.errors[code] += 1
        self._reply(identity, error)
        self._publish_now(b"error", error)

    def _publish_now(self, topic: bytes, payload: bytes) -> bool:
        """Publish outside the queue of answers, or not at all if a listener is full.

        For stats and for errors about unreadable messages: they are not part of the
        sequence of answers, so they neither wait behind a slow listener nor grow memory
        when a peer floods the service with garbage."""
        assert self._results is not None
        try:
            self._results.send_multipart([topic, payload], zmq.NOBLOCK)
            return True
        except zmq.Again:
            return False

    def _reply(self, identity: bytes, payload: bytes) -> None:
        assert self._frames is not None
        try:
            # ROUTER drops (never blocks on) a reply to a producer that is gone or not reading.
            self._frames.send_multipart([identity, payload], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass

    def _flush(self) -> None:
        """Hand queued answers to the results socket until it pushes back (lossless) or all are out."""
        assert self._results is not None
        while self._outgoing and self._is_durable(self._outgoing[0].seq):
            item = self._outgoing[0]
            try:
                self._results.send_multipart([item.topic, item.payload], zmq.NOBLOCK)
            except zmq.Again:
                return  # a listener is full (XPUB_NODROP): keep it; the worker pauses
            self._outgoing.popleft()
            self._published_seq = item.seq
            if item.reply is not None:
                self._reply(item.reply_to, item.reply)
            if item.key is not None:
                self._schedule.unacked.discard(item.key)
            self.counters.service_ms.add(1e3 * (time.monotonic() - item.received))

    # -- stats and shutdown --------------------------------------------------------------------

    def stats(self, final: bool = False) -> Stats:
        now = time.monotonic()
        for identity, seen in list(self._producers.items()):
            if now - seen > PRODUCER_ACTIVE_S:
                del self._producers[identity]
        c = self.counters
        by_code = dict(c.errors)
        sink_failures = self._worker.sink_failures if self._worker is not None else 0
        if sink_failures:
            by_code["sink_failed"] = sink_failures  # counted, but no error message is sent for these
        journal = None
        if self.journal is not None:
            j = self.journal
            blocked = self._writer.failure if self._writer is not None else None
            journal = JournalInfo(j.id, j.first, j.committed, j.nbytes, j.segments, blocked, self._withdrawn)
        return Stats(
            session=self.session, mode=self.config.mode, uptime_s=c.uptime, received=c.received,
            answered=c.answered, dropped=c.dropped, missing=c.missing, duplicates=c.duplicates,
            errors=sum(c.errors.values()), errors_by_code=by_code,
            queued_frames=len(self._schedule), queued_results=len(self._outgoing),
            listeners=self._listeners(), producers=len(self._producers),
            latency_ms={"step": c.step_ms.summary(), "service": c.service_ms.summary()}, final=final,
            seq=self._published_seq, journal=journal, streams=self.streams.stats(now),
        )

    def _forget(self, name: str) -> None:
        self._unsaved.discard(name)
        self._durable_states.pop(name, None)
        self._durable_answers.pop(name, None)
        if self._writer is not None:
            self._writer.forget(name)

    def _maybe_stats(self) -> None:
        now = time.monotonic()
        if now >= self._next_stats:
            self._next_stats = now + self.config.stats_interval
            for name in self.streams.expire(now):
                self._forget(name)
            if self._saved and now - self.counters.started > self.config.stream_expiry:
                for name in list(self._saved):  # not seen since the restart: expired as any idle stream
                    del self._saved[name]
                    self._forget(name)
            self._publish_now(b"stats", wire.encode_stats(self.stats()))

    def _shutdown(self) -> Stats:
        """Flush what is answered (within ``linger``), publish the final stats, close."""
        if self._stop.is_set():
            unanswered = len(self._schedule)
            last = f"last answered frame {self._last_answered}, " if self._last_answered is not None else ""
            self.log(f"{self._stop_reason}: {last}stopping after {self.counters.answered} answers"
                     + (f"; {unanswered} queued frame(s) left unanswered" if unanswered else ""))
        deadline = time.monotonic() + self.config.linger
        final = self.stats(final=True)
        if self._results is not None:
            if self._writer is not None:
                self._writer.close()  # everything answered is written and flushed, where the disk takes it
                try:
                    self._take_durable()
                    if self._withdrawing or self._unconfirmed:
                        self._withdrawing = False
                        if self._busy is None:
                            self._withdraw()
                except JournalError as exc:
                    self.log(str(exc))
            self._release()
            while self._outgoing and time.monotonic() < deadline:
                self._flush()
                if self._outgoing:
                    time.sleep(RETRY_MS / 1e3)
            if self._outgoing:
                kept = sum(self._is_durable(item.seq) for item in self._outgoing) if self.journal is not None else 0
                where = f"; {kept} of them are in the journal" if kept else ""
                self.log(f"{len(self._outgoing)} answer(s) not delivered within {self.config.linger:.1f} s{where}")
            final = self.stats(final=True)
            payload = wire.encode_stats(final)
            while not self._publish_now(b"stats", payload) and time.monotonic() < deadline:
                time.sleep(RETRY_MS / 1e3)
        for sink in self.sinks:
            try:
                close_sink(sink)
            except Exception as exc:
                self.log(f"sink {sink!r} failed to close: {exc}")
        # ZeroMQ finishes sending what it has taken within what is left of the linger time.
        self.close(linger_ms=max(0, int(1e3 * (deadline - time.monotonic()))))
        return final


def _journaled(payload: bytes) -> tuple[Any, Any, Any]:
    """A journaled answer's stream, frame id and stream_seq."""
    message = msgpack.unpackb(payload, raw=False)
    return message.get("stream"), message.get("frame_id"), message.get("stream_seq")

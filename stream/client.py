"""Consuming the service's answers: :func:`results` and :class:`Listener`.

    import lostx.stream
    for result in lostx.stream.results("tcp://127.0.0.1:5556"):
        print(result.frame_id, result.match_index, result.confidence)

A listener connects (the service binds), so it may start before the service and
it picks a restarted service up by itself (``Result.session`` changes). Any
number of listeners may listen at once. Messages that fail to decode are
counted (``Listener.bad_messages``) and skipped: the service is not trusted either.

Answers (results, and the errors that answer frames) carry sequence numbers,
so a listener knows what it missed. Where the service keeps a journal, a
listener fetches what it missed from the service's history socket and hands
every answer over once, in order; it can also resume from a sequence number
(``after``) after a restart of its own. Without a journal what it missed is
counted (``Listener.missed``).
"""

from __future__ import annotations

import time
from collections import deque
from typing import Iterator, Sequence

import zmq

from . import wire
from .errors import ProtocolError, StreamError
from .history import HistoryClient
from .messages import TOPICS, Limits, Published, Result, Stats, Tag
from .sockets import ClientKeys, connect, history_endpoint

LISTENER_LIMITS = Limits(max_message_bytes=1024 * 1024)
"""Result, error and stats messages are small (a few kB); anything over 1 MiB is refused unread."""

Numbering = tuple[str, str]
"""Whose sequence numbers: ("journal", id), continuous across restarts; or ("session", id) without one."""


class Listener:
    """A SUB socket on the results channel, decoding what arrives, answers in sequence."""

    def __init__(
        self,
        endpoint: str,
        *,
        topics: Sequence[str] = ("result", "error", "stats"),
        keys: ClientKeys | None = None,
        hwm: int = 10_000,
        rcvbuf: int | None = None,
        limits: Limits = LISTENER_LIMITS,
        history: str | None = None,
        after: int | None = None,
        journal: str | None = None,
        history_timeout: float = 30.0,
    ) -> None:
        """``hwm``: messages ZeroMQ holds for this listener; ``rcvbuf``: the kernel's receive
        buffer in bytes (None: the system default). Small values make a slow listener felt
        sooner: by the service in lossless mode, as missed results in live mode.

        ``history``: the service's history endpoint (None: the one that goes with ``endpoint``,
        :func:`lostx.stream.sockets.history_endpoint`). ``after``: resume, handing over every
        journaled answer numbered above it first; ``journal``: the id of the journal that
        number belongs to, where known (another journal is then read from its start).
        """
        unknown = [t for t in topics if t.encode() not in TOPICS]
        if unknown:
            raise ValueError(f"unknown topic(s) {', '.join(unknown)}; known: result, error, stats")
        self.endpoint = endpoint
        self.limits = limits
        self.keys = keys
        self.history_timeout = history_timeout
        self.bad_messages = 0
        self.missed = 0
        """Answers this listener never got: dropped for it in live mode, or no longer in the journal."""
        self.recovered = 0
        """Answers fetched from the journal (missed live, or older than this listener)."""
        self.duplicates = 0
        """Answers that arrived twice and were handed over once."""
        self.notices: deque[str] = deque(maxlen=100)
        """Events a user should hear of (the journal changed, answers no longer in it, ...)."""
        self._wanted = set(topics)
        # Errors that answer frames are numbered with the results: a result listener hears them too, to
        # know what it missed. Not the stats: in lossless mode a stopped listener's full queue holds back
        # every message of the topics it subscribed to, and the stats must reach the others.
        self._ordered = "result" in self._wanted
        subscribed = set(topics) | ({"error"} if self._ordered else set())
        self._history_endpoint = history
        self._history: HistoryClient | None = None
        self._numbering: Numbering | None = None
        self._next: int | None = None if after is None else after + 1
        self._resume_journal = journal
        self._ready: deque[Published] = deque()
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.SUB)
        self._socket.setsockopt(zmq.RCVHWM, hwm)
        if rcvbuf is not None:
            self._socket.setsockopt(zmq.RCVBUF, rcvbuf)
        self._socket.setsockopt(zmq.MAXMSGSIZE, limits.max_message_bytes)
        self._socket.setsockopt(zmq.LINGER, 0)
        try:
            for topic in sorted(subscribed):
                self._socket.setsockopt(zmq.SUBSCRIBE, topic.encode())
            connect(self._socket, endpoint, keys)
        except BaseException:
            self.close()
            raise

    @property
    def last_seq(self) -> int | None:
        """The sequence number of the last answer handed over (or skipped as seen)."""
        return None if self._next is None else self._next - 1

    def receive(self, timeout: float | None = None) -> Published | None:
        """The next message (Result, ErrorMessage or Stats); None after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._ready:
                return self._ready.popleft()
            wait = -1 if deadline is None else max(0, int(1e3 * (deadline - time.monotonic())))
            if not self._socket.poll(wait, zmq.POLLIN):
                if deadline is not None and time.monotonic() >= deadline:
                    return None
                continue
            parts = self._socket.recv_multipart(copy=True)
            if len(parts) != 2:
                self.bad_messages += 1
                continue
            try:
                message = wire.decode_published(parts[0], parts[1], self.limits)
            except ProtocolError:
                self.bad_messages += 1
                continue
            self._take(message)

    def __iter__(self) -> Iterator[Published]:
        while True:
            message = self.receive()
            if message is not None:
                yield message

    def close(self) -> None:
        if self._history is not None:
            self._history.close()
            self._history = None
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None  # type: ignore[assignment]
        self._context.term()

    def __enter__(self) -> "Listener":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- answers in sequence -------------------------------------------------------------------

    def _take(self, message: Published) -> None:
        if isinstance(message, Stats):
            if self._ordered:
                self._on_stats(message)
            self._hand_over(message)
            return
        tag = message.tag
        if tag is None or not self._ordered:
            self._hand_over(message)  # a refused message: not an answer, not numbered
            return
        numbering: Numbering = ("journal", tag.journal) if tag.journal else ("session", message.session or "")
        if numbering != self._numbering:
            self._enter(numbering, tag.seq)
        assert self._next is not None
        if tag.seq < self._next:
            self.duplicates += 1
            return
        if tag.seq > self._next:
            self._fill(tag.seq - 1)
        self._hand_over(message)
        self._next = tag.seq + 1

    def _on_stats(self, stats: Stats) -> None:
        """The stats tell the last answer published: anything after ours up to it was missed. (So a
        resuming listener, subscribed before it asks, catches up at the first stats or answer it hears.)"""
        numbering: Numbering = ("journal", stats.journal.id) if stats.journal else ("session", stats.session)
        if numbering != self._numbering:
            if self._numbering is not None:
                return  # a change of numbering is taken from the next answer
            self._enter(numbering, stats.seq + 1)
        assert self._next is not None
        if stats.journal is not None and stats.journal.last < self._next - 1:
            self.notices.append(f"answer {self._next - 1} is beyond the last in the service's journal "
                                f"({stats.journal.last}): taking answers from {stats.journal.last + 1}")
            self._next = stats.journal.last + 1
        if stats.seq >= self._next:
            self._fill(stats.seq)

    def _enter(self, numbering: Numbering, first_seen: int) -> None:
        """Follow a new numbering; ``first_seen`` is the first number this listener has heard of in it."""
        before, self._numbering = self._numbering, numbering
        journaled = numbering[0] == "journal"
        if before is None and self._next is None:
            self._next = first_seen  # the first contact: nothing before it is this listener's
        elif before is None:
            if not journaled:
                self.notices.append("the service keeps no journal: nothing to resume from; taking answers from here")
                self._next = first_seen
            elif self._resume_journal not in (None, numbering[1]):
                self.notices.append(f"the service's journal is {numbering[1]}, not {self._resume_journal}: "
                                    f"reading it from its start")
                self._next = 1
        elif journaled:
            self.notices.append(f"the service has a new journal ({numbering[1]}): reading it from its start")
            self._next = 1
        else:
            self.notices.append("the service restarted without a journal: what it answered meanwhile is unknown")
            self._next = first_seen

    def _fill(self, upto: int) -> None:
        """Answers from the next expected to ``upto`` were not received: fetch them from the journal
        and hand them over, or count them as missed."""
        assert self._next is not None and self._numbering is not None
        if self._numbering[0] != "journal":
            self.missed += upto - self._next + 1
            self._next = upto + 1
            return
        while self._next <= upto:
            try:
                reply = self._history_client().fetch(self._next - 1, upto - self._next + 1)
            except StreamError as exc:
                self._give_up(upto, str(exc))
                return
            if reply.journal != self._numbering[1]:
                self._give_up(upto, f"the history holds journal {reply.journal}, not {self._numbering[1]}")
                return
            if reply.first > self._next:
                gone = min(reply.first, upto + 1) - self._next
                self.notices.append(f"answers {self._next}-{self._next + gone - 1} are no longer in the journal")
                self.missed += gone
                self._next += gone
            before = self._next
            for item in reply.items:
                try:
                    answer = wire.decode_answer(item, self.limits)
                except ProtocolError:
                    self.bad_messages += 1
                    break
                tag: Tag = answer.tag  # type: ignore[assignment]
                if tag.seq != self._next or tag.seq > upto:
                    break
                self.recovered += 1
                self._hand_over(answer)
                self._next += 1
            if self._next == before and self._next <= upto:
                self._give_up(upto, "the journal does not hold them" if not reply.items else "unreadable in the journal")

    def _give_up(self, upto: int, why: str) -> None:
        assert self._next is not None
        self.notices.append(f"answers {self._next}-{upto} missed: {why}")
        self.missed += upto - self._next + 1
        self._next = upto + 1

    def _history_client(self) -> HistoryClient:
        if self._history is None:
            endpoint = self._history_endpoint or history_endpoint(self.endpoint)
            self._history = HistoryClient(endpoint, keys=self.keys, timeout=self.history_timeout)
        return self._history

    def _hand_over(self, message: Published) -> None:
        kind = "result" if isinstance(message, Result) else "stats" if isinstance(message, Stats) else "error"
        if kind in self._wanted:
            self._ready.append(message)


def results(
    endpoint: str,
    *,
    timeout: float | None = None,
    count: int | None = None,
    keys: ClientKeys | None = None,
) -> Iterator[Result]:
    """Yield each :class:`Result` the service publishes.

    Ends after ``count`` results, or when no result arrived for ``timeout`` seconds;
    runs forever with neither. The socket closes when the loop ends or breaks.
    """
    with Listener(endpoint, topics=("result",), keys=keys) as listener:
        n = 0
        while count is None or n < count:
            message = listener.receive(timeout)
            if message is None:
                return
            if isinstance(message, Result):
                n += 1
                yield message

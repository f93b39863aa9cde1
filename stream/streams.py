"""The service's streams: one localizer state per stream id over the one shared map.

Every frame belongs to the stream its ``stream`` field names (a frame without
one to the stream ``""``). Each stream has its own :class:`Localizer` (sequence
window, tracker, running normalisation), so frames of different streams may
interleave freely; all of them read the same memory-mapped reference map and
share one backbone. A stream's state is created by its first frame, forgotten
after ``stream_expiry`` seconds without a frame, and at most ``max_streams``
exist at once, at most ``max_streams_per_peer`` of them held by one peer (one
connection to the frames socket), so that one peer cannot take every slot.
The service's I/O loop owns the table; the worker only steps the localizer a
job carries.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Callable, Iterator, Literal

from lostx.core.backbones import Backbone
from lostx.core.config import Config
from lostx.core.localizer import Localizer
from lostx.core.maps.refmap import ReferenceMap

from .errors import ProtocolError
from .messages import StreamStats


def localizer_factory(refmap: ReferenceMap, config: Config, backbone: Backbone | None = None) -> Callable[[], Localizer]:
    """New localizers over ``refmap``, all sharing one backbone. The first is made at once, so a
    map and a backbone that do not go together fail here, before the service starts."""
    first = Localizer(refmap, config, backbone)
    shared = getattr(first.matcher.describer, "backbone", None)  # thumbnail maps have none
    spare = [first]

    def new_localizer() -> Localizer:
        return spare.pop() if spare else Localizer(refmap, config, shared)

    return new_localizer


TimeVerdict = Literal["ok", "restart"]


def check_time(previous: float | None, timestamp: float | None, max_jump: float) -> TimeVerdict:
    """Whether a frame stamped ``timestamp`` may follow one stamped ``previous`` in a stream.

    ``ok``; ``restart`` where the clock went back by more than ``max_jump`` (a restarted
    clock: a new traverse); :class:`ProtocolError` ``bad_timestamp`` where it went back
    less, or ahead by more than ``max_jump``. Frames without a timestamp are always ok.
    """
    if timestamp is None or previous is None:
        return "ok"
    if timestamp > previous + max_jump:
        raise ProtocolError("bad_timestamp", f"timestamp {timestamp:.17g} is {timestamp - previous:.3g} s after the "
                            f"stream's previous frame (at most max_time_jump = {max_jump:g} s)")
    if timestamp < previous:
        if previous - timestamp > max_jump:
            return "restart"
        raise ProtocolError("bad_timestamp", f"timestamp {timestamp:.17g} is earlier than the stream's previous "
                            f"frame ({previous:.17g}); a stream's frames must arrive in time order")
    return "ok"


@dataclass
class StreamCounts:
    received: int = 0
    answered: int = 0
    errors: int = 0
    dropped: int = 0
    missing: int = 0
    duplicates: int = 0
    restarts: int = 0


@dataclass
class StreamState:
    """Everything the service keeps about one stream."""

    name: str
    localizer: Localizer
    last_seen: float
    """time.monotonic() of the stream's last frame."""
    counts: StreamCounts = field(default_factory=StreamCounts)
    last_id: int | None = None
    """The highest frame id seen, to count ids that never arrived."""
    last_timestamp: float | None = None
    """The timestamp of the last frame handed to the localizer."""
    answers: int = 0
    """Answers given so far (the last answer's ``stream_seq``)."""
    in_service: int = 0
    """Frames taken and not yet answered; a stream with any never expires."""
    peer: bytes = b""
    """The routing id of the connection that sent the stream's last frame: the peer holding its slot."""

    def saw(self, frame_id: int) -> int:
        """Count a frame id; returns how many ids were skipped since the highest one seen."""
        skipped = 0
        if self.last_id is not None and frame_id > self.last_id + 1:
            skipped = frame_id - self.last_id - 1
        if self.last_id is None or frame_id > self.last_id:
            self.last_id = frame_id
        self.counts.missing += skipped
        return skipped

    def stats(self, now: float) -> StreamStats:
        c = self.counts
        return StreamStats(c.received, c.answered, c.errors, c.dropped, c.missing, c.duplicates, c.restarts,
                           self.in_service, round(now - self.last_seen, 3))


class StreamTable:
    """The live streams, bounded in number, in all and per peer; idle ones expire."""

    def __init__(self, new_localizer: Callable[[], Localizer], max_streams: int, expiry: float,
                 max_per_peer: int) -> None:
        self.new_localizer = new_localizer
        self.max_streams = max_streams
        self.max_per_peer = max_per_peer
        self.expiry = expiry
        self.created = 0
        self.expired = 0
        self.released = 0
        """Streams forgotten to make room for a newer stream of the same peer."""
        self._states: dict[str, StreamState] = {}

    def get(self, name: str, now: float, peer: bytes = b"") -> StreamState:
        """The stream's state, made on its first frame; ``too_many_streams`` when none is free.

        A peer holding ``max_per_peer`` streams that starts another gives up its own least recently
        used stream with no frame in service (a producer moving on to a new stream, a replay's next
        lap); when all of them have frames in service the new one is refused, whatever else is free."""
        state = self._states.get(name)
        if state is None:
            held = self.held_by(peer)
            if len(held) >= self.max_per_peer:
                idle = [s for s in held if s.in_service == 0]
                if not idle:
                    raise ProtocolError("too_many_streams", f"stream {name!r} would be one more than the "
                                        f"{self.max_per_peer} streams one producer may hold (max_streams_per_peer), "
                                        f"and each of its streams has a frame in service")
                del self._states[min(idle, key=lambda s: s.last_seen).name]
                self.released += 1
            if len(self._states) >= self.max_streams:
                self.expire(now)
            if len(self._states) >= self.max_streams:
                raise ProtocolError("too_many_streams", f"stream {name!r} would be one more than the "
                                    f"{self.max_streams} live streams (max_streams); a stream expires "
                                    f"{self.expiry:g} s after its last frame")
            state = StreamState(name, self.new_localizer(), now)
            self._states[name] = state
            self.created += 1
        state.last_seen = now
        state.peer = peer
        return state

    def peek(self, name: str) -> StreamState | None:
        """The stream's state where it has one (makes none)."""
        return self._states.get(name)

    def held_by(self, peer: bytes) -> list[StreamState]:
        """The streams whose last frame came from ``peer``."""
        return [s for s in self._states.values() if s.peer == peer]

    def expire(self, now: float) -> list[str]:
        """Forget the streams idle for longer than the expiry time (never one with frames in service)."""
        gone = [name for name, s in self._states.items() if s.in_service == 0 and now - s.last_seen > self.expiry]
        for name in gone:
            del self._states[name]
        self.expired += len(gone)
        return gone

    def stats(self, now: float) -> dict[str, StreamStats]:
        return {name: state.stats(now) for name, state in self._states.items()}

    def __len__(self) -> int:
        return len(self._states)

    def __contains__(self, name: object) -> bool:
        return name in self._states

    def __iter__(self) -> Iterator[StreamState]:
        return iter(list(self._states.values()))


class AnsweredIds:
    """The frame ids answered lately, per stream: a frame a producer sends again after a reconnection
    is recognised (and acknowledged) instead of answered twice. A resend is at most a window old, so
    ``per_stream`` ids are plenty; the least recently used streams are forgotten first."""

    def __init__(self, per_stream: int = 1024, streams: int = 256) -> None:
        self.per_stream = per_stream
        self.streams = streams
        self._ids: OrderedDict[str, tuple[deque[int], set[int]]] = OrderedDict()

    def __contains__(self, key: tuple[str, int]) -> bool:
        entry = self._ids.get(key[0])
        return entry is not None and key[1] in entry[1]

    def discard(self, key: tuple[str, int]) -> None:
        """Forget that a frame was answered (its answer was withdrawn): sent again, it is answered again."""
        entry = self._ids.get(key[0])
        if entry is not None:
            entry[1].discard(key[1])

    def add(self, key: tuple[str, int]) -> None:
        stream, frame_id = key
        entry = self._ids.get(stream)
        if entry is None:
            if len(self._ids) >= self.streams:
                self._ids.popitem(last=False)
            entry = self._ids[stream] = (deque(), set())
        else:
            self._ids.move_to_end(stream)
        order, ids = entry
        order.append(frame_id)
        ids.add(frame_id)
        if len(order) > self.per_stream:
            ids.discard(order.popleft())

"""Feeding the service: :class:`FramePublisher`, all a camera process needs.

    publisher = FramePublisher("tcp://127.0.0.1:5555")
    publisher.wait_ready()                  # the service is up (and says live or lossless)
    for frame in camera:                    # any lostx.core.Frame
        publisher.send(frame)               # live: never blocks; lossless: waits for credit
    publisher.flush()                       # lossless: until every frame is answered
    publisher.close()

The publisher connects (the service binds), so it may start first and it keeps
working across a service restart. In lossless mode it keeps every frame that is
not yet answered and, after any reconnection (a restarted service, a dropped
connection), sends them again in order, so nothing is lost; docs/protocol.md
has the whole exchange.
"""

from __future__ import annotations

import secrets
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field

import zmq
from zmq.utils.monitor import recv_monitor_message

from lostx.core.frame import Frame

from . import wire
from .errors import ProtocolError, StreamError
from .messages import VERSION, Ack, ErrorMessage, Limits, Ready, Reply
from .sockets import ClientKeys, connect

HELLO_RETRY_S = 0.5
"""How often a producer waiting for the service says hello again."""
REPLY_LIMITS = Limits(max_message_bytes=1024 * 1024)
"""Replies are small; a larger one is refused unread."""
SEND_AGAIN = frozenset({"journal_unwritable"})
"""Error codes that refuse a frame for now only: lossless, it is sent again after :data:`SEND_AGAIN_S`."""
SEND_AGAIN_S = 1.0


@dataclass
class PublisherCounts:
    sent: int = 0
    """Frames handed to the socket (resends not included)."""
    dropped: int = 0
    """Live: frames not sent because the service was absent or not keeping up."""
    acked: int = 0
    """Lossless: frames the service answered."""
    resent: int = 0
    """Lossless: frames sent again after a reconnection (a restarted service, a dropped connection)."""
    refused: int = 0
    """Error replies received."""
    sessions: list[str] = field(default_factory=list)
    """Service sessions seen, in order (more than one: the service restarted)."""


class FramePublisher:
    """A producer's end of the frames channel (a DEALER socket that connects)."""

    def __init__(
        self,
        endpoint: str,
        *,
        encoding: str = "raw",
        quality: int = 90,
        stream: str | None = None,
        name: str | None = None,
        keys: ClientKeys | None = None,
    ) -> None:
        if encoding not in ("raw", "png", "jpeg"):
            raise StreamError(f"unknown encoding {encoding!r}: use raw, png or jpeg")
        self.endpoint = endpoint
        self.encoding = encoding
        self.quality = quality
        self.stream = stream if stream is not None else secrets.token_hex(4)
        self.name = name
        self.counts = PublisherCounts()
        self.errors: deque[ErrorMessage] = deque(maxlen=100)
        self.ready: Ready | None = None
        self._outdated: str | None = None  # why a service refused this producer's schema version
        self._pending: OrderedDict[int, tuple[bytes, float | None]] = OrderedDict()  # id -> (payload, sent at)
        self._last_hello = 0.0
        self._held_until = 0.0  # the service refused frames for now: none is sent before this
        self._connections = 0
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.DEALER)
        # IMMEDIATE: no queueing towards a service that is not connected (live frames would be stale
        # by the time it is; lossless frames are kept here and resent instead).
        self._socket.setsockopt(zmq.IMMEDIATE, 1)
        self._socket.setsockopt(zmq.SNDHWM, 4)
        self._socket.setsockopt(zmq.RCVHWM, 1000)
        self._socket.setsockopt(zmq.MAXMSGSIZE, REPLY_LIMITS.max_message_bytes)
        self._socket.setsockopt(zmq.LINGER, 1000)
        # Connection events tell a reconnection (frames in flight on the old connection are lost).
        self._monitor = self._socket.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED)
        try:
            connect(self._socket, endpoint, keys)
        except BaseException:
            self.close()
            raise

    # -- public API ----------------------------------------------------------------------------

    @property
    def lossless(self) -> bool:
        return self.ready is not None and self.ready.mode == "lossless"

    @property
    def in_flight(self) -> int:
        """Lossless: frames sent and not yet answered."""
        return len(self._pending)

    def wait_ready(self, timeout: float | None = None) -> Ready:
        """Say hello until the service answers; raises :class:`StreamError` after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        self.ready = None
        while self.ready is None:
            if time.monotonic() - self._last_hello >= HELLO_RETRY_S:
                self._hello()
            self._read_replies(50)
            if self._outdated is not None:
                raise StreamError(f"the service at {self.endpoint} is older than this producer: it refused "
                                  f"protocol version {VERSION} ({self._outdated}); upgrade the service")
            if deadline is not None and time.monotonic() > deadline:
                raise StreamError(f"no service answered at {self.endpoint} within {timeout:.0f} s")
        return self.ready

    def send(self, frame: Frame, timeout: float | None = None) -> bool:
        """Send one frame. Live: never waits; False when it had to be dropped. Lossless: waits
        for credit (``timeout`` seconds at most, then :class:`StreamError`) and returns True."""
        payload = wire.encode_frame(frame, self.encoding, self.quality, self.stream)
        if self.ready is not None and len(payload) > self.ready.max_message_bytes:
            raise StreamError(f"frame {frame.id}: {len(payload)} bytes is over the service's limit of "
                              f"{self.ready.max_message_bytes}; use --encoding jpeg or smaller frames")
        self._read_replies(0)
        if not self.lossless:
            try:
                self._socket.send(payload, zmq.NOBLOCK, copy=False)  # zero-copy: ZeroMQ sends from our bytes
            except zmq.Again:
                self.counts.dropped += 1
                return False
            self.counts.sent += 1
            return True
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            self._send_unsent(deadline)  # frames to resend go first, in order
            if self.in_flight < self.ready.window:  # type: ignore[union-attr]
                break
            self._wait_step(deadline)
        self._pending[int(frame.id)] = (payload, None)
        self._send_unsent(deadline)
        self.counts.sent += 1
        return True

    def flush(self, timeout: float | None = None) -> bool:
        """Lossless: wait until every frame sent is answered. Live: nothing to wait for."""
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            while self.lossless and self._pending:
                self._send_unsent(deadline)
                if self._pending:
                    self._wait_step(deadline)
        except StreamError:
            return False
        return not self._pending

    def close(self) -> None:
        if self._socket is not None:
            self._socket.disable_monitor()
            self._monitor.close(linger=0)
            self._socket.close()
            self._socket = None  # type: ignore[assignment]
        self._context.term()

    def __enter__(self) -> "FramePublisher":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------------------

    def _hello(self) -> None:
        self._last_hello = time.monotonic()
        try:
            self._socket.send(wire.encode_hello(self.stream, self.name), zmq.NOBLOCK)
        except zmq.Again:
            pass  # not connected yet: the next hello will try again

    def _wait_step(self, deadline: float | None) -> None:
        """Wait a little for replies and connection events."""
        if deadline is not None and time.monotonic() > deadline:
            raise StreamError(f"the service at {self.endpoint} has not answered {self.in_flight} frame(s) in time")
        self._read_replies(50)

    def _send_unsent(self, deadline: float | None) -> None:
        """Send every pending frame not (or no longer) sent, oldest first."""
        while time.monotonic() < self._held_until:
            self._wait_step(deadline)
        while True:
            frame_id = next((i for i, (_, sent_at) in self._pending.items() if sent_at is None), None)
            if frame_id is None:
                return
            payload = self._pending[frame_id][0]
            try:
                self._socket.send(payload, zmq.NOBLOCK, copy=False)
            except zmq.Again:
                # Not connected (the service is restarting) or its queue is full: wait and retry;
                # the frame stays pending either way, so nothing is lost.
                self._wait_step(deadline)
                continue
            self._pending[frame_id] = (payload, time.monotonic())

    def _read_replies(self, timeout_ms: int) -> None:
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        events = dict(poller.poll(timeout_ms))
        if events.get(self._monitor):
            self._on_connection_events()
        if not events.get(self._socket):
            return
        while True:
            try:
                data = self._socket.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                reply = wire.decode_reply(data, REPLY_LIMITS)
            except ProtocolError:
                continue  # the service is not trusted either; a bad reply is ignored
            self._on_reply(reply)

    def _on_connection_events(self) -> None:
        while True:
            try:
                event = recv_monitor_message(self._monitor, zmq.NOBLOCK)
            except zmq.Again:
                return
            if event["event"] != zmq.EVENT_HANDSHAKE_SUCCEEDED:
                continue
            self._connections += 1
            if self._connections > 1:
                # A new connection (a restarted service, or a dropped one): whatever was in flight on the
                # old one is gone. Send it all again, in order; the service acknowledges without answering
                # twice a frame it had already answered. And ask who is there now.
                self._resend_all()
                self._hello()

    def _on_reply(self, reply: Reply) -> None:
        if isinstance(reply, Ready):
            self.ready = reply
            if not self.counts.sessions or self.counts.sessions[-1] != reply.session:
                self.counts.sessions.append(reply.session)
        elif isinstance(reply, Ack):
            if self._pending.pop(reply.frame_id, None) is not None:
                self.counts.acked += 1
        else:
            self.counts.refused += 1
            self.errors.append(reply)
            if reply.code == "bad_version" and reply.frame_id is None:
                self._outdated = reply.text
            if reply.frame_id is None or reply.frame_id not in self._pending:
                return
            if reply.code in SEND_AGAIN:
                self._pending[reply.frame_id] = (self._pending[reply.frame_id][0], None)
                self._held_until = time.monotonic() + SEND_AGAIN_S
            else:
                del self._pending[reply.frame_id]  # an error is that frame's answer

    def _resend_all(self) -> None:
        """Mark every pending frame sent so far to be sent again (in order, by :meth:`_send_unsent`)."""
        for frame_id, (payload, sent_at) in list(self._pending.items()):
            if sent_at is not None:
                self._pending[frame_id] = (payload, None)
                self.counts.resent += 1

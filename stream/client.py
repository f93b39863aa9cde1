"""Consuming the service's answers: :func:`results` and :class:`Listener`.

    import lostx.stream
    for result in lostx.stream.results("tcp://127.0.0.1:5556"):
        print(result.frame_id, result.match_index, result.confidence)

A listener connects (the service binds), so it may start before the service and
it picks a restarted service up by itself (``Result.session`` changes). Any
number of listeners may listen at once. Messages that fail to decode are
counted (``Listener.bad_messages``) and skipped: the service is not trusted either.
"""

from __future__ import annotations

import time
from typing import Iterator, Sequence

import zmq

from . import protocol as wire
from .errors import ProtocolError
from .protocol import Limits, Published, Result
from .sockets import ClientKeys, apply_client_keys, connect

LISTENER_LIMITS = Limits(max_message_bytes=1024 * 1024)
"""Result, error and stats messages are small (a few kB); anything over 1 MiB is refused unread."""


class Listener:
    """A SUB socket on the results channel, decoding what arrives."""

    def __init__(
        self,
        endpoint: str,
        *,
        topics: Sequence[str] = ("result", "error", "stats"),
        keys: ClientKeys | None = None,
        hwm: int = 10_000,
        rcvbuf: int | None = None,
        limits: Limits = LISTENER_LIMITS,
    ) -> None:
        """``hwm``: messages ZeroMQ holds for this listener; ``rcvbuf``: the kernel's receive
        buffer in bytes (None: the system default). Small values make a slow listener felt
        sooner: by the service in lossless mode, as dropped results in live mode."""
        unknown = [t for t in topics if t.encode() not in wire.TOPICS]
        if unknown:
            raise ValueError(f"unknown topic(s) {', '.join(unknown)}; known: result, error, stats")
        self.endpoint = endpoint
        self.limits = limits
        self.bad_messages = 0
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.SUB)
        self._socket.setsockopt(zmq.RCVHWM, hwm)
        if rcvbuf is not None:
            self._socket.setsockopt(zmq.RCVBUF, rcvbuf)
        self._socket.setsockopt(zmq.MAXMSGSIZE, limits.max_message_bytes)
        self._socket.setsockopt(zmq.LINGER, 0)
        try:
            if keys is not None:
                apply_client_keys(self._socket, keys)
            for topic in topics:
                self._socket.setsockopt(zmq.SUBSCRIBE, topic.encode())
            connect(self._socket, endpoint)
        except BaseException:
            self.close()
            raise

    def receive(self, timeout: float | None = None) -> Published | None:
        """The next message (Result, ErrorMessage or Stats); None after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
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
                return wire.decode_published(parts[0], parts[1], self.limits)
            except ProtocolError:
                self.bad_messages += 1

    def __iter__(self) -> Iterator[Published]:
        while True:
            message = self.receive()
            if message is not None:
                yield message

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None  # type: ignore[assignment]
        self._context.term()

    def __enter__(self) -> "Listener":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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

"""A listener's end of the history channel: the journaled answers after a sequence number.

This is the ZeroMQ guide's Clone pattern, with the journal as the snapshot: a
listener subscribes to the results first, then asks the service's history
socket (a ROUTER) for what it missed, and from then on takes the live answers
whose sequence numbers follow. A request that gets no reply (the service is
restarting, or the reply was lost with a broken connection) is sent again
until the timeout.
"""

from __future__ import annotations

import time

import zmq

from . import protocol as wire
from .errors import ProtocolError, StreamError
from .protocol import Fetch, History, Limits
from .sockets import ClientKeys, connect

RETRY_S = 1.0
"""How long to wait for a reply before asking again."""
REPLY_LIMITS = Limits(max_message_bytes=1024 * 1024)


class HistoryClient:
    """Fetch journaled answers from a service's history endpoint (a DEALER socket that connects)."""

    def __init__(self, endpoint: str, *, keys: ClientKeys | None = None, timeout: float = 30.0) -> None:
        self.endpoint = endpoint
        self.timeout = timeout
        self._context = zmq.Context()
        self._socket = self._context.socket(zmq.DEALER)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.setsockopt(zmq.MAXMSGSIZE, REPLY_LIMITS.max_message_bytes)
        try:
            connect(self._socket, endpoint, keys)
        except BaseException:
            self.close()
            raise

    def fetch(self, after: int, count: int) -> History:
        """Up to ``count`` answers after ``after``; :class:`StreamError` if the service does not answer
        within the timeout or refuses the request."""
        request = wire.encode_fetch(Fetch(after, min(count, wire.MAX_FETCH)))
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            try:
                self._socket.send(request, zmq.NOBLOCK)
            except zmq.Again:
                pass  # requests are queued already: one of them will do
            retry = min(deadline, time.monotonic() + RETRY_S)
            while (wait := retry - time.monotonic()) > 0:
                if not self._socket.poll(int(1e3 * wait) + 1, zmq.POLLIN):
                    continue
                try:
                    reply = wire.decode_history(self._socket.recv(), REPLY_LIMITS)
                except ProtocolError:
                    continue  # the service is not trusted either
                if isinstance(reply, wire.ErrorMessage):
                    raise StreamError(f"the history at {self.endpoint} refused: {reply.code}: {reply.text}")
                if reply.after == after:
                    return reply
                # A late reply to an earlier request: not this one.
        raise StreamError(f"no answer from the history at {self.endpoint} within {self.timeout:.0f} s")

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None  # type: ignore[assignment]
        self._context.term()

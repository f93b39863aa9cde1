"""The history channel: the journaled answers after a sequence number, fetched by a listener and served
by the service from its journal.

This is the ZeroMQ guide's Clone pattern, with the journal as the snapshot: a
listener subscribes to the results first, then asks the service's history
socket (a ROUTER) for what it missed, and from then on takes the live answers
whose sequence numbers follow. A request that gets no reply (the service is
restarting, or the reply was lost with a broken connection) is sent again
until the timeout.
"""

from __future__ import annotations

import time
from collections import Counter

import zmq

from . import wire
from .errors import ProtocolError, StreamError
from .journal import Journal, JournalError
from .messages import MAX_FETCH, ErrorMessage, Fetch, History, Limits
from .sockets import ClientKeys, connect

HISTORY_BYTES = 512 * 1024
"""Most payload bytes in one history reply (listeners refuse messages over 1 MiB)."""
HISTORY_LIMITS = Limits(max_message_bytes=4096)
"""A fetch request is a few bytes."""
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
        request = wire.encode_fetch(Fetch(after, min(count, MAX_FETCH)))
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
                if isinstance(reply, ErrorMessage):
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


def serve_history(socket: zmq.Socket, journal: Journal, session: str, errors: Counter[str]) -> None:
    """Answer the fetch requests waiting on the service's history ``socket`` (a ROUTER) from ``journal``,
    which serves only what is durable; refusals are counted in ``errors`` by code."""
    for _ in range(100):
        try:
            parts = socket.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return
        identity, body = parts[0], parts[1:]
        try:
            if len(body) != 1:
                raise ProtocolError("multipart", f"expected one message part, got {len(body)}")
            fetch = wire.decode_fetch(body[0], HISTORY_LIMITS)
            items = journal.read(fetch.after, fetch.max, HISTORY_BYTES)
            reply = wire.encode_history(History(session, journal.id, fetch.after, journal.first, journal.committed,
                                                tuple(items)))
        except ProtocolError as exc:
            errors[exc.code] += 1
            reply = wire.encode_error(ErrorMessage(exc.code, exc.text, None, session))
        except (JournalError, OSError) as exc:
            errors["journal_failed"] += 1
            reply = wire.encode_error(ErrorMessage("journal_failed", str(exc), None, session))
        try:
            socket.send_multipart([identity, reply], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass  # the listener is gone or not reading; it asks again

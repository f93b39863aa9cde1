"""Errors of the wire: a peer's bad message, and a transport that cannot do what it was asked."""

from __future__ import annotations

from lostx.core.errors import InputError, LostxError


class StreamError(LostxError):
    """A socket cannot be bound or reached, a key file is unusable, or a peer did not answer in time."""


class ProtocolError(InputError):
    """A message that breaks the wire protocol (docs/protocol.md).

    ``code`` is one of :data:`lostx.stream.messages.ERROR_CODES`; ``frame_id`` is the frame's id
    where it could be read from the message, else ``None``. The service answers the peer with
    both, so the sender learns which frame was refused and why.
    """

    def __init__(self, code: str, text: str, frame_id: int | None = None) -> None:
        super().__init__(text)
        self.code = code
        self.text = text
        self.frame_id = frame_id

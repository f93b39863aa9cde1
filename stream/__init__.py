"""lostx.stream: the wire. The msgpack protocol, ZeroMQ sockets, the localizer service,
the replay producer and the client helpers (docs/protocol.md is the spec).

    import lostx.stream
    for result in lostx.stream.results("tcp://127.0.0.1:5556"):
        ...
"""

from .client import Listener, results
from .errors import ProtocolError, StreamError
from .journal import Journal, JournalError
from .producer import FramePublisher
from .protocol import ErrorMessage, Limits, Result, ResultCandidate, Stats, Tag
from .service import LocalizerService
from .sinks import JsonlSink, Sink
from .sockets import ClientKeys, ServerKeys, make_keys
from .streams import localizer_factory

__all__ = [
    "ClientKeys", "ErrorMessage", "FramePublisher", "Journal", "JournalError", "JsonlSink", "Limits", "Listener",
    "LocalizerService", "ProtocolError", "Result", "ResultCandidate", "ServerKeys", "Sink", "Stats", "StreamError",
    "Tag", "localizer_factory", "make_keys", "results",
]

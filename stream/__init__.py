"""lostx.stream: the wire. The msgpack protocol, ZeroMQ sockets, the localizer service,
the replay producer and the client helpers (docs/protocol.md is the spec).

    import lostx.stream
    for result in lostx.stream.results("tcp://127.0.0.1:5556"):
        ...

Names are imported on first use (ZeroMQ and the localizer load only then).
"""

from lostx.core.lazy import lazy_exports

_EXPORTS = {
    **dict.fromkeys(("Listener", "results"), ".client"),
    **dict.fromkeys(("ProtocolError", "StreamError"), ".errors"),
    **dict.fromkeys(("Journal", "JournalError"), ".journal"),
    "FramePublisher": ".producer",
    **dict.fromkeys(("ErrorMessage", "Limits", "Result", "ResultCandidate", "Stats", "Tag"), ".messages"),
    "LocalizerService": ".service",
    **dict.fromkeys(("JsonlSink", "Sink"), ".sinks"),
    **dict.fromkeys(("ClientKeys", "ServerKeys", "make_keys"), ".sockets"),
    "localizer_factory": ".streams",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

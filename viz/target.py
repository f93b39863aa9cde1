"""Where a recording should go, as plain data (importing this does not import Rerun)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"
DEFAULT_MEMORY_LIMIT = "2GiB"


@dataclass(frozen=True)
class ViewerOutput:
    """The destinations of one recording."""

    spawn: bool = False
    """Start the native viewer (``rerun`` on PATH) and stream to it."""
    connect: str | None = None
    """Stream to a viewer or server already running at this ``rerun+http://.../proxy`` URL."""
    rrd: Path | None = None
    """Write the recording to this file (open it later with ``rerun FILE``)."""
    web: bool = False
    """Host a gRPC server and the web viewer; print the URL to open."""
    memory_limit: str = DEFAULT_MEMORY_LIMIT
    """Memory limit of the spawned viewer and of the web server's buffer (e.g. ``2GiB``, ``25%``);
    past it the oldest data is dropped."""
    spawn_port: int = 9876
    grpc_port: int = 9877
    web_port: int = 9090

    @property
    def any(self) -> bool:
        return self.spawn or self.connect is not None or self.rrd is not None or self.web

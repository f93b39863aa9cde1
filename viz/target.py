"""Where a recording should go, as plain data (importing this does not import Rerun)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

DEFAULT_CONNECT = "rerun+http://127.0.0.1:9876/proxy"
DEFAULT_MEMORY_LIMIT = "2GiB"
DEFAULT_WEB_ADDRESS = "127.0.0.1"
"""The web viewer listens on loopback unless told otherwise: camera images are not for the network."""
WEB_PORT = 9090
GRPC_PORT = 9877
"""Rerun's own defaults: the web viewer's page, and the gRPC server it reads the recording from."""


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
    web_address: str = DEFAULT_WEB_ADDRESS
    """The address both of the web viewer's ports listen on (``0.0.0.0``: every interface)."""
    memory_limit: str = DEFAULT_MEMORY_LIMIT
    """Memory limit of the spawned viewer and of the web server's buffer (e.g. ``2GiB``, ``25%``);
    past it the oldest data is dropped."""
    spawn_port: int = 9876
    grpc_port: int = GRPC_PORT
    """0: a free port."""
    web_port: int = WEB_PORT
    """0: a free port."""

    @property
    def any(self) -> bool:
        return self.spawn or self.connect is not None or self.rrd is not None or self.web

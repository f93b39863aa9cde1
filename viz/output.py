"""Where the recording goes: a spawned viewer, a running one, an .rrd file, a served web viewer.

Any combination may be asked for at once; they are attached to one recording
stream as Rerun sinks, so each frame is encoded once.
"""

from __future__ import annotations

import shutil
import socket
import sys
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import rerun as rr
import rerun.blueprint as rrb

from lostx.core.errors import InputError

from .target import ViewerOutput


@dataclass
class OpenedOutput:
    """What :func:`open_output` attached, and what to tell the user."""

    messages: list[str] = field(default_factory=list)
    web_url: str | None = None


def open_output(recording: rr.RecordingStream, output: ViewerOutput, blueprint: rrb.Blueprint) -> OpenedOutput:
    """Attach ``output``'s destinations to ``recording``, each with ``blueprint`` as the default layout."""
    opened = OpenedOutput()
    sinks: list[rr.GrpcSink | rr.GrpcServerSink | rr.FileSink] = []
    if output.rrd is not None:
        Path(output.rrd).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(output.rrd)))
        opened.messages.append(f"recording to {output.rrd} (open it with: rerun {output.rrd})")
    if output.connect is not None:
        sinks.append(rr.GrpcSink(output.connect))
        opened.messages.append(f"streaming to the viewer at {output.connect}")
    if output.spawn:
        # Start the viewer with its memory limit, then connect like any other client.
        rr.spawn(port=output.spawn_port, connect=False, memory_limit=output.memory_limit,
                 executable_path=viewer_executable(), recording=recording)
        url = f"rerun+http://127.0.0.1:{output.spawn_port}/proxy"
        if url != output.connect:
            sinks.append(rr.GrpcSink(url))
        opened.messages.append(f"spawned the viewer (memory limit {output.memory_limit})")
    server: rr.GrpcServerSink | None = None
    if output.web:
        # Rerun reports a taken port only in its log; say so before anything is started.
        for port in (output.grpc_port, output.web_port):
            _require_free_port(port)
        server = rr.GrpcServerSink(port=output.grpc_port, server_memory_limit=output.memory_limit)
        sinks.append(server)
    if sinks:
        recording.set_sinks(*sinks, default_blueprint=blueprint)
    if server is not None:
        # The server listens on every interface; a browser on this machine reaches it at 127.0.0.1
        # (browsers refuse 0.0.0.0). From elsewhere, replace 127.0.0.1 with this machine's address.
        uri = f"rerun+http://127.0.0.1:{output.grpc_port}/proxy"
        rr.serve_web_viewer(web_port=output.web_port, open_browser=False, connect_to=uri)
        opened.web_url = f"http://localhost:{output.web_port}/?url={quote(uri, safe='')}"
        opened.messages.append(f"web viewer: {opened.web_url} (server buffer {output.memory_limit})")
    return opened


def _require_free_port(port: int) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("0.0.0.0", port))
        except OSError:
            raise InputError(f"port {port} is in use (another viewer or lostx --web?); stop it first") from None


def viewer_executable() -> str | None:
    """The ``rerun`` viewer: on PATH, else the one the rerun-sdk wheel ships in ``rerun_cli``.

    A virtual environment's ``bin`` is on PATH only when it is activated; ``.venv/bin/lostx
    --viewer`` run without activating it should still find the viewer installed beside it.
    """
    found = shutil.which("rerun")
    if found:
        return found
    try:
        import rerun_cli
    except ImportError:
        return None
    folder = Path(rerun_cli.__file__).parent
    suffix = ".exe" if sys.platform.startswith("win") else ""
    for candidate in (folder / "Rerun.app" / "Contents" / "MacOS" / "Rerun", folder / f"rerun{suffix}"):
        if candidate.is_file():
            return str(candidate)
    return None

"""Where the recording goes: a spawned viewer, a running one, an .rrd file, a served web viewer.

Any combination may be asked for at once; they are attached to one recording
stream as Rerun sinks, so each frame is encoded once. A viewer that cannot start
(no display, a failed window) is reported in one line and left out: the other
destinations, and the command's own results, go on without it.
"""

from __future__ import annotations

import dataclasses
import ipaddress
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

import rerun as rr
import rerun.blueprint as rrb

from lostx.core.errors import InputError

from .rerun_app import ALTERNATIVES, ViewerUnavailable, accepts_connections, free_port, port_is_free, spawn_viewer
from .target import ViewerOutput
from .web import WebViewer


@dataclass
class OpenedOutput:
    """What :func:`open_output` attached, and what to tell the user."""

    messages: list[str] = field(default_factory=list)
    web_url: str | None = None
    destinations: int = 0
    """Rerun sinks attached to the recording (0: everything asked for was unavailable)."""
    web: WebViewer | None = None

    def close(self) -> None:
        """Stop serving the web viewer's page (the recording's sinks are closed with the recording)."""
        if self.web is not None:
            self.web.close()
            self.web = None


def is_loopback(address: str) -> bool:
    return ipaddress.ip_address(address).is_loopback


def open_output(recording: rr.RecordingStream, output: ViewerOutput, blueprint: rrb.Blueprint) -> OpenedOutput:
    """Attach ``output``'s destinations to ``recording``, each with ``blueprint`` as the default layout."""
    opened = OpenedOutput()
    sinks: list[rr.GrpcSink | rr.GrpcServerSink | rr.FileSink] = []
    if output.web:
        output = _with_ports(output)
    if output.rrd is not None:
        Path(output.rrd).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(output.rrd)))
        opened.messages.append(f"recording to {output.rrd} (open it with: rerun {output.rrd})")
    if output.connect is not None:
        absent = no_viewer_at(output.connect)
        if absent is not None:
            # Said once here, instead of Rerun's own errors for every message it could not send.
            opened.messages.append(f"{absent}; going on without it (start the viewer first: `rerun`)")
        else:
            try:
                sinks.append(rr.GrpcSink(output.connect))
            except RuntimeError as exc:  # Rerun's words name the schemes it takes
                raise InputError(f"--connect: {exc}") from None
            opened.messages.append(f"streaming to the viewer at {output.connect}")
    if output.spawn:
        try:
            spawn_viewer(output.spawn_port, output.memory_limit)
        except ViewerUnavailable as exc:
            opened.messages.append(f"{exc}; {ALTERNATIVES}")
        else:
            url = f"rerun+http://127.0.0.1:{output.spawn_port}/proxy"
            if url != output.connect:
                sinks.append(rr.GrpcSink(url))
            opened.messages.append(f"native viewer on 127.0.0.1:{output.spawn_port} (memory limit {output.memory_limit})")
    if output.web:
        sinks.append(rr.GrpcServerSink(bind_ip=output.web_address, port=output.grpc_port,
                                       server_memory_limit=output.memory_limit,
                                       cors_allow_origin=page_origins(output.web_address, output.web_port)))
    if sinks:
        recording.set_sinks(*sinks, default_blueprint=blueprint)
    opened.destinations = len(sinks)
    if output.web:
        _serve_page(opened, output)
    return opened


def no_viewer_at(url: str, timeout: float = 2.0) -> str | None:
    """Why nothing can take a recording at ``url`` (nothing accepts connections on its port), or None where
    something listens there, or where the URL names no port to try (Rerun's own default is then used)."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        return None  # not a URL Rerun takes either: its own message says why
    if port is None or not parts.hostname:
        return None
    if accepts_connections(port, parts.hostname, timeout):
        return None
    return f"no Rerun viewer at {url} (nothing accepts connections on {parts.hostname}:{port})"


def _with_ports(output: ViewerOutput) -> ViewerOutput:
    """``output`` with free ports in place of 0; an error where a port asked for is taken."""
    ports = {}
    for name in ("web_port", "grpc_port"):
        port = getattr(output, name)
        if port == 0:
            port = free_port(output.web_address, avoid=set(ports.values()))
        elif not port_is_free(output.web_address, port):
            # Rerun reports a taken port only in its log; say so before anything is started.
            raise InputError(f"port {port} on {output.web_address} is in use (another lostx --web or Rerun viewer?); "
                             f"stop it or choose another with --{name.replace('_', '-')}")
        ports[name] = port
    return dataclasses.replace(output, **ports)


def page_origins(address: str, web_port: int) -> list[str]:
    """Origins whose pages may read the recording from the gRPC server: the web viewer's own."""
    if address in ("0.0.0.0", "::"):
        return [f"http://*:{web_port}"]
    host = f"[{address}]" if ":" in address else address
    return list(dict.fromkeys([f"http://{host}:{web_port}", f"http://127.0.0.1:{web_port}", f"http://localhost:{web_port}"]))


def _serve_page(opened: OpenedOutput, output: ViewerOutput) -> None:
    try:
        opened.web = WebViewer(output.web_address, output.web_port, output.grpc_port)
    except (ViewerUnavailable, OSError) as exc:
        opened.messages.append(f"{exc}; the recording is still served: open it with "
                               f"`rerun rerun+http://127.0.0.1:{output.grpc_port}/proxy`")
        return
    opened.web_url = opened.web.url()
    opened.messages.append(f"web viewer at {opened.web_url} (server buffer {output.memory_limit})")
    if not is_loopback(output.web_address):
        opened.messages.append(f"the web viewer listens on {output.web_address}: anyone who can reach this machine "
                               f"on ports {output.web_port} and {output.grpc_port} sees the camera images")

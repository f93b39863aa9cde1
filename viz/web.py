"""The web viewer, served from this machine with no call to any other.

Rerun's web viewer is a page, a script and a WebAssembly program that Rerun's ``rerun``
program hands out over HTTP. As published, the page loads fonts from Google and the
program asks GitHub for newer releases, Rerun's servers for examples and reports usage
to them. lostx runs Rerun's file server on a private loopback port and puts a small
proxy in front of it, on the address the user chose, that

- drops the page's links to outside font servers (the viewer brings its own fonts), and
- sends a Content-Security-Policy with every response, so that the browser lets the
  page talk to this machine only: the page's own address and the recording's gRPC port.

The recording itself is served by the lostx process (a Rerun gRPC server sink).
"""

from __future__ import annotations

import http.client
import re
import shutil
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import quote

from .rerun_app import Started, free_port, start

OUTSIDE_FONTS = re.compile(rb"<link\b[^>]*fonts\.(?:googleapis|gstatic)\.com[^>]*>", re.IGNORECASE)
"""The page's links to Google's font servers (stylesheet and preconnect hints)."""
PASSED_HEADERS = ("Content-Type", "Content-Length", "Content-Encoding", "rerun-final-length")
"""Response headers of Rerun's file server that the page needs (the last one drives its progress bar)."""


def content_policy(page_host: str, grpc_port: int) -> str:
    """The Content-Security-Policy of every response: nothing but this machine.

    ``page_host`` is the host the browser used to reach the page; the recording's gRPC
    server is on the same machine, so the page may also reach that host (and the loopback
    names) on ``grpc_port``."""
    grpc = " ".join(f"http://{host}:{grpc_port}" for host in dict.fromkeys((page_host, "127.0.0.1", "localhost")))
    return ("default-src 'self'; script-src 'self' 'unsafe-inline' 'wasm-unsafe-eval'; "
            "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
            f"worker-src 'self' blob:; connect-src 'self' {grpc}")


def strip_outside_fonts(page: bytes) -> bytes:
    return OUTSIDE_FONTS.sub(b"", page)


def host_of(header: str | None) -> str:
    """The host name of an HTTP Host header (``[::1]:9090`` -> ``[::1]``, ``example:9090`` -> ``example``)."""
    if not header:
        return "127.0.0.1"
    if header.startswith("["):
        return header[: header.index("]") + 1] if "]" in header else header
    return header.rsplit(":", 1)[0] if header.count(":") == 1 else header


class _Proxy(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, address: tuple[str, int], upstream_port: int, grpc_port: int) -> None:
        self.upstream_port = upstream_port
        self.grpc_port = grpc_port
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        super().__init__(address, _Handler)


class _Handler(BaseHTTPRequestHandler):
    server: _Proxy
    protocol_version = "HTTP/1.0"  # one response per connection: a streamed body ends when the connection does

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        path = self.path.split("?", 1)[0] or "/"
        upstream = http.client.HTTPConnection("127.0.0.1", self.server.upstream_port, timeout=30)
        try:
            upstream.request("GET", path)
            response = upstream.getresponse()
            page = response.getheader("Content-Type", "").startswith("text/html")
            body = strip_outside_fonts(response.read()) if page else None
            self.send_response(response.status)
            for name in PASSED_HEADERS:
                value = response.getheader(name)
                # The page's length changes with the links taken out.
                if value is not None and not (page and name in ("Content-Length", "rerun-final-length")):
                    self.send_header(name, value)
            if body is not None:
                self.send_header("Content-Length", str(len(body)))
            self.send_header("Content-Security-Policy", content_policy(host_of(self.headers.get("Host")),
                                                                       self.server.grpc_port))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            if body is not None:
                self.wfile.write(body)
            else:
                shutil.copyfileobj(response, self.wfile, 1 << 20)
        except (OSError, http.client.HTTPException):
            pass  # the browser went away, or the file server ended with lostx: nothing to tell anyone
        finally:
            upstream.close()

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (http.server's signature)
        pass  # one line per file fetched is noise in a command's output


class WebViewer:
    """Rerun's web viewer for a recording served on ``grpc_port``, at ``address:web_port``."""

    def __init__(self, address: str, web_port: int, grpc_port: int) -> None:
        self.address = address
        self.web_port = web_port
        self.grpc_port = grpc_port
        files_port = free_port()
        grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
        self._files: Started | None = start(
            ["--serve-web", grpc_url, "--bind", "127.0.0.1", "--web-viewer-port", str(files_port)],
            files_port, "web viewer's file server", tied=True)
        try:
            self._proxy = _Proxy((address, web_port), files_port, grpc_port)
        except OSError:
            self._files.stop()
            raise
        self._thread = threading.Thread(target=self._proxy.serve_forever, name="lostx-web-viewer", daemon=True)
        self._thread.start()

    def url(self, host: str | None = None) -> str:
        """The address to open in a browser on this machine (or, with ``host``, from elsewhere)."""
        if host is None:
            host = "127.0.0.1" if self.address in ("0.0.0.0", "::") else self.address
        if ":" in host and not host.startswith("["):
            host = f"[{host}]"
        recording = quote(f"rerun+http://{host}:{self.grpc_port}/proxy", safe="")
        return f"http://{host}:{self.web_port}/?url={recording}"

    def close(self) -> None:
        self._proxy.shutdown()
        self._proxy.server_close()
        if self._files is not None:
            self._files.stop()
            self._files = None

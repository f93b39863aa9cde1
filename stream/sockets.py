"""ZeroMQ sockets as lostx uses them: who binds, who connects, which options, which keys.

The service binds both of its sockets and everybody else connects. A
connecting ZeroMQ socket reconnects by itself, so producers and listeners can
start before the service, and keep working when the service is restarted at
the same address; the service is the one fixed point.

Binding is loopback-only unless the caller says otherwise, and a socket bound
to a non-loopback address must use CurveZMQ (or be explicitly marked
insecure): the service is never exposed on a network by accident.
"""

from __future__ import annotations

import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from .errors import StreamError

KEEPALIVE_IDLE_S = 10
KEEPALIVE_INTERVAL_S = 5
KEEPALIVE_COUNT = 3
"""TCP keepalive: a peer whose host is gone (no FIN ever comes) is dropped after about 25 s.

Not ZeroMQ's own ZMTP heartbeats: a peer reads no PING while its input is stalled by
back-pressure, so heartbeats would cut off a listener that is merely slow (exactly the
one a lossless service must wait for), and libzmq 4.3 can abort on reconnecting such a
stalled connection (zeromq/libzmq#3937). The kernel answers keepalive probes whatever
the application does, so keepalive drops dead hosts only."""

RECONNECT_IVL_MS = 100
"""First reconnection attempt after a peer went away (then doubling up to the maximum)."""
RECONNECT_IVL_MAX_MS = 1000


def is_local_endpoint(endpoint: str) -> bool:
    """True for ipc://, inproc:// and tcp:// on a loopback address."""
    transport, _, address = endpoint.partition("://")
    if transport in ("ipc", "inproc"):
        return True
    if transport != "tcp":
        return False
    host = address.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # "*", an interface name, or a host name: all can face a network


def history_endpoint(results: str) -> str:
    """The history endpoint that goes with a results endpoint, unless one is given: the next port
    (tcp), or the same name with ``-history`` appended (ipc, inproc). Port 0 (any) stays 0."""
    transport, _, address = results.partition("://")
    if transport == "tcp":
        host, colon, port = address.rpartition(":")
        if not colon or not port.isdigit():
            raise StreamError(f"cannot derive a history endpoint from {results}: give one")
        return f"tcp://{host}:{int(port) + 1 if int(port) else 0}"
    if transport in ("ipc", "inproc"):
        return f"{results}-history"
    raise StreamError(f"cannot derive a history endpoint from {results}: use tcp://, ipc:// or inproc://")


def check_bind_endpoint(endpoint: str, secure: bool, insecure_ok: bool = False) -> None:
    """Refuse to bind a non-loopback address without CurveZMQ unless told to."""
    transport = endpoint.partition("://")[0]
    if transport not in ("tcp", "ipc", "inproc"):
        raise StreamError(f"cannot bind {endpoint}: use tcp://HOST:PORT, ipc://PATH or inproc://NAME")
    if not is_local_endpoint(endpoint) and not secure and not insecure_ok:
        raise StreamError(
            f"refusing to bind {endpoint} (not loopback) without CurveZMQ keys: pass --curve-secret and "
            f"--curve-clients (make keys with `lostx keys`), or --insecure on a trusted network"
        )


@dataclass(frozen=True)
class ServerKeys:
    """CurveZMQ for the service: its own key pair, and the public keys of the clients it accepts."""

    secret_file: Path
    """The service's ``.key_secret`` file (from ``lostx keys``)."""
    clients_dir: Path
    """Folder of the ``.key`` public key files of every producer and listener allowed in."""


@dataclass(frozen=True)
class ClientKeys:
    """CurveZMQ for a producer or listener: the service's public key and the client's own key pair."""

    server_public_file: Path
    secret_file: Path


def make_keys(directory: str | Path, name: str) -> tuple[Path, Path]:
    """Write ``NAME.key`` (public, share it) and ``NAME.key_secret`` (keep it) into ``directory``."""
    if not zmq.has("curve"):
        raise StreamError("this libzmq was built without CurveZMQ support")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    public, secret = directory / f"{name}.key", directory / f"{name}.key_secret"
    for path in (public, secret):
        if path.exists():
            raise StreamError(f"{path} exists; remove it or choose another --name")
    made_public, made_secret = zmq.auth.create_certificates(str(directory), name)
    os.chmod(made_secret, 0o600)
    return Path(made_public), Path(made_secret)


def _load(path: Path, secret: bool) -> tuple[bytes, bytes | None]:
    if not path.is_file():
        raise StreamError(f"key file not found: {path}")
    try:
        public, secret_key = zmq.auth.load_certificate(str(path))
    except (ValueError, OSError) as exc:
        raise StreamError(f"{path}: not a CurveZMQ key file ({exc})") from None
    if secret and secret_key is None:
        raise StreamError(f"{path} holds no secret key (pass the .key_secret file)")
    return public, secret_key


def apply_server_keys(socket: zmq.Socket, keys: ServerKeys) -> None:
    _, secret = _load(keys.secret_file, secret=True)
    socket.curve_secretkey = secret
    socket.curve_server = True


def apply_client_keys(socket: zmq.Socket, keys: ClientKeys) -> None:
    server_public, _ = _load(keys.server_public_file, secret=False)
    public, secret = _load(keys.secret_file, secret=True)
    socket.curve_serverkey = server_public
    socket.curve_publickey = public
    socket.curve_secretkey = secret


def start_authenticator(context: zmq.Context, keys: ServerKeys) -> ThreadAuthenticator:
    """ZAP handler (a thread of this process) that admits only the clients in ``keys.clients_dir``."""
    if not keys.clients_dir.is_dir():
        raise StreamError(f"client keys folder not found: {keys.clients_dir}")
    if not any(keys.clients_dir.glob("*.key")):
        raise StreamError(f"{keys.clients_dir} holds no client public keys (*.key); no client could connect")
    auth = ThreadAuthenticator(context)
    auth.start()
    auth.configure_curve(domain="*", location=str(keys.clients_dir))
    return auth


def keep_alive(socket: zmq.Socket) -> None:
    socket.setsockopt(zmq.TCP_KEEPALIVE, 1)
    socket.setsockopt(zmq.TCP_KEEPALIVE_IDLE, KEEPALIVE_IDLE_S)
    socket.setsockopt(zmq.TCP_KEEPALIVE_INTVL, KEEPALIVE_INTERVAL_S)
    socket.setsockopt(zmq.TCP_KEEPALIVE_CNT, KEEPALIVE_COUNT)


def bind(socket: zmq.Socket, endpoint: str) -> str:
    """Bind and return the actual endpoint (``tcp://127.0.0.1:0`` picks a free port)."""
    if endpoint.startswith("ipc://"):
        Path(endpoint[len("ipc://"):]).parent.mkdir(parents=True, exist_ok=True)
    try:
        socket.bind(endpoint)
    except zmq.ZMQError as exc:
        raise StreamError(f"cannot bind {endpoint}: {exc}") from None
    return socket.getsockopt_string(zmq.LAST_ENDPOINT)


def connect(socket: zmq.Socket, endpoint: str, keys: ClientKeys | None = None) -> None:
    """Connect with keep-alive and reconnection settings; with ``keys``, as a CurveZMQ client (the keys
    must be on the socket before it connects)."""
    transport = endpoint.partition("://")[0]
    if transport not in ("tcp", "ipc", "inproc"):
        raise StreamError(f"cannot connect to {endpoint}: use tcp://HOST:PORT, ipc://PATH or inproc://NAME")
    if keys is not None:
        apply_client_keys(socket, keys)
    keep_alive(socket)
    socket.setsockopt(zmq.RECONNECT_IVL, RECONNECT_IVL_MS)
    socket.setsockopt(zmq.RECONNECT_IVL_MAX, RECONNECT_IVL_MAX_MS)
    try:
        socket.connect(endpoint)
    except zmq.ZMQError as exc:
        raise StreamError(f"cannot connect to {endpoint}: {exc}") from None

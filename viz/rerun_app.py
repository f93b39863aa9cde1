"""Rerun's own programs, started the way lostx wants them: telemetry off, loopback only,
and a failure to start said in one line instead of a hang.

lostx starts two: the native viewer (``--viewer``) and the small file server that hands
the web viewer's page to a browser (``--web``, see :mod:`.web`). Both run with their own
Rerun configuration folder in which Rerun's usage analytics are disabled (Rerun's own
``rerun analytics disable``, applied to that folder only), so neither reports to Rerun's
servers and the user's own Rerun settings are left as they are.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from lostx.core.paths import cache_dir

ALTERNATIVES = "use --web (a browser), --rrd FILE (open it later with `rerun FILE`) or --connect URL instead"
"""What to do when no native viewer can start: said with every such message."""
START_TIMEOUT = 15.0
"""Seconds a started Rerun program gets to listen on its port."""
WINDOW_SETTLE = 2.0
"""Seconds the native viewer must survive after it listens: where no window can open, it exits within them."""


class ViewerUnavailable(RuntimeError):
    """A Rerun program could not start; the message is one line for the user."""


def viewer_executable() -> str | None:
    """The ``rerun`` program: the one the rerun-sdk wheel ships in ``rerun_cli`` (the viewer of the SDK's own
    version), else one on PATH.

    Not PATH first: in an activated virtual environment ``rerun`` there is pip's Python wrapper, which runs the
    wheel's program as a child of its own; stopping the wrapper leaves that child serving. Without the wheel's
    program (a viewer installed apart), PATH's is used.
    """
    try:
        import rerun_cli
    except ImportError:
        rerun_cli = None
    if rerun_cli is not None:
        folder = Path(rerun_cli.__file__).parent
        suffix = ".exe" if sys.platform.startswith("win") else ""
        for candidate in (folder / "Rerun.app" / "Contents" / "MacOS" / "Rerun", folder / f"rerun{suffix}"):
            if candidate.is_file():
                return str(candidate)
    return shutil.which("rerun")


def no_display_reason(environ: dict[str, str] | None = None) -> str | None:
    """Why a native window cannot open here (a Linux machine without X11 or Wayland), or None."""
    env = os.environ if environ is None else environ
    if not sys.platform.startswith("linux"):
        return None
    if env.get("DISPLAY") or env.get("WAYLAND_DISPLAY") or env.get("WAYLAND_SOCKET"):
        return None
    return "no display here ($DISPLAY and $WAYLAND_DISPLAY are not set), so the native viewer cannot open"


def rerun_env(config_root: Path | None = None) -> dict[str, str]:
    """The environment for a Rerun program: this one, with a Rerun configuration folder whose
    analytics are disabled (created on first use with Rerun's own ``rerun analytics disable``)."""
    root = config_root or cache_dir() / "rerun-config"
    env = {**os.environ, "XDG_CONFIG_HOME": str(root), "RERUN_APP_ONLY": "true"}
    settings = root / "rerun" / "analytics.json"
    if not _analytics_disabled(settings):
        executable = viewer_executable()
        if executable is None:
            raise ViewerUnavailable("the `rerun` program is not installed (it comes with rerun-sdk)")
        try:
            root.mkdir(parents=True, exist_ok=True)
            done = subprocess.run([executable, "analytics", "disable"], env=env, stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60, check=False)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ViewerUnavailable(f"could not prepare Rerun's configuration folder {root} ({exc})") from None
        if done.returncode != 0 or not _analytics_disabled(settings):
            raise ViewerUnavailable(f"could not turn Rerun's analytics off in {root} (rerun exited with "
                                    f"code {done.returncode}); not starting a Rerun program with them on")
    return env


def _analytics_disabled(settings: Path) -> bool:
    import json

    try:
        return json.loads(settings.read_text()).get("analytics_enabled") is False
    except (OSError, ValueError, AttributeError):
        return False


def port_is_free(address: str, port: int) -> bool:
    """True if nothing listens on ``address:port`` (and this process may bind it)."""
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((address, port))
        except OSError:
            return False
    return True


def free_port(address: str = "127.0.0.1", avoid: set[int] | None = None) -> int:
    """A TCP port nothing listens on at ``address``, chosen by the kernel (not one of ``avoid``)."""
    family = socket.AF_INET6 if ":" in address else socket.AF_INET
    while True:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.bind((address, 0))
            port = int(probe.getsockname()[1])
        if port not in (avoid or set()):
            return port


def accepts_connections(port: int, host: str = "127.0.0.1", timeout: float = 0.2) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


@dataclass
class Started:
    """A Rerun program lostx started: its process, and where its output went."""

    process: subprocess.Popen
    log: Path

    def stop(self, grace: float = 3.0) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(grace)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.unlink(missing_ok=True)


def start(args: list[str], port: int, what: str, *, tied: bool, env: dict[str, str] | None = None,
          timeout: float = START_TIMEOUT, settle: float = 0.0) -> Started:
    """Run ``rerun ARGS`` and wait until it listens on 127.0.0.1:``port`` (and is still running
    ``settle`` seconds later).

    ``tied``: the program ends with this process (it serves nothing once lostx is gone);
    otherwise it is detached, like a window the user closes when done.
    Raises :class:`ViewerUnavailable` with the program's own last words when it exits, or
    does not listen, within ``timeout`` seconds.
    """
    executable = viewer_executable()
    if executable is None:
        raise ViewerUnavailable(f"the {what} cannot start: the `rerun` program is not installed (it comes with rerun-sdk)")
    env = env if env is not None else rerun_env()
    handle, log_name = tempfile.mkstemp(prefix="lostx-rerun-", suffix=".log")
    log = Path(log_name)
    with os.fdopen(handle, "w") as out:
        process = subprocess.Popen([executable, *args], env=env, stdin=subprocess.DEVNULL, stdout=out,
                                   stderr=subprocess.STDOUT, start_new_session=not tied,
                                   preexec_fn=_parent_death_signal() if tied else None)
    started = Started(process, log)
    deadline = time.monotonic() + timeout
    while not accepts_connections(port):
        if process.poll() is not None:
            reason = last_words(log)
            started.stop()
            raise ViewerUnavailable(f"the {what} did not start ({reason or f'exit code {process.returncode}'})")
        if time.monotonic() > deadline:
            reason = last_words(log)
            started.stop()
            raise ViewerUnavailable(f"the {what} did not start within {timeout:.0f} s"
                                    + (f" ({reason})" if reason else ""))
        time.sleep(0.05)
    settled = time.monotonic() + settle
    while time.monotonic() < settled:
        if process.poll() is not None:
            reason = last_words(log)
            started.stop()
            raise ViewerUnavailable(f"the {what} did not start ({reason or f'exit code {process.returncode}'})")
        time.sleep(0.05)
    # The program keeps its output file open; its name is not needed any more.
    log.unlink(missing_ok=True)
    return started


def _parent_death_signal():
    """A function for the child to run before exec so that it gets SIGTERM when its parent dies,
    even by SIGKILL (Linux; None elsewhere). The C function is looked up here, in the parent:
    the forked child of a threaded process should only call, not load."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    PR_SET_PDEATHSIG = 1

    def set_signal() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))

    return set_signal


def last_words(log: Path, limit: int = 240) -> str:
    """The most telling line a Rerun program wrote: its error, else its last line (colour codes removed)."""
    import re

    try:
        text = log.read_text(errors="replace")
    except OSError:
        return ""
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in text.splitlines()]
    lines = [line for line in lines if line]
    errors = [line for line in lines if line.startswith("Error") or " ERROR " in line]
    chosen = (errors or lines or [""])[-1]
    return chosen if len(chosen) <= limit else chosen[: limit - 1] + "…"


def spawn_viewer(port: int, memory_limit: str) -> Started | None:
    """Start the native viewer listening on 127.0.0.1:``port``; None where one already listens there
    (it is used as it is). Raises :class:`ViewerUnavailable` where no window can open."""
    reason = no_display_reason()
    if reason is not None:
        raise ViewerUnavailable(reason)
    if accepts_connections(port):
        return None
    # The viewer listens before it opens its window; a window that cannot open ends it a moment later.
    return start(["--port", str(port), "--bind", "127.0.0.1", "--memory-limit", memory_limit, "--expect-data-soon"],
                 port, "native viewer", tied=False, settle=WINDOW_SETTLE)

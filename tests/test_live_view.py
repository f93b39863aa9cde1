"""The live view as a user starts it: ``--web`` served on loopback with no outside calls,
results written before the viewer is served, a clean end on SIGTERM and Ctrl-C, and a
native viewer that cannot start said in one line while the command goes on.

These start real ``lostx`` processes and read what they print; the web viewer is fetched
over HTTP (no browser needed) and the listening sockets are read from /proc.
"""

from __future__ import annotations

import csv
import ipaddress
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

rr = pytest.importorskip("rerun")

from lostx.cli import main  # noqa: E402
from lostx.options import VIEWER_NOTICE  # noqa: E402
from lostx.stream.processes import lostx_command  # noqa: E402
from lostx.viz.rerun_app import ALTERNATIVES, no_display_reason, rerun_env, viewer_executable  # noqa: E402
from lostx.viz.web import content_policy, host_of, strip_outside_fonts  # noqa: E402

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads listening sockets from /proc")


# -- helpers -----------------------------------------------------------------------------------------


class Output:
    """Lines a process writes to one stream, read on a thread so that nothing blocks."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._queue: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            self._queue.put(line.rstrip("\n"))
        self._queue.put(None)

    def wait_for(self, text: str, timeout: float) -> str:
        """The first line containing ``text``; fails with everything read so far after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        for line in self.lines:
            if text in line:
                return line
        while time.monotonic() < deadline:
            try:
                line = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            if line is None:
                break
            self.lines.append(line)
            if text in line:
                return line
        raise AssertionError(f"no line with {text!r} within {timeout} s; got:\n" + "\n".join(self.lines))


def start(args: list[str], env: dict[str, str]) -> tuple[subprocess.Popen, Output, Output]:
    proc = subprocess.Popen(lostx_command(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL, env=env)
    return proc, Output(proc.stdout), Output(proc.stderr)


def process_tree(pid: int) -> set[int]:
    """``pid`` and all its descendants."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    tree, frontier = {pid}, [pid]
    while frontier:
        parent = frontier.pop()
        children = [child for child, ppid in parents.items() if ppid == parent and child not in tree]
        tree.update(children)
        frontier.extend(children)
    return tree


def listening(pids: set[int]) -> list[tuple[str, int]]:
    """(address, port) of every TCP socket the processes listen on."""
    inodes: set[str] = set()
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                target = os.readlink(fd)
                if target.startswith("socket:["):
                    inodes.add(target[8:-1])
        except OSError:
            continue
    found = []
    for table, width in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            if state != "0A" or inode not in inodes:  # 0A: LISTEN
                continue
            hex_address, hex_port = local.split(":")
            raw = bytes.fromhex(hex_address)
            # /proc prints the address as 32-bit words in host byte order.
            words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4)) if sys.byteorder == "little" else raw
            found.append((str(ipaddress.ip_address(words if width == 16 else words[:4])), int(hex_port, 16)))
    return found


def fetch(url: str) -> tuple[int, dict[str, str], bytes]:
    with urllib.request.urlopen(url, timeout=30) as response:
        return response.status, dict(response.headers), response.read()


def check_web_viewer(url: str, pids: set[int]) -> None:
    """The page answers on loopback, keeps the browser on this machine, and nothing listens beyond loopback."""
    parts = urlsplit(url)
    assert parts.hostname == "127.0.0.1"
    status, headers, page = fetch(url)
    assert status == 200 and headers["Content-Type"].startswith("text/html")
    assert b"re_viewer.js" in page and b"fonts.googleapis.com" not in page and b"fonts.gstatic.com" not in page
    recording = urlsplit(unquote(parts.query.split("url=", 1)[1]).replace("rerun+http", "http"))
    assert f"connect-src 'self' http://127.0.0.1:{recording.port} " in headers["Content-Security-Policy"]
    status, headers, script = fetch(f"{parts.scheme}://{parts.netloc}/re_viewer.js")
    assert status == 200 and len(script) > 10_000 and "Content-Security-Policy" in headers
    sockets = listening(pids)
    assert {parts.port, recording.port} <= {port for _, port in sockets}
    assert all(ipaddress.ip_address(address).is_loopback for address, _ in sockets), sockets


@pytest.fixture
def env(tmp_path) -> dict[str, str]:
    """A child's environment with its own cache (reference thumbnails, Rerun's configuration folder)."""
    return {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}


def verify_rrd(path: Path) -> subprocess.CompletedProcess:
    """Rerun's own check of a recording; it fails on a file without its footer."""
    return subprocess.run([viewer_executable(), "rrd", "verify", str(path)], capture_output=True, text=True,
                          timeout=60, env=rerun_env(path.parent / "rerun-config"))


# -- match --web -------------------------------------------------------------------------------------


@linux_only
def test_match_web_writes_its_results_then_serves_on_loopback_until_sigterm(day_map, robotcar, tmp_path, env):
    out, rrd = tmp_path / "m.csv", tmp_path / "m.rrd"
    proc, stdout, stderr = start(["match", str(day_map.path), str(robotcar / "night"), "--out", str(out),
                                  "--rrd", str(rrd), "--web", "--web-port", "0", "--grpc-port", "0", "--quiet"], env)
    try:
        line = stderr.wait_for("serving the web viewer at ", timeout=180)
        url = line.split(" at ", 1)[1].split()[0]
        # The results come first: the CSV is complete and the summary printed while the viewer is served.
        assert len(list(csv.DictReader(open(out)))) == 10
        stdout.wait_for("matched 10 queries", timeout=5)
        check_web_viewer(url, process_tree(proc.pid))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    done = verify_rrd(rrd)
    assert done.returncode == 0, done.stdout + done.stderr
    with pytest.raises(OSError):
        fetch(url)


@linux_only
def test_sigterm_while_matching_leaves_a_complete_recording(day_map, tmp_path, env):
    # A longer run, stopped half way (a background job gets SIGTERM, not Ctrl-C): the .rrd gets its footer.
    rrd = tmp_path / "half.rrd"
    proc, _, stderr = start(["match", str(day_map.path), str(robotcar_like_queries(tmp_path, 60)), "--out",
                             str(tmp_path / "half.csv"), "--rrd", str(rrd), "--quiet"], env)
    try:
        stderr.wait_for(f"{VIEWER_NOTICE}recording to", timeout=120)
        deadline = time.monotonic() + 120
        while (not rrd.exists() or rrd.stat().st_size < 200_000) and time.monotonic() < deadline:
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    stderr.wait_for("lostx: interrupted", timeout=5)
    done = verify_rrd(rrd)
    assert done.returncode == 0, done.stdout + done.stderr


@linux_only
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
def test_every_stop_signal_to_lostx_alone_ends_the_web_viewer_with_it(day_map, robotcar, tmp_path, env, stop):
    # Started as a script's background job is: with SIGINT ignored. The signal goes to lostx's pid only, not to
    # its process group, so nothing but lostx itself can end the web viewer's file server. SIGHUP as a terminal
    # leaves it, whatever the test run inherited (under nohup lostx rightly keeps a SIGHUP ignored).
    rrd = tmp_path / "m.rrd"

    def background_job() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)

    proc = subprocess.Popen(lostx_command("match", str(day_map.path), str(robotcar / "night"), "--out",
                                          str(tmp_path / "m.csv"), "--rrd", str(rrd), "--web", "--web-port", "0",
                                          "--grpc-port", "0", "--quiet"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            env=env, preexec_fn=background_job)
    stderr = Output(proc.stderr)
    Output(proc.stdout)
    try:
        stderr.wait_for("serving the web viewer at ", timeout=180)
        tree = process_tree(proc.pid)
        ports = {port for _, port in listening(tree)}
        assert len(tree) == 2 and len(ports) == 3  # the file server; the page, the recording, the files
        proc.send_signal(stop)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 10
    while any(Path(f"/proc/{pid}").exists() for pid in tree) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(Path(f"/proc/{pid}").exists() for pid in tree), "the web viewer's process outlived lostx"
    for port in ports:
        with pytest.raises(OSError):
            fetch(f"http://127.0.0.1:{port}/")
    done = verify_rrd(rrd)  # the recording was closed, as on Ctrl-C
    assert done.returncode == 0, done.stdout + done.stderr


def robotcar_like_queries(tmp_path: Path, n: int) -> Path:
    """A folder of ``n`` query images: the ten RobotCar night frames, repeated (links, no copies)."""
    from lostx.core.paths import data_dir

    night = sorted((data_dir() / "robotcar-daynight" / "night").glob("*.png"))
    folder = tmp_path / "queries"
    folder.mkdir()
    for i in range(n):
        (folder / f"{i:05d}.png").symlink_to(night[i % len(night)])
    return folder


# -- demo --web --------------------------------------------------------------------------------------


@linux_only
def test_demo_web_prints_its_url_summary_and_serves_until_ctrl_c(tmp_path, env):
    # No display here: the demo's service cannot open a native viewer and says so; the web viewer serves.
    env = {k: v for k, v in env.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}
    proc, stdout, _ = start(["demo", "--workdir", str(tmp_path / "demo"), "--viewer", "--web",
                             "--web-port", "0", "--grpc-port", "0"], env)
    tree = {proc.pid}
    try:
        line = stdout.wait_for("serving the web viewer at ", timeout=300)
        url = line.split(" at ", 1)[1].split()[0]
        text = "\n".join(stdout.lines)
        # The summary before the serving (the demo's service is lossless: every frame is answered).
        assert "night -> day (answered 10 of 10" in text and "sequence filter:" in text
        assert f"{VIEWER_NOTICE}web viewer at {url}" in text
        notice = [line for line in stdout.lines if "no display here" in line]
        assert len(notice) == 1 and notice[0].startswith(VIEWER_NOTICE) and ALTERNATIVES in notice[0]
        tree = process_tree(proc.pid)
        check_web_viewer(url, tree)
        time.sleep(1.0)
        fetch(url)  # still serving after the last answer
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    deadline = time.monotonic() + 10
    while any(Path(f"/proc/{pid}").exists() for pid in tree - {proc.pid}) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(Path(f"/proc/{pid}").exists() for pid in tree - {proc.pid}), "a child outlived the demo"


# -- a native viewer that cannot start ---------------------------------------------------------------


@pytest.mark.parametrize("display", [None, ":8571"], ids=["no-display", "display-without-server"])
def test_viewer_that_cannot_start_is_one_line_and_the_results_are_written(day_map, robotcar, tmp_path, monkeypatch,
                                                                          capsys, display):
    if not sys.platform.startswith("linux"):
        pytest.skip("Linux decides here whether a window can open")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    if display is not None:
        monkeypatch.setenv("DISPLAY", display)  # an X display nobody serves: the viewer starts and fails
    out = tmp_path / "m.csv"
    start_s = time.monotonic()
    assert main(["match", str(day_map.path), str(robotcar / "night"), "--out", str(out), "--viewer", "--quiet"]) == 0
    assert time.monotonic() - start_s < 60
    captured = capsys.readouterr()
    notes = [line for line in captured.err.splitlines() if line.startswith(VIEWER_NOTICE)]
    assert len(notes) == 1 and notes[0].endswith(ALTERNATIVES), captured.err
    if display is None:
        assert "no display here" in notes[0]
    else:
        assert "the native viewer did not start (" in notes[0] and "Traceback" not in captured.err
    assert len(list(csv.DictReader(open(out)))) == 10
    assert "matched 10 queries" in captured.out


def test_no_display_is_known_from_the_environment():
    if not sys.platform.startswith("linux"):
        assert no_display_reason({}) is None
        return
    assert "no display here" in no_display_reason({})
    assert no_display_reason({"DISPLAY": ":0"}) is None and no_display_reason({"WAYLAND_DISPLAY": "wayland-0"}) is None


# -- telemetry and the web page's policy ---------------------------------------------------------------


def test_rerun_programs_run_with_analytics_off(tmp_path):
    root = tmp_path / "config"
    env = rerun_env(root)
    assert env["XDG_CONFIG_HOME"] == str(root)
    settings = json.loads((root / "rerun" / "analytics.json").read_text())
    assert settings["analytics_enabled"] is False
    shown = subprocess.run([viewer_executable(), "analytics", "config"], env=env, capture_output=True, text=True,
                           timeout=60)
    assert json.loads(shown.stdout)["analytics_enabled"] is False
    mtime = (root / "rerun" / "analytics.json").stat().st_mtime_ns
    rerun_env(root)  # already off: left as it is
    assert (root / "rerun" / "analytics.json").stat().st_mtime_ns == mtime


def test_web_page_policy_keeps_the_browser_on_this_machine():
    policy = content_policy("192.168.1.5", 9877)
    directives = dict(part.strip().split(" ", 1) for part in policy.split(";"))
    assert directives["connect-src"].split() == ["'self'", "http://192.168.1.5:9877", "http://127.0.0.1:9877",
                                                 "http://localhost:9877"]
    assert directives["default-src"] == "'self'" and directives["font-src"] == "'self' data:"
    assert "https:" not in policy and "*" not in policy
    page = (b'<head><link rel="preconnect" href="https://fonts.googleapis.com" />\n<link\n  '
            b'href="https://fonts.googleapis.com/css2?family=Inter" rel="stylesheet"\n/><link rel="icon" '
            b'href="favicon.ico"></head>')
    assert strip_outside_fonts(page) == b'<head>\n<link rel="icon" href="favicon.ico"></head>'
    assert host_of("127.0.0.1:9090") == "127.0.0.1" and host_of("[::1]:9090") == "[::1]" and host_of(None) == "127.0.0.1"


def test_the_recording_is_readable_only_by_the_web_viewers_own_page():
    from lostx.viz.output import page_origins

    assert page_origins("127.0.0.1", 9090) == ["http://127.0.0.1:9090", "http://localhost:9090"]
    assert page_origins("192.168.1.5", 8000) == ["http://192.168.1.5:8000", "http://127.0.0.1:8000",
                                                  "http://localhost:8000"]
    assert page_origins("0.0.0.0", 9090) == ["http://*:9090"]  # any address of this machine, that port only


def test_web_address_must_be_an_ip_address(day_map, robotcar, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["match", str(day_map.path), str(robotcar / "night"), "--out", str(tmp_path / "m.csv"), "--web", "map"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --web: 'map' is not an IP address to listen on" in err and "Traceback" not in err
    assert not (tmp_path / "m.csv").exists()

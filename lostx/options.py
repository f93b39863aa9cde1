"""Command-line options shared by several commands, and turning them into a :class:`Config`."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import re
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.core.backbones.presets import PRESETS
from lostx.core.config import LIMITS, Config, load_config

DEFAULTS = Config()

if TYPE_CHECKING:
    from lostx.core.backbones.base import BackboneInfo
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.viz.sink import RerunSink


def whole_number(minimum: int = 1, maximum: int | None = None):
    """argparse ``type``: an integer of at least ``minimum`` (and at most ``maximum``), or a one-line error naming
    the value and the range."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            allowed = f"between {minimum} and {maximum}" if maximum is not None else f"at least {minimum}"
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {value}")
        return value

    return parse


def number(minimum: float = 0.0, above: bool = False, maximum: float | None = None):
    """argparse ``type``: a finite number of at least ``minimum`` (or above it, with ``above``; and at most
    ``maximum``)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if (not math.isfinite(value) or value < minimum or (above and value == minimum)
                or (maximum is not None and value > maximum)):
            allowed = f"{'above' if above else 'at least'} {minimum:g}"
            if maximum is not None:
                allowed += f" and at most {maximum:g}"
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text}")
        return value

    return parse


MAX_FPS = 1000.0
"""Frames per second of recorded time that ``--fps`` may keep (beyond any camera's rate)."""


def _most(section: str, key: str) -> int:
    """The largest valid value of a whole-number setting (lostx.core.config.LIMITS): options and files agree."""
    return int(LIMITS[section][key].high)  # type: ignore[arg-type]


window_length = whole_number(1, _most("sequence", "length"))
"""argparse ``type`` of a sequence window's length in frames."""

MEMORY = re.compile(r"^\d+(\.\d+)?\s*(%|B|kB|KB|MB|GB|TB|KiB|MiB|GiB|TiB)?$")


def memory_limit(text: str) -> str:
    """argparse ``type``: a memory limit as Rerun takes it (``4GiB``, ``500MB``, ``25%``)."""
    if not MEMORY.match(text.strip()) or (text.strip().endswith("%") and not 0 < float(text.strip()[:-1]) <= 100):
        raise argparse.ArgumentTypeError(f"expected an amount such as 4GiB, 500MB or 25%, got {text!r}")
    return text.strip()


def add_backbone_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("backbone")
    group.add_argument("--backbone", help="semantic backbone: a name from `lostx backbones`, a plugin's name, or "
                                          "package.module:factory")
    group.add_argument("--model", type=Path, help="model file of the backbone (default: in ../shared/models); for "
                                                   "tflite and onnx, the model's .toml description or the model "
                                                   "with it beside")
    group.add_argument("--device", help=f"auto, cpu, cuda or cuda:N (PyTorch and ONNX backbones; default "
                                        f"{DEFAULTS.backbone.device})")
    group.add_argument("--threads", type=whole_number(1, _most("backbone", "threads")), metavar="N",
                       help=f"CPU threads for the network (default {DEFAULTS.backbone.threads})")
    group.add_argument("--class-preset", choices=sorted(PRESETS),
                       help="descriptor classes by name: street (road, building, vegetation) or indoor (wall, floor, "
                            "ceiling); default: the backbone's own")


def add_config_options(parser: argparse.ArgumentParser, matching: bool = True) -> None:
    """``--config`` and the backbone options; with ``matching``, also the options of the matching stages."""
    parser.add_argument("--config", type=Path, help="TOML file of settings (see docs/config.md)")
    add_backbone_options(parser)
    if not matching:
        return
    group = parser.add_argument_group("matching")
    group.add_argument("--scoring", choices=["eq4-lost", "eq4", "released"], help="verification score")
    group.add_argument("--top-k", type=whole_number(1), metavar="K",
                       help=f"candidates verified per query (default {DEFAULTS.verify.top_k})")
    group.add_argument("--window", type=window_length, metavar="L",
                       help=f"frames in the sequence filter's window (default {DEFAULTS.sequence.length}); refused "
                            f"before any work, naming the largest that fits, where its memory would not fit")
    group.add_argument("--no-tracker", action="store_true", help="answer without the route tracker")
    group.add_argument("--index", choices=["auto", "on", "off"],
                       help="search the map's approximate index: auto (default: maps of at least "
                       f"{DEFAULTS.search.index_min_frames} frames), on (any size), off (compare every frame)")


def config_from_args(args: argparse.Namespace) -> Config:
    config = load_config(getattr(args, "config", None))
    backbone = config.backbone
    for field, option in (("name", "backbone"), ("model_path", "model"), ("device", "device"), ("threads", "threads")):
        value = getattr(args, option, None)
        if value is not None:
            backbone = dataclasses.replace(backbone, **{field: value})
    lost = config.lost
    if getattr(args, "class_preset", None):
        # On the command line the preset overrides the classes of a --config file.
        lost = dataclasses.replace(lost, class_preset=args.class_preset, classes=None)
    verify = config.verify
    if getattr(args, "scoring", None):
        verify = dataclasses.replace(verify, scoring=args.scoring)
    if getattr(args, "top_k", None) is not None:
        verify = dataclasses.replace(verify, top_k=args.top_k)
    sequence, tracker = config.sequence, config.tracker
    if getattr(args, "window", None) is not None:
        sequence = dataclasses.replace(sequence, length=args.window)
    if getattr(args, "no_tracker", False):
        tracker = dataclasses.replace(tracker, enabled=False)
    search = config.search
    if getattr(args, "index", None):
        search = dataclasses.replace(search, index=args.index)
    return dataclasses.replace(config, backbone=backbone, lost=lost, verify=verify, search=search, sequence=sequence,
                               tracker=tracker)


class IgnoredSettingWarning(UserWarning):
    """A setting that does not act in this command (shown as one ``lostx: warning:`` line)."""


def ignored_classes_note(args: argparse.Namespace, config: Config, refmap: ReferenceMap,
                         info: BackboneInfo | None) -> str | None:
    """Why the descriptor classes asked for (``--class-preset``, or ``[lost]`` of a --config file) are not used
    against ``refmap``, whose backbone is described by ``info``: a map is matched with the classes it was built
    with. None where none were asked for, or they are the map's own."""
    lost = config.lost
    built = refmap.manifest.get("classes")
    if info is None or built is None or not (lost.classes or lost.class_preset):
        return None
    from lostx.core.describe.describer import descriptor_classes

    asked = descriptor_classes(lost, info)
    if {name: list(members) for name, members in asked.items()} == built:
        return None
    if getattr(args, "class_preset", None):
        setting = f"--class-preset {args.class_preset}"
    else:
        setting = f"[lost] {'classes' if lost.classes else 'class_preset'} in {getattr(args, 'config', None)}"
    return (f"{setting} is ignored: {refmap.path} was built with the classes {', '.join(built)}, and a map is "
            f"matched with its own (build the map with these classes to use them)")


SOURCE_FORMATS = ("folder", "robotcar", "bag", "video", "nuscenes")


CAMERA_FILE_HELP = ("the camera's intrinsics and mounting (a TOML camera file, see docs/datasets.md), in place of "
                    "the source's own calibration or a camera.toml beside its frames")


def add_source_options(parser: argparse.ArgumentParser, *, format: bool = True, reverse: bool = False,
                       camera_file: bool = True) -> None:
    """How to read a traverse: its format, a bag's topics, a nuScenes scene, which frames, the camera's
    geometry (docs/datasets.md)."""
    group = parser.add_argument_group("source (see docs/datasets.md)")
    if format:
        group.add_argument("--format", choices=SOURCE_FORMATS, help="the source's format (default: recognised)")
    if camera_file:
        group.add_argument("--camera-file", type=Path, metavar="PATH", help=CAMERA_FILE_HELP)
    group.add_argument("--topic", help="bag: the image topic (sensor_msgs/Image or CompressedImage; "
                       "default: the bag's only one)")
    group.add_argument("--pose-topic", metavar="TOPIC", help="bag: the positions topic (Odometry, PoseStamped "
                       "or NavSatFix; default: the bag's only one)")
    group.add_argument("--scene", help="nuScenes: the scene, e.g. scene-0523 (default: the only one with images)")
    group.add_argument("--channel", help="nuScenes: the camera channel at a dataset root (default CAM_FRONT)")
    group.add_argument("--look-at", type=float, nargs="?", const=15.0, metavar="M",
                       help="nuScenes: positions M metres along the camera's heading (default 15) instead of "
                            "the vehicle's")
    frames = group.add_mutually_exclusive_group()
    frames.add_argument("--every", type=whole_number(1), metavar="N", help="keep every N-th frame")
    frames.add_argument("--fps", type=number(0.0, above=True, maximum=MAX_FPS), metavar="F",
                        help=f"keep F frames per second of recorded time (at most {MAX_FPS:g})")
    if reverse:
        group.add_argument("--reverse", action="store_true", help="the frames in reverse order, timestamps "
                           "reflected: the route driven the other way")


def source_options_from_args(args: argparse.Namespace):
    """The :class:`~lostx.replay.dataset.SourceOptions` the command line gives."""
    from lostx.replay.dataset import SourceOptions

    return SourceOptions(topic=args.topic, pose_topic=args.pose_topic, scene=args.scene, channel=args.channel,
                         look_at=args.look_at, every=args.every, fps=args.fps,
                         camera_file=getattr(args, "camera_file", None))


def print_notes(notes: list[str]) -> None:
    """What the readers skipped or assumed, one line each."""
    for note in notes:
        print(f"note: {note}")


def add_stream_options(parser: argparse.ArgumentParser) -> None:
    """Settings of the service (``[stream]`` in a --config file; these override it)."""
    group = parser.add_argument_group("stream (see docs/protocol.md)")
    group.add_argument("--frames", metavar="ENDPOINT",
                       help="bind the frames socket here (default tcp://127.0.0.1:5555)")
    group.add_argument("--results", metavar="ENDPOINT",
                       help="bind the results socket here (default tcp://127.0.0.1:5556)")
    group.add_argument("--mode", choices=["live", "lossless"],
                       help="live: newest frame first, drop the rest (default); lossless: answer every frame in order")
    group.add_argument("--credit", type=int, metavar="N", help="lossless: unanswered frames per producer (default 4)")
    group.add_argument("--wait-listeners", type=int, metavar="N",
                       help="hold producers back until N listeners subscribe (lossless: at least 1)")
    group.add_argument("--max-message-bytes", type=int, metavar="BYTES", help="largest frame message (default 16 MiB)")
    group.add_argument("--stats-interval", type=float, metavar="S", help="seconds between stats messages (default 1)")
    group.add_argument("--max-streams", type=int, metavar="N",
                       help=f"streams (a localizer state each) at one time, at most {_most('stream', 'max_streams')} "
                            f"(default {DEFAULTS.stream.max_streams}): a frame starting one more is refused "
                            f"(too_many_streams) unless an idle stream has expired; a producer holding "
                            f"{DEFAULTS.stream.max_streams_per_peer} ([stream] max_streams_per_peer) that starts "
                            f"another forgets its least recently used idle one. Refused at start-up where their "
                            f"memory would not fit")
    group.add_argument("--stream-expiry", type=float, metavar="S",
                       help="forget a stream after S seconds without a frame (default 300)")
    journal = parser.add_argument_group("journal (lossless mode needs one, or --no-journal)")
    choice = journal.add_mutually_exclusive_group()
    choice.add_argument("--journal", type=Path, metavar="DIR",
                        help="write every answer to the journal in DIR before acknowledging its frame; "
                             "listeners resume from it (lostx listen --resume), a restarted service carries every "
                             "stream on; while its disk is full, frames are refused (journal_unwritable)")
    choice.add_argument("--no-journal", action="store_true",
                        help="lossless without a journal: answers a listener had not read when it died are lost")
    journal.add_argument("--history", metavar="ENDPOINT",
                         help="bind the history socket (journaled answers for listeners) here "
                              "(default: the results port plus one)")


def add_client_key_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("CurveZMQ (for a service started with --curve-secret)")
    group.add_argument("--curve-server", type=Path, metavar="FILE", help="the service's public key (.key)")
    group.add_argument("--curve-secret", type=Path, metavar="FILE", help="this client's secret key (.key_secret)")


def client_keys_from_args(args: argparse.Namespace):
    """ClientKeys, or None without CurveZMQ options; both files are needed together."""
    from lostx.core.errors import InputError
    from lostx.stream.sockets import ClientKeys

    server, secret = getattr(args, "curve_server", None), getattr(args, "curve_secret", None)
    if server is None and secret is None:
        return None
    if server is None or secret is None:
        raise InputError("CurveZMQ needs both --curve-server (the service's .key) and --curve-secret (yours)")
    return ClientKeys(server, secret)


def stream_config_from_args(args: argparse.Namespace, config: Config) -> Config:
    """``config`` with the stream settings given on the command line applied."""
    changes = {
        name: getattr(args, name, None)
        for name in ("frames", "results", "mode", "wait_listeners", "max_message_bytes", "stats_interval",
                     "max_streams", "stream_expiry", "journal", "history")
    }
    changes["window"] = getattr(args, "credit", None)
    stream = dataclasses.replace(config.stream, **{k: v for k, v in changes.items() if v is not None})
    if getattr(args, "no_journal", False):
        stream = dataclasses.replace(stream, journal=None)
    return dataclasses.replace(config, stream=stream)


def add_viewer_options(parser: argparse.ArgumentParser) -> None:
    """The live view's options: where the Rerun recording goes, and how much of it."""
    from lostx.viz.target import DEFAULT_CONNECT, DEFAULT_MEMORY_LIMIT, DEFAULT_WEB_ADDRESS, GRPC_PORT, WEB_PORT

    group = parser.add_argument_group("live view (Rerun; see docs/viewer.md)")
    group.add_argument("--viewer", action="store_true",
                       help="open the native Rerun viewer and stream to it (needs a display)")
    group.add_argument("--connect", nargs="?", const=DEFAULT_CONNECT, metavar="URL",
                       help=f"stream to a running Rerun viewer (default URL {DEFAULT_CONNECT})")
    group.add_argument("--rrd", type=Path, metavar="FILE", help="record to an .rrd file (open it with `rerun FILE`)")
    group.add_argument("--web", nargs="?", const=DEFAULT_WEB_ADDRESS, metavar="ADDRESS", type=_web_address,
                       help=f"serve the web viewer and print its URL; it listens on {DEFAULT_WEB_ADDRESS} unless "
                            f"given an address (0.0.0.0: every interface, for other machines)")
    group.add_argument("--web-port", type=whole_number(0, 65535), default=WEB_PORT, metavar="PORT",
                       help=f"port of the web viewer's page (default {WEB_PORT}; 0: a free one)")
    group.add_argument("--grpc-port", type=whole_number(0, 65535), default=GRPC_PORT, metavar="PORT",
                       help=f"port the web viewer reads the recording from (default {GRPC_PORT}; 0: a free one)")
    group.add_argument("--viewer-rate", type=number(0.0), default=10.0, metavar="HZ",
                       help="most frames per second whose images, label maps, lines and sequence window are logged "
                            "(the rest of the view is logged every frame; 0: every frame; default 10)")
    group.add_argument("--viewer-memory", type=memory_limit, default=DEFAULT_MEMORY_LIMIT, metavar="LIMIT",
                       help=f"memory limit of the native viewer and the web viewer's recording buffer, e.g. 4GiB or 25%% "
                            f"(oldest data dropped first; default {DEFAULT_MEMORY_LIMIT})")


def _web_address(value: str) -> str:
    import ipaddress

    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not an IP address to listen on (e.g. 127.0.0.1 or 0.0.0.0)") \
            from None


def viewer_notice(message: str) -> None:
    """One line about the live view on stderr (``lostx demo`` repeats its service's lines that start so)."""
    print(f"{VIEWER_NOTICE}{message}", file=sys.stderr, flush=True)


VIEWER_NOTICE = "lostx: live view: "


def viewer_sink_from_args(args: argparse.Namespace, refmap: ReferenceMap) -> RerunSink | None:
    """A Rerun sink for the destinations the options name; None where they name none, or where none of
    them can be had (a native viewer without a display: said in one line, and the command goes on)."""
    from lostx.viz.target import DEFAULT_MEMORY_LIMIT, DEFAULT_WEB_ADDRESS, GRPC_PORT, WEB_PORT, ViewerOutput

    output = ViewerOutput(
        spawn=bool(getattr(args, "viewer", False)),
        connect=getattr(args, "connect", None),
        rrd=getattr(args, "rrd", None),
        web=getattr(args, "web", None) is not None,
        web_address=getattr(args, "web", None) or DEFAULT_WEB_ADDRESS,
        memory_limit=getattr(args, "viewer_memory", None) or DEFAULT_MEMORY_LIMIT,
        web_port=getattr(args, "web_port", WEB_PORT),
        grpc_port=getattr(args, "grpc_port", GRPC_PORT),
    )
    if not output.any:
        return None
    from lostx.viz.rerun_app import ALTERNATIVES, no_display_reason

    reason = no_display_reason() if output.spawn else None
    if reason is not None:
        # Known before anything starts: no window, and no Rerun recording just for it.
        viewer_notice(f"{reason}; {ALTERNATIVES}")
        output = dataclasses.replace(output, spawn=False)
        if not output.any:
            return None
    from lostx.viz.sink import RerunSink, SinkSettings  # imports Rerun: only when a view is asked for

    rate = getattr(args, "viewer_rate", None)
    sink = RerunSink(refmap, output, SinkSettings(heavy_hz=rate if rate and rate > 0 else None))
    for message in sink.opened.messages:
        viewer_notice(message)
    if sink.opened.destinations == 0:
        sink.close()
        return None
    return sink


def viewer_args(args: argparse.Namespace) -> list[str]:
    """The viewer options of ``args`` as a command line, for a child process that does the logging."""
    out: list[str] = []
    if getattr(args, "viewer", False):
        out.append("--viewer")
    if getattr(args, "connect", None):
        out += ["--connect", str(args.connect)]
    if getattr(args, "rrd", None):
        out += ["--rrd", str(Path(args.rrd).resolve())]
    if getattr(args, "web", None):
        out += ["--web", str(args.web), "--web-port", str(args.web_port), "--grpc-port", str(args.grpc_port)]
    if out:
        out += ["--viewer-rate", str(args.viewer_rate), "--viewer-memory", str(args.viewer_memory)]
    return out


@contextlib.contextmanager
def live_view(args: argparse.Namespace, refmap: ReferenceMap) -> Iterator[RerunSink | None]:
    """The sink of :func:`viewer_sink_from_args` for the length of a command, closed on the way out (the
    stop signals end a command through this cleanup, see :func:`stop_signals_as_interrupt`, so that an
    ``.rrd`` always gets its footer and the web viewer's process ends with lostx)."""
    sink = viewer_sink_from_args(args, refmap)
    if sink is None:
        yield None
        return
    try:
        yield sink
    finally:
        sink.close()


STOP_SIGNALS = ("SIGTERM", "SIGINT", "SIGHUP")
"""The signals that end a command the way Ctrl-C does (SIGHUP: the terminal closed)."""


@contextlib.contextmanager
def stop_signals_as_interrupt() -> Iterator[None]:
    """Each of :data:`STOP_SIGNALS` raises KeyboardInterrupt in the main thread for the duration, so that
    the cleanup written for Ctrl-C (child processes stopped, the web viewer's among them; files completed)
    runs whichever of them ends the command.

    A script's background job starts with SIGINT ignored, yet ``kill -INT PID`` names this process: it is
    honoured. A SIGHUP ignored on purpose (``nohup``) stays ignored."""

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    previous: dict[signal.Signals, object] = {}
    for name in STOP_SIGNALS:
        number = getattr(signal, name, None)
        if number is None:  # not on this platform (SIGHUP on Windows)
            continue
        if number == signal.SIGHUP and signal.getsignal(number) is signal.SIG_IGN:
            continue
        previous[number] = signal.signal(number, interrupt)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)  # type: ignore[arg-type]


def serve_until_interrupted(sink: RerunSink | None) -> None:
    """With ``--web``, keep the web viewer up until Ctrl-C (or another stop signal); the command's results are
    out already."""
    if sink is None or sink.opened.web_url is None:
        return
    sink.flush()
    viewer_notice(f"serving the web viewer at {sink.opened.web_url} until Ctrl-C")
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass

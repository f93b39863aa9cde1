"""``lostx replay SOURCE --to ENDPOINT``: play a recorded traverse into the service as a live stream."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lostx.core.errors import InputError
from lostx.options import add_client_key_options, client_keys_from_args
from lostx.replay.dataset import open_traverse
from lostx.replay.pace import Pace, check_realtime
from lostx.stream.producer import FramePublisher
from lostx.stream.protocol import MAX_NAME

LAP_SUFFIX = 16
"""Characters kept free in a stream id for the lap number of --loop (ID.1, ID.2, ...)."""
from lostx.stream.replay import replay


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("replay", help="replay a traverse into the service as a live stream")
    parser.add_argument("source", type=Path, help="the traverse: a folder of images (name order) or a RobotCar "
                        "traverse folder (see docs/datasets.md)")
    parser.add_argument("--format", choices=["folder", "robotcar"], help="the source's format (default: recognised)")
    parser.add_argument("--to", required=True, metavar="ENDPOINT",
                        help="the service's frames endpoint, e.g. tcp://127.0.0.1:5555")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, metavar="HZ", help="frames per second (default 10, or --realtime "
                      "where the traverse has timestamps)")
    pace.add_argument("--realtime", action="store_true", help="at the recorded rate (needs timestamps)")
    pace.add_argument("--as-fast-as-possible", action="store_true", help="no pacing (lossless services still "
                      "hold the replay back)")
    parser.add_argument("--loop", action="store_true", help="start over after the last frame, until Ctrl-C")
    parser.add_argument("--stream", metavar="ID", help="the stream id the frames carry (default: 8 random hex "
                        "digits); the service keeps one localizer state per stream, and a loop's laps are "
                        "ID.1, ID.2, ...")
    camera = parser.add_mutually_exclusive_group()
    camera.add_argument("--camera", choices=["front", "rear"], help="declare the direction the camera faced (default: not declared)")
    camera.add_argument("--opposite", action="store_true", help="the frames come from a rear camera "
                        "(the opposite of a front-camera map); same as --camera rear")
    parser.add_argument("--mirror", action="store_true",
                        help="flip the images left-right (a test of the flip handling, not an opposite view)")
    parser.add_argument("--positions", type=Path, metavar="CSV",
                        help="positions (and timestamps) per image, sent for evaluation only (RobotCar: the INS CSV)")
    enc = parser.add_argument_group("encoding")
    enc.add_argument("--encoding", choices=["raw", "png", "jpeg"],
                     help="raw pixels (default: exact and cheapest on one machine), png (exact), jpeg (networks)")
    enc.add_argument("--jpeg-quality", type=int, metavar="Q", help="JPEG quality 1-100 (implies --encoding jpeg; "
                     "default 90)")
    parser.add_argument("--wait", type=float, metavar="S", help="give up if no service answers within S seconds "
                        "(default: wait)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_client_key_options(parser)
    parser.set_defaults(run=run)


def open_source(path: Path, format: str | None, positions: Path | None, camera: str, mirror: bool):
    """A traverse from SOURCE through the dataset readers (any sized, re-iterable collection of Frames
    would do: the replay itself knows nothing of formats)."""
    return open_traverse(path, format, camera, positions, mirror)  # type: ignore[arg-type]


def run(args: argparse.Namespace) -> int:
    if args.jpeg_quality is not None and not 1 <= args.jpeg_quality <= 100:
        raise InputError(f"--jpeg-quality must be 1-100, got {args.jpeg_quality}")
    if args.jpeg_quality is not None and args.encoding not in (None, "jpeg"):
        raise InputError("--jpeg-quality goes with --encoding jpeg")
    if args.stream is not None and not 1 <= len(args.stream) <= MAX_NAME - LAP_SUFFIX:
        raise InputError(f"--stream must be 1 to {MAX_NAME - LAP_SUFFIX} characters, got {len(args.stream)}")
    encoding = args.encoding or ("jpeg" if args.jpeg_quality is not None else "raw")
    camera = "rear" if args.opposite else args.camera
    frames = open_source(args.source, args.format, args.positions, camera, args.mirror)
    if args.as_fast_as_possible:
        pace = Pace("unlimited")
    elif args.realtime:
        check_realtime(frames)
        pace = Pace("realtime")
    elif args.rate is not None:
        pace = Pace("rate", args.rate)
    else:
        pace = Pace("realtime") if getattr(frames, "timestamps", None) is not None else Pace("rate", 10.0)
    keys = client_keys_from_args(args)
    with FramePublisher(args.to, encoding=encoding, quality=args.jpeg_quality or 90, keys=keys, stream=args.stream,
                        name=f"lostx replay {args.source.name}") as publisher:
        if not args.quiet:
            print(f"replaying {len(frames)} frames from {args.source} to {args.to} as stream "
                  f"{publisher.stream} ({pace.describe()}, "
                  f"{encoding}{', looping' if args.loop else ''}); waiting for the service...", file=sys.stderr)
        summary = replay(frames, publisher, pace, loop=args.loop, progress=not args.quiet, wait=args.wait)
    print(summary.line())
    if summary.interrupted:
        return 130
    return 0 if summary.unanswered == 0 else 1

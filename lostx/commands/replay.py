"""``lostx replay SOURCE --to ENDPOINT``: play a recorded traverse, or a live camera, into the service."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.options import (
    add_client_key_options,
    add_source_options,
    client_keys_from_args,
    number,
    print_notes,
    source_options_from_args,
)

if TYPE_CHECKING:
    from lostx.stream.producer import FramePublisher
    from lostx.stream.replay import ReplaySummary

LAP_SUFFIX = 16
"""Characters kept free in a stream id for the lap number of --loop (ID.1, ID.2, ...)."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("replay", help="replay a traverse (or stream a camera) into the service")
    parser.add_argument("source", help="the traverse: a folder of images (name order), a RobotCar folder, a ROS 2 "
                        "bag (.mcap), a video, a nuScenes scene (see docs/datasets.md); or camera:N, a live "
                        "camera (OpenCV device N)")
    parser.add_argument("--to", required=True, metavar="ENDPOINT",
                        help="the service's frames endpoint, e.g. tcp://127.0.0.1:5555")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=number(0, above=True), metavar="HZ",
                      help="frames per second (default 10, or --realtime "
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
    parser.add_argument("--wait", type=number(0), metavar="S", help="give up if no service answers within S seconds "
                        "(default: wait)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_source_options(parser, reverse=True)
    add_client_key_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from lostx.core.errors import InputError
    from lostx.replay.camera import camera_index
    from lostx.replay.dataset import open_traverse
    from lostx.replay.pace import Pace, check_realtime
    from lostx.stream.messages import MAX_NAME
    from lostx.stream.replay import replay

    if args.jpeg_quality is not None and not 1 <= args.jpeg_quality <= 100:
        raise InputError(f"--jpeg-quality must be 1-100, got {args.jpeg_quality}")
    if args.jpeg_quality is not None and args.encoding not in (None, "jpeg"):
        raise InputError("--jpeg-quality goes with --encoding jpeg")
    if args.stream is not None and not 1 <= len(args.stream) <= MAX_NAME - LAP_SUFFIX:
        raise InputError(f"--stream must be 1 to {MAX_NAME - LAP_SUFFIX} characters, got {len(args.stream)}")
    encoding = args.encoding or ("jpeg" if args.jpeg_quality is not None else "raw")
    camera = "rear" if args.opposite else args.camera
    index = camera_index(args.source)
    if index is not None:
        return _run_camera(args, index, camera, encoding)
    source = Path(args.source)
    frames = open_traverse(source, args.format, camera, args.positions, args.mirror,
                           source_options_from_args(args))
    if args.reverse:
        frames = frames.reversed()
    print_notes(frames.notes)
    if args.as_fast_as_possible:
        pace = Pace("unlimited")
    elif args.realtime:
        check_realtime(frames)
        pace = Pace("realtime")
    elif args.rate is not None:
        pace = Pace("rate", args.rate)
    else:
        pace = Pace("realtime") if frames.timestamps is not None else Pace("rate", 10.0)
    with _publisher(args, encoding, source.name) as publisher:
        if not args.quiet:
            print(f"replaying {len(frames)} frames from {source} to {args.to} as stream {publisher.stream} "
                  f"({pace.describe()}, "
                  f"{encoding}{', looping' if args.loop else ''}); waiting for the service...", file=sys.stderr)
        summary = replay(frames, publisher, pace, loop=args.loop, progress=not args.quiet, wait=args.wait)
    return _finish(summary)


def _run_camera(args: argparse.Namespace, index: int, camera: str | None, encoding: str) -> int:
    """A live camera: its own rate, newest frame first, until Ctrl-C or the device stops."""
    from lostx.core.errors import InputError
    from lostx.replay.camera import LiveCamera
    from lostx.stream.replay import relay_live

    for_recordings = {"--rate": args.rate is not None, "--realtime": args.realtime, "--loop": args.loop,
                      "--as-fast-as-possible": args.as_fast_as_possible, "--reverse": args.reverse,
                      "--positions": args.positions is not None, "--format": args.format is not None,
                      "--every": args.every is not None, "--fps": args.fps is not None}
    misplaced = [flag for flag, given in for_recordings.items() if given]
    misplaced += source_options_from_args(args).misplaced("camera")
    if misplaced:
        raise InputError(f"camera:{index} is a live camera; {', '.join(misplaced)} "
                         f"{'is' if len(misplaced) == 1 else 'are'} for recordings only")
    geometry = None
    if args.camera_file is not None:
        from lostx.core.geometry import read_camera_file

        geometry = read_camera_file(args.camera_file)
    with LiveCamera(index, camera, geometry=geometry) as live, \
            _publisher(args, encoding, live.name) as publisher:  # type: ignore[arg-type]
        if not args.quiet:
            print(f"streaming {live.name} to {args.to} as stream {publisher.stream} ({encoding}, newest frame "
                  f"first); waiting for the service... (Ctrl-C to stop)", file=sys.stderr)
        summary = relay_live(live, publisher, progress=not args.quiet, wait=args.wait)
    code = _finish(summary)
    if live.failure is not None:
        raise InputError(live.failure)
    return code


def _publisher(args: argparse.Namespace, encoding: str, name: str) -> "FramePublisher":
    from lostx.stream.producer import FramePublisher

    return FramePublisher(args.to, encoding=encoding, quality=args.jpeg_quality or 90,
                          keys=client_keys_from_args(args), stream=args.stream, name=f"lostx replay {name}")


def _finish(summary: "ReplaySummary") -> int:
    print(summary.line())
    if summary.interrupted:
        return 130
    return 0 if summary.unanswered == 0 else 1

"""``lostx camera check SOURCE``: a source's camera geometry, printed and drawn on one of its frames."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.options import add_source_options, print_notes, source_options_from_args, whole_number

if TYPE_CHECKING:
    from lostx.core.frame import Frame
    from lostx.core.geometry import CameraGeometry
    from lostx.replay.folder import Traverse

LIVE_TIMEOUT_S = 10.0
"""How long ``camera check camera:N`` waits for the device's first frame."""
MOTION_FRAMES = 40
"""Frames of a recording over which the pitch is checked against the direction of travel."""
PITCH_AGREES_DEG = 1.0
"""Within this the pitch the motion shows agrees with the geometry's (its own error on real frames: about 0.5)."""


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("camera", help="check a camera's calibration (intrinsics and mounting)")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    check = verbs.add_parser(
        "check", help="print the camera's numbers and the rows of the horizon and the road ahead, and draw them "
                      "on a frame",
        description="Print the camera's intrinsics and mounting, where they came from, and the image rows of the "
                    "horizon and of the road 10, 20 and 40 m ahead; with --out, draw them on a frame. The "
                    "horizon should lie where the road vanishes: if it does not, the numbers are wrong.")
    check.add_argument("source", help="the frames: a folder of images, a RobotCar folder, a ROS 2 bag (.mcap), a "
                       "video, a nuScenes scene, or camera:N (see docs/datasets.md)")
    check.add_argument("--frame", type=whole_number(0), default=0, metavar="N",
                       help="the frame to draw on (0-based; default 0)")
    check.add_argument("--out", type=Path, metavar="PNG", help="write the frame with the lines drawn on it here")
    add_source_options(check)
    check.set_defaults(run=run_check)


def run_check(args: argparse.Namespace) -> int:
    from lostx.core.outputs import check_output_file

    if args.out is not None:
        check_output_file(args.out, "--out")
    frame, label, notes, traverse = _frame(args)
    print_notes(notes)
    geometry = _geometry(frame, args.source)
    _print_and_draw(frame, geometry, label, args.out)
    if traverse is not None:
        _print_seen_motion(traverse, geometry, args.frame)
    return 0


def _print_seen_motion(traverse: Traverse, geometry: CameraGeometry, start: int) -> None:
    """What up to ``MOTION_FRAMES`` frames from ``start`` show: the rows that stay the same (the vehicle's body),
    and the pitch their direction of travel puts the camera at (visual odometry)."""
    from lostx.core.motion.visual import VisualOdometry

    from . import camera_check

    odometry = VisualOdometry(geometry)
    details = []  # small: the frames themselves are not kept
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # said here as a line of its own
        for k in range(start, min(len(traverse), start + MOTION_FRAMES)):
            image = traverse.frame(k).image
            details.append(camera_check.body_detail(image))
            odometry.step(image)
    if len(details) > 1:
        print(camera_check.body_line(camera_check.seen_body(details), len(details) - 1, geometry.body))
    seen = odometry.seen_pitch()
    if seen is None:
        print(f"motion     no step along the camera's axis in frames {start}-{start + MOTION_FRAMES - 1}: "
              f"the pitch is not checked against the motion")
        return
    pitch, steps = seen
    verdict = ("agrees" if abs(pitch - geometry.pitch) <= PITCH_AGREES_DEG else
               "DISAGREES: the layout needs the pitch to within half a degree; see where the horizon falls")
    print(f"motion     the direction of travel over {steps} steps puts the pitch at {pitch:.2f} degrees "
          f"(the geometry: {geometry.pitch:.2f}): {verdict}")


def _print_and_draw(frame: Frame, calibrated: CameraGeometry, label: str, out: Path | None) -> None:
    import cv2

    from lostx.core.errors import InputError

    from . import camera_check

    height, width = frame.image.shape[:2]
    geometry = calibrated.scaled_to(width, height)
    print(f"frame      {label}: {frame.name or frame.id}, {width} x {height}")
    for line in camera_check.report(geometry, calibrated):
        print(line)
    warning = camera_check.aspect_warning((width, height), calibrated)
    if warning:
        print(f"warning    {warning}")
    if out is None:
        print("(--out check.png draws these lines on the frame)")
        return
    if not cv2.imwrite(str(out), camera_check.draw(frame.image, geometry)):
        raise InputError(f"--out {out}: cannot write a PNG there (give a name ending in .png)")
    print(f"wrote {out}: the horizon should lie where the road vanishes, the lines on the road that far ahead")


def _geometry(frame: Frame, source: str) -> CameraGeometry:
    from lostx.core.errors import InputError

    if frame.geometry is None:
        raise InputError(f"{source}: no camera geometry: give a camera file with --camera-file PATH, or put "
                         f"camera.toml beside the frames (its format: docs/datasets.md, 'Camera file')")
    return frame.geometry


def _frame(args: argparse.Namespace) -> tuple[Frame, str, list[str], Traverse | None]:
    """Frame ``--frame`` of the source, a label for it, the reader's notes, and the recording (None: live)."""
    from lostx.core.errors import InputError
    from lostx.replay.camera import camera_index
    from lostx.replay.dataset import open_traverse

    index = camera_index(args.source)
    if index is not None:
        return _live_frame(args, index), f"camera:{index}", [], None
    traverse = open_traverse(Path(args.source), args.format, options=source_options_from_args(args))
    if args.frame >= len(traverse):
        raise InputError(f"--frame {args.frame}: {args.source} has {len(traverse)} frames (0 to {len(traverse) - 1})")
    return traverse.frame(args.frame), f"{traverse.name} #{args.frame}", traverse.notes, traverse


def _live_frame(args: argparse.Namespace, index: int) -> Frame:
    """The first frame a live camera delivers, with the camera file's geometry."""
    from lostx.core.errors import InputError
    from lostx.core.geometry import read_camera_file
    from lostx.replay.camera import LiveCamera

    if args.camera_file is None:
        raise InputError(f"camera:{index}: a live camera carries no calibration; give its camera file with "
                         f"--camera-file PATH (its format: docs/datasets.md, 'Camera file')")
    geometry = read_camera_file(args.camera_file)
    with LiveCamera(index, geometry=geometry) as live:
        frame = live.next_frame(LIVE_TIMEOUT_S)
        if frame is None:
            raise InputError(live.failure or f"camera:{index} gave no frame within {LIVE_TIMEOUT_S:g} s")
    return frame

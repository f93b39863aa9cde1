"""One entry point for reading a traverse in any supported format.

Formats (``format=`` or recognised from the path):

- ``folder``: a folder of images in name order, with a positions CSV (given, or a
  ``positions.csv`` inside the folder) or none;
- ``robotcar``: RobotCar traverse folders (``stereo/centre/`` and/or ``mono_rear/``,
  timestamps files, ``gps/ins.csv``); the camera is chosen with ``camera``
  (front = stereo centre, rear = mono rear);
- ``bag``: a ROS 2 bag in MCAP (an ``.mcap`` file or a rosbag2 folder of them); the
  image and pose topics are chosen with :class:`SourceOptions`;
- ``video``: a video file (``.mp4``, ``.mkv``, ``.avi``, ...), every frame at its recorded rate;
- ``nuscenes``: one camera channel of one nuScenes scene (a dataset root, or a folder of
  its camera images with the ``v1.0-*`` tables near);
- ``vprbench`` and ``pairs`` name reference/query pairs; they are opened as pairs by
  :func:`lostx.evaluation.datasets.open_pair`.

Every format's frames may carry the camera's geometry and the vehicle's odometry
(``Traverse.geometry``, ``Traverse.odometry``): a dataset's or a bag's calibration and poses,
or, for a folder, a ``camera.toml`` and an ``odometry.csv`` beside the frames (a video: a
``camera.toml`` in its folder); ``SourceOptions.camera_file`` overrides the geometry of any source
(:mod:`.calibration`, :mod:`.odometry`).

Recognition: an ``.mcap`` file or a folder of them is a bag; a file with a video suffix
is a video; a folder with ``ref/`` and ``query/`` is VPR-Bench; one with a RobotCar camera
folder or timestamps file is RobotCar; one with nuScenes tables (or nuScenes camera
images with the tables near) is nuScenes; any other folder of images is ``folder``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.core.images import list_images

from .bag import bag_traverse, is_bag
from .calibration import calibrate, mirror_calibration
from .folder import Traverse, folder_traverse
from .formats import FORMATS, Format
from .nuscenes import is_nuscenes, nuscenes_traverse
from .odometry import ODOMETRY_FILE, read_odometry_csv
from .robotcar import is_robotcar, robotcar_traverse
from .subsample import select_frames
from .video import VIDEO_SUFFIXES, is_video, video_traverse
from .vprbench import is_vprbench

POSITIONS_FILE = "positions.csv"


@dataclass(frozen=True)
class SourceOptions:
    """What to read from a recording beyond its path; each reader uses the fields that concern it."""

    topic: str | None = None
    """Bag: the image topic (may be left out when the bag has one)."""
    pose_topic: str | None = None
    """Bag: the topic positions come from (may be left out when the bag has at most one)."""
    scene: str | None = None
    """nuScenes: the scene name, e.g. ``scene-0523`` (may be left out when only one has images)."""
    channel: str | None = None
    """nuScenes: the camera channel at a dataset root (default CAM_FRONT; a folder of images has its own)."""
    look_at: float | None = None
    """nuScenes: positions this many metres along the camera's heading instead of the vehicle's."""
    every: int | None = None
    """Keep every N-th frame."""
    fps: float | None = None
    """Keep frames at this rate of recorded time (needs timestamps)."""
    camera_file: Path | None = None
    """A camera file (intrinsics and mounting, see docs/datasets.md) for the frames, in place of any
    geometry the source carries or a ``camera.toml`` beside its frames."""

    def misplaced(self, kind: str) -> list[str]:
        """The options given that a source of format ``kind`` has no use for (as command-line flags)."""
        return [f"--{name.replace('_', '-')}" for name, kinds in _OPTION_FORMATS.items()
                if getattr(self, name) is not None and kind not in kinds]

    def only_for(self, kind: str) -> "SourceOptions":
        """These options without those a source of format ``kind`` has no use for."""
        return replace(self, **{name: None for name, kinds in _OPTION_FORMATS.items() if kind not in kinds})


_OPTION_FORMATS = {"topic": ("bag",), "pose_topic": ("bag",), "scene": ("nuscenes",), "channel": ("nuscenes",),
                   "look_at": ("nuscenes",)}


def detect_format(path: str | Path) -> Format:
    """The format of one path (see the module docstring)."""
    path = Path(path)
    if path.is_file():
        if is_bag(path):
            return "bag"
        if is_video(path):
            return "video"
        raise InputError(f"{path}: a file, but neither an MCAP bag (.mcap) nor a video "
                         f"({', '.join(VIDEO_SUFFIXES)}); a traverse of images is a folder")
    if not path.is_dir():
        raise InputError(f"no such file or folder: {path}")
    if is_vprbench(path):
        return "vprbench"
    if is_robotcar(path):
        return "robotcar"
    if is_bag(path):
        return "bag"
    if is_nuscenes(path):
        return "nuscenes"
    list_images(path)  # raises, naming the folder, when there is nothing to read
    return "folder"


def open_traverse(
    path: str | Path,
    format: str | None = None,
    camera: Camera | None = None,
    positions: str | Path | None = None,
    mirror: bool = False,
    options: SourceOptions | None = None,
) -> Traverse:
    """One traverse in any format but the pair formats, recognised when ``format`` is None.

    ``camera`` declares the camera's direction (RobotCar: chooses the camera, front by
    default; nuScenes: overrides the channel's own). ``positions`` names the positions
    file: for RobotCar the INS/GPS CSV (default ``gps/ins.csv``), for a folder the
    positions CSV (default ``positions.csv`` inside it, if there).
    """
    path = Path(path)
    options = options or SourceOptions()
    kind = format or detect_format(path)
    if positions is not None and kind not in ("folder", "pairs", "robotcar"):
        raise InputError(f"{path}: a positions file goes with a folder or RobotCar traverse; a {kind} source "
                         f"has its own positions")
    misplaced = options.misplaced(kind)
    if misplaced:
        raise InputError(f"{path}: {', '.join(misplaced)} {'does' if len(misplaced) == 1 else 'do'} not apply "
                         f"to a {kind} source")
    if kind == "robotcar":
        traverse = robotcar_traverse(path, camera or "front", ins=positions, mirror=mirror)
    elif kind in ("folder", "pairs"):
        if positions is None and (path / POSITIONS_FILE).is_file():
            positions = path / POSITIONS_FILE
        traverse = with_odometry_file(folder_traverse(path, positions, camera, mirror), path)
    elif kind == "bag":
        traverse = bag_traverse(path, options.topic, options.pose_topic, camera, mirror)
    elif kind == "video":
        traverse = video_traverse(path, camera, mirror)
    elif kind == "nuscenes":
        traverse = nuscenes_traverse(path, options.scene, options.channel, camera, options.look_at, mirror)
    elif kind == "vprbench":
        raise InputError(f"{path}: a VPR-Bench folder is a reference/query pair; open it with open_pair")
    else:
        raise InputError(f"unknown dataset format {kind!r}; expected one of {', '.join(FORMATS)}")
    traverse = calibrate(mirror_calibration(traverse), path, kind, options.camera_file)
    return select_frames(traverse, options.every, options.fps)


def with_odometry_file(traverse: Traverse, folder: Path) -> Traverse:
    """A folder's traverse with the odometry of the ``odometry.csv`` in it, where there is one."""
    path = folder / ODOMETRY_FILE
    if not path.is_file():
        return traverse
    return replace(traverse, odometry=read_odometry_csv(path, traverse.names, traverse.timestamps))

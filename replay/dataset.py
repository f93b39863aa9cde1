"""One entry point for reading a traverse in any supported format.

Formats (``format=`` or recognised from the folder):

- ``robotcar``: RobotCar traverse folders (``stereo/centre/`` and/or ``mono_rear/``,
  timestamps files, ``gps/ins.csv``); the camera is chosen with ``camera``
  (front = stereo centre, rear = mono rear);
- ``folder``: a folder of images in name order, with a positions CSV (given, or a
  ``positions.csv`` inside the folder) or none;
- ``vprbench`` and ``pairs`` name reference/query pairs; they are opened as pairs by
  :func:`lostx.evaluation.datasets.open_pair`.

Recognition: a folder with ``ref/`` and ``query/`` is VPR-Bench; one with a
RobotCar camera folder or timestamps file is RobotCar; any other folder of images
is ``folder``.
"""

from __future__ import annotations

from pathlib import Path

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.core.images import list_images

from .folder import Traverse, folder_traverse
from .formats import FORMATS, Format
from .robotcar import is_robotcar, robotcar_traverse
from .vprbench import is_vprbench

POSITIONS_FILE = "positions.csv"


def detect_format(folder: str | Path) -> Format:
    """The format of one folder: 'vprbench', 'robotcar' or 'folder' (a plain image folder)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"not a folder: {folder}")
    if is_vprbench(folder):
        return "vprbench"
    if is_robotcar(folder):
        return "robotcar"
    list_images(folder)  # raises, naming the folder, when there is nothing to read
    return "folder"


def open_traverse(
    path: str | Path,
    format: str | None = None,
    camera: Camera | None = None,
    positions: str | Path | None = None,
    mirror: bool = False,
) -> Traverse:
    """One traverse in the 'folder' (or 'pairs') or 'robotcar' format, recognised when ``format`` is None.

    For RobotCar, ``positions`` names the INS/GPS CSV (default ``gps/ins.csv``);
    for a folder, the positions CSV (default ``positions.csv`` inside it, if there).
    """
    path = Path(path)
    kind = format or detect_format(path)
    if kind == "robotcar":
        return robotcar_traverse(path, camera or "front", ins=positions, mirror=mirror)
    if kind in ("folder", "pairs"):
        if positions is None and (path / POSITIONS_FILE).is_file():
            positions = path / POSITIONS_FILE
        return folder_traverse(path, positions, camera, mirror)
    if kind == "vprbench":
        raise InputError(f"{path}: a VPR-Bench folder is a reference/query pair; open it with open_pair")
    raise InputError(f"unknown dataset format {kind!r}; expected one of {', '.join(FORMATS)}")

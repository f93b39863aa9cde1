"""Where a traverse's camera geometry comes from when its source does not carry it: a camera file.

A folder of frames may hold ``camera.toml`` (and a video file may have one in its folder): it is read
without any option. ``--camera-file PATH`` (``SourceOptions.camera_file``) names one explicitly and
wins over everything, a dataset's or a bag's own calibration included: a user who gives a file means
it. The file's format and conventions are in :mod:`lostx.core.geometry` and docs/datasets.md.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from lostx.core.geometry import CAMERA_FILE, CameraGeometry, read_camera_file

from .folder import Traverse

BESIDE_FORMATS = ("folder", "pairs", "video")
"""Sources that carry no calibration of their own, so a camera file beside their frames is read."""


def camera_file_beside(path: str | Path, kind: str) -> Path | None:
    """The camera file that goes with a source of format ``kind`` at ``path`` without any option, if one
    is there: ``camera.toml`` inside a folder of frames, or in the folder of a video file."""
    if kind not in BESIDE_FORMATS:
        return None
    path = Path(path)
    candidate = (path if path.is_dir() else path.parent) / CAMERA_FILE
    return candidate if candidate.is_file() else None


def calibrate(traverse: Traverse, path: str | Path, kind: str, camera_file: str | Path | None) -> Traverse:
    """``traverse`` with the geometry of ``camera_file`` (given), else of the camera file beside its
    frames, else its source's own."""
    if camera_file is not None:
        return with_camera_file(traverse, camera_file)
    beside = camera_file_beside(path, kind)
    if beside is None or traverse.geometry is not None:
        return traverse
    return with_camera_file(traverse, beside)


def with_camera_file(traverse: Traverse, camera_file: str | Path) -> Traverse:
    """``traverse`` with the geometry of ``camera_file`` (mirrored where the traverse flips its images),
    noted, and saying so where it replaces the source's own calibration."""
    geometry = read_camera_file(camera_file)
    if traverse.mirror:
        geometry = mirrored_geometry(geometry)
    note = f"camera geometry from {camera_file}"
    if traverse.geometry is not None:
        note += f", in place of the source's own ({traverse.geometry.source or 'its calibration'})"
    return replace(traverse, geometry=geometry, notes=[*traverse.notes, note])


def mirrored_geometry(geometry: CameraGeometry) -> CameraGeometry:
    """The camera that sees ``geometry``'s images flipped left-right: the world reflected in the vehicle's
    x-z plane (y, yaw and roll change sign; the principal point moves to the other side)."""
    return replace(geometry, cx=geometry.width - 1 - geometry.cx, y=-geometry.y, yaw=-geometry.yaw,
                   roll=-geometry.roll)


def mirrored_odometry(odometry: np.ndarray) -> np.ndarray:
    """Vehicle poses in the same reflected world: (x, -y, -yaw)."""
    return np.asarray(odometry, dtype=np.float64) * np.array([1.0, -1.0, -1.0])


def mirror_calibration(traverse: Traverse) -> Traverse:
    """A traverse whose images are flipped left-right gets the geometry and odometry of that mirrored
    world, so that what the layout computes from the flipped images agrees with them (for the calibration
    its reader gave; a camera file is mirrored as it is read, by :func:`with_camera_file`)."""
    if not traverse.mirror:
        return traverse
    geometry = mirrored_geometry(traverse.geometry) if traverse.geometry is not None else None
    odometry = mirrored_odometry(traverse.odometry) if traverse.odometry is not None else None
    return replace(traverse, geometry=geometry, odometry=odometry)

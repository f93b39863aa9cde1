"""The vehicle's odometry at each frame: from an ``odometry.csv`` beside a folder's frames, from RobotCar's
visual odometry (``vo/vo.csv``), and the planar-pose arithmetic the readers share.

Odometry is a pose (x, y in metres, yaw in radians anticlockwise) per frame in the source's own
odometry frame: only the motion between frames is used, so its origin does not matter.

``odometry.csv`` has a header row and the columns (case-insensitive):

- ``x``, ``y``: metres; ``yaw``: degrees, anticlockwise (the vehicle's x forward, y left);
- and ``file`` (or ``filename``, ``image``, ``name``): the image's file name, each image needing a row;
  or ``timestamp`` (or ``time``, ``t``), seconds on the clock of the frames' timestamps
  (``positions.csv``): each frame takes the row nearest in time, which must be within
  :data:`MAX_GAP_S`; or neither: row k is the k-th image in name order.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from lostx.core.errors import InputError

from .positions import read_csv

ODOMETRY_FILE = "odometry.csv"
MAX_GAP_S = 1.0
"""Furthest a frame may be in time from the odometry row it takes (further: the clocks differ)."""
_FILE = ("file", "filename", "image", "name")
_TIME = ("timestamp", "time", "t")
_POSE = ("x", "y", "yaw")


def read_odometry_csv(path: str | Path, names: list[str], timestamps: np.ndarray | None) -> np.ndarray:
    """(N, 3) x, y, yaw (radians) for the images ``names`` (name order) from an odometry CSV."""
    path = Path(path)
    header, rows = read_csv(path, "odometry", "file,x,y,yaw")
    col = _columns(path, header, rows, _POSE, "an odometry file has x, y (metres), yaw (degrees) and file or "
                   "timestamp (see docs/datasets.md)", "odometry rows")
    file_col = next((col[n] for n in _FILE if n in col), None)
    time_col = next((col[n] for n in _TIME if n in col), None)
    poses, keys, lines = _parse(path, header, rows, [col[n] for n in _POSE], file_col, time_col)
    if file_col is not None:
        return poses[_by_name(path, keys, lines, names)]
    if time_col is not None:
        return poses[_by_time(path, np.asarray(keys, dtype=np.float64), names, timestamps)]
    if len(poses) != len(names):
        raise InputError(f"{path}: {len(poses)} odometry rows for {len(names)} images; add a file or timestamp "
                         f"column, or give one row per image in name order")
    return poses


def _columns(path: Path, header: list[str], rows: list[tuple[int, list[str]]], required: tuple[str, ...],
             advice: str, what: str) -> dict[str, int]:
    """Each column's index; a one-line error where a ``required`` column or every row is missing."""
    col = {name: i for i, name in enumerate(header)}
    missing = [name for name in required if name not in col]
    if missing:
        raise InputError(f"{path}:1: header {header} lacks {', '.join(missing)}; {advice}")
    if not rows:
        raise InputError(f"{path}: no {what} after the header")
    return col


def _parse(path: Path, header: list[str], rows: list[tuple[int, list[str]]], pose_cols: list[int],
           file_col: int | None, time_col: int | None) -> tuple[np.ndarray, list, list[int]]:
    """The poses (yaw in radians), the file name or timestamp of each row, and the rows' line numbers."""
    key_col = file_col if file_col is not None else time_col
    need = max(c for c in (*pose_cols, key_col) if c is not None)
    poses, keys, lines = [], [], []
    for line, row in rows:
        if len(row) <= need:
            raise InputError(f"{path}:{line}: expected {len(header)} columns, got {len(row)}: {row}")
        try:
            x, y, yaw = (float(row[c]) for c in pose_cols)
            stamp = float(row[time_col]) if key_col == time_col and time_col is not None else None
        except ValueError:
            raise InputError(f"{path}:{line}: not a number in {row}") from None
        if not all(math.isfinite(v) for v in (x, y, yaw, *([stamp] if stamp is not None else []))):
            raise InputError(f"{path}:{line}: non-finite value in {row}")
        if file_col is not None:
            name = row[file_col].strip()
            if not name:
                raise InputError(f"{path}:{line}: empty file name in column '{header[file_col]}'")
            keys.append(Path(name).name)
        else:
            keys.append(stamp)
        poses.append((x, y, math.radians(yaw)))
        lines.append(line)
    return np.asarray(poses, dtype=np.float64), keys, lines


def _by_name(path: Path, files: list[str], lines: list[int], names: list[str]) -> np.ndarray:
    index: dict[str, int] = {}
    for row, name in enumerate(files):
        if name in index:
            raise InputError(f"{path}:{lines[row]}: file {name} is listed twice (first on line {lines[index[name]]})")
        index[name] = row
    missing = [n for n in names if n not in index]
    if missing:
        raise InputError(f"{path}: no odometry for {len(missing)} image(s), e.g. {', '.join(missing[:3])}")
    return np.asarray([index[n] for n in names], dtype=np.int64)


def _by_time(path: Path, stamps: np.ndarray, names: list[str], timestamps: np.ndarray | None) -> np.ndarray:
    """The row nearest in time to each frame (ties to the earlier row)."""
    if timestamps is None:
        raise InputError(f"{path} matches frames by timestamp, and these frames have none: give them timestamps "
                         f"(a timestamp column in positions.csv) or give odometry.csv a file column")
    order = np.argsort(stamps, kind="stable")
    sorted_stamps = stamps[order]
    after = np.clip(np.searchsorted(sorted_stamps, timestamps), 1, max(len(stamps) - 1, 1))
    before = after - 1
    if len(stamps) == 1:
        nearest = np.zeros(len(timestamps), dtype=np.int64)
    else:
        nearest = np.where(sorted_stamps[after] - timestamps < timestamps - sorted_stamps[before], after, before)
    gaps = np.abs(sorted_stamps[nearest] - timestamps)
    worst = int(np.argmax(gaps)) if len(gaps) else 0
    if len(gaps) and gaps[worst] > MAX_GAP_S:
        raise InputError(f"{path}: frame {names[worst]} at {timestamps[worst]:.3f} s is {gaps[worst]:.3f} s from the "
                         f"nearest odometry row (at most {MAX_GAP_S:g} s): are both on the same clock, in seconds?")
    return order[nearest]


# -- planar poses --------------------------------------------------------------------------------


def yaw_of_quaternion(w: float, x: float, y: float, z: float) -> float:
    """Heading (rotation about the vertical axis) of a unit quaternion, radians anticlockwise from x."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def interpolate_poses(sample_times: np.ndarray, poses: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(N, 3) poses at ``times``, linear between samples (yaw along the shorter way round), held at the
    first or last sample outside their span."""
    t0 = sample_times[0]  # relative times: integer micro- or nanoseconds lose precision as float64
    st = (np.asarray(sample_times) - t0).astype(np.float64)
    tt = (np.asarray(times) - t0).astype(np.float64)
    yaw = np.unwrap(poses[:, 2])
    out = np.stack([np.interp(tt, st, poses[:, 0]), np.interp(tt, st, poses[:, 1]), np.interp(tt, st, yaw)], axis=1)
    out[:, 2] = np.pi - np.mod(np.pi - out[:, 2], 2.0 * np.pi)  # back into (-pi, pi]
    return out


# -- RobotCar visual odometry ----------------------------------------------------------------------

VO_FILE = "vo/vo.csv"
_VO_COLUMNS = ("source_timestamp", "destination_timestamp", "x", "y", "z", "roll", "pitch", "yaw")


def read_robotcar_vo(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps in microseconds, (M, 3) planar poses) of a RobotCar ``vo.csv``, its relative motions
    chained into poses (the first at the first row's destination time).

    Each row is the pose of the camera at ``source_timestamp`` in its frame at ``destination_timestamp``
    (the previous row's source), as x, y, z metres and roll, pitch, yaw radians in RobotCar's vehicle frame
    (x forward, y right, z down), chained as the RobotCar SDK does (``interpolate_vo_poses``); the poses
    come out in lostx's frame (y left, yaw anticlockwise).
    """
    path = Path(path)
    header, rows = read_csv(path, "odometry", ",".join(_VO_COLUMNS))
    col = _columns(path, header, rows, _VO_COLUMNS, f"RobotCar's vo.csv has {','.join(_VO_COLUMNS)}", "motions")
    pose = np.eye(4)
    times: list[int] = []
    planar: list[tuple[float, float, float]] = []
    for line, row in rows:
        source, destination, motion = _vo_row(path, line, row, col)
        if not times:
            times.append(destination)
            planar.append((0.0, 0.0, 0.0))
        if source <= times[-1]:
            raise InputError(f"{path}:{line}: source_timestamp {source} is not after the previous pose's ({times[-1]})")
        pose = pose @ _se3(*motion)
        times.append(source)
        planar.append((float(pose[0, 3]), -float(pose[1, 3]), -math.atan2(pose[1, 0], pose[0, 0])))
    return np.asarray(times, dtype=np.int64), np.asarray(planar, dtype=np.float64)


def _vo_row(path: Path, line: int, row: list[str], col: dict[str, int]) -> tuple[int, int, list[float]]:
    if len(row) <= max(col[name] for name in _VO_COLUMNS):
        raise InputError(f"{path}:{line}: expected {len(col)} columns, got {len(row)}")
    try:
        source, destination = int(row[col["source_timestamp"]]), int(row[col["destination_timestamp"]])
        motion = [float(row[col[name]]) for name in _VO_COLUMNS[2:]]
    except ValueError:
        raise InputError(f"{path}:{line}: not a number in {row}") from None
    if not all(math.isfinite(v) for v in motion):
        raise InputError(f"{path}:{line}: non-finite value in {row}")
    return source, destination, motion


def _se3(x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The 4x4 transform of a translation and roll, pitch, yaw (R = Rz(yaw) Ry(pitch) Rx(roll)), as the
    RobotCar SDK's ``build_se3_transform``."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    out = np.eye(4)
    out[:3, :3] = [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                   [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                   [-sp, cp * sr, cp * cr]]
    out[:3, 3] = (x, y, z)
    return out

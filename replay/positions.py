"""Positions (and timestamps) of a traverse's frames from a CSV file.

The CSV has a header row. Recognised columns (case-insensitive):

- ``file`` (or ``filename``, ``image``, ``name``): the image file name. Optional:
  without it, row k belongs to the k-th image in name order.
- ``x`` and ``y`` (or ``easting`` and ``northing``) in metres, or
  ``lat`` and ``lon`` (or ``latitude`` and ``longitude``) in degrees, which are
  projected to local metres (east, north) about the first row.
- ``timestamp`` (or ``time``, ``t``) in seconds. Optional.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lostx.core.errors import InputError

EARTH_RADIUS_M = 6_371_008.8
_FILE = ("file", "filename", "image", "name")
_XY = (("x", "y"), ("easting", "northing"))
_LATLON = (("lat", "lon"), ("latitude", "longitude"))
_TIME = ("timestamp", "time", "t")


@dataclass
class PositionTable:
    positions: np.ndarray  # (N, 2) metres
    timestamps: np.ndarray | None  # (N,) seconds
    files: list[str] | None  # file name per row, if the CSV names them
    geographic: bool  # read from lat/lon
    origin: tuple[float, float] | None = None  # (lat, lon) of the projection origin
    geo: np.ndarray | None = None  # (N, 2) the latitudes and longitudes as read, when geographic
    lines: list[int] | None = None  # the CSV line number of each row, for messages


def latlon_to_local(lat: np.ndarray, lon: np.ndarray, origin: tuple[float, float]) -> np.ndarray:
    """Equirectangular projection to metres east and north of ``origin``; exact enough over a few km."""
    lat0, lon0 = origin
    east = np.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    north = np.radians(lat - lat0) * EARTH_RADIUS_M
    return np.stack([east, north], axis=1)


def read_csv(path: Path, kind: str, example: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """A CSV file's header (lower case) and its non-blank rows with their line numbers; one-line errors naming
    the ``kind`` of file (e.g. ``positions``) and an ``example`` header for an empty one."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # a spreadsheet's byte-order mark is not part of the header
    except FileNotFoundError:
        raise InputError(f"{kind} file not found: {path}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file") from None
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError(f"{path}: empty {kind} file (expected a header row such as '{example}')")
    body = [(line, row) for line, row in enumerate(rows[1:], start=2) if any(cell.strip() for cell in row)]
    return [h.strip().lower() for h in rows[0]], body


def read_positions(path: str | Path) -> PositionTable:
    path = Path(path)
    header, rows = read_csv(path, "positions", "file,x,y")
    col = {name: i for i, name in enumerate(header)}

    def find(names: tuple[str, ...]) -> int | None:
        return next((col[n] for n in names if n in col), None)

    pair = next(((col[a], col[b]) for a, b in _XY if a in col and b in col), None)
    geographic = False
    if pair is None:
        pair = next(((col[a], col[b]) for a, b in _LATLON if a in col and b in col), None)
        geographic = True
    if pair is None:
        raise InputError(
            f"{path}:1: header {header} has no position columns; expected x,y (metres) or lat,lon (degrees)"
        )
    file_col, time_col = find(_FILE), find(_TIME)
    values, stamps, files, lines = [], [], [], []
    for line, row in rows:
        needed = [c for c in (*pair, file_col, time_col) if c is not None]
        if len(row) <= max(needed):
            raise InputError(f"{path}:{line}: expected {len(header)} columns, got {len(row)}: {row}")
        try:
            a, b = float(row[pair[0]]), float(row[pair[1]])
            t = float(row[time_col]) if time_col is not None else None
        except ValueError:
            raise InputError(f"{path}:{line}: not a number in {row}") from None
        if not (math.isfinite(a) and math.isfinite(b)) or (t is not None and not math.isfinite(t)):
            raise InputError(f"{path}:{line}: non-finite value in {row}")
        if geographic and not (-90 <= a <= 90 and -180 <= b <= 180):
            raise InputError(f"{path}:{line}: latitude/longitude out of range: {a}, {b}")
        values.append((a, b))
        stamps.append(t)
        lines.append(line)
        if file_col is not None:
            name = row[file_col].strip()
            if not name:
                raise InputError(f"{path}:{line}: empty file name in column '{header[file_col]}'")
            files.append(Path(name).name)  # a path in the CSV matches the image by its name
    if not values:
        raise InputError(f"{path}: no position rows after the header")
    coords = np.asarray(values, dtype=np.float64)
    origin = geo = None
    if geographic:
        geo = coords
        origin = (float(coords[0, 0]), float(coords[0, 1]))
        coords = latlon_to_local(coords[:, 0], coords[:, 1], origin)
    return PositionTable(
        positions=coords,
        timestamps=np.asarray(stamps, dtype=np.float64) if time_col is not None else None,
        files=files if file_col is not None else None,
        geographic=geographic,
        origin=origin,
        geo=geo,
        lines=lines,
    )


def align_positions(
    table: PositionTable, names: list[str], source: Path
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Positions, timestamps (or None) and latitude/longitude (or None) in the order of the image ``names``."""
    if table.files is None:
        if len(table.positions) != len(names):
            raise InputError(
                f"{source}: {len(table.positions)} position rows for {len(names)} images; "
                f"add a 'file' column or give one row per image in name order"
            )
        return table.positions, table.timestamps, table.geo
    index: dict[str, int] = {}
    for row, name in enumerate(table.files):
        if name in index:
            line = table.lines[row] if table.lines else row + 2
            first = table.lines[index[name]] if table.lines else index[name] + 2
            raise InputError(f"{source}:{line}: file {name} is listed twice (first on line {first})")
        index[name] = row
    missing = [n for n in names if n not in index]
    if missing:
        raise InputError(f"{source}: no position for {len(missing)} image(s), e.g. {', '.join(missing[:3])}")
    order = np.asarray([index[n] for n in names])
    stamps = table.timestamps[order] if table.timestamps is not None else None
    geo = table.geo[order] if table.geo is not None else None
    return table.positions[order], stamps, geo


def interpolate_positions(sample_times: np.ndarray, sample_values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Linear interpolation of (N, 2) samples at ``times``; NaN outside the sampled time span."""
    # Relative to the first sample: integer UNIX times in micro- or nanoseconds lose precision as float64.
    t0 = sample_times[0]
    st = (sample_times - t0).astype(np.float64)
    tt = (np.asarray(times) - t0).astype(np.float64)
    out = np.stack([np.interp(tt, st, sample_values[:, k]) for k in range(sample_values.shape[1])], axis=1)
    out[(tt < st[0]) | (tt > st[-1])] = np.nan
    return out


@dataclass
class Located:
    """Positions interpolated at frame times (see :func:`locate`)."""

    inside: np.ndarray
    """(N,) bool: the frame time lies within the samples' time span (the others have no position)."""
    positions: np.ndarray
    """(M, 2) metres of the frames inside, M = inside.sum()."""
    geo: np.ndarray | None
    """(M, 2) latitude, longitude of the frames inside, when the samples were geographic."""


def locate(sample_times: np.ndarray, sample_values: np.ndarray, geographic: bool, times: np.ndarray) -> Located:
    """Positions at ``times`` from time-stamped samples (metres, or latitude/longitude projected to
    metres about the first frame's), for the frames within the samples' time span."""
    at = interpolate_positions(sample_times, sample_values, times)
    inside = np.isfinite(at).all(axis=1)
    at = at[inside]
    if not geographic:
        return Located(inside, at, None)
    origin = (float(at[0, 0]), float(at[0, 1])) if len(at) else (0.0, 0.0)
    return Located(inside, latlon_to_local(at[:, 0], at[:, 1], origin), at)

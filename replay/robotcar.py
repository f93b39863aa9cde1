"""Oxford RobotCar traverses as distributed (Maddern et al., IJRR 2017).

Layout of one traverse folder (``yyyy-mm-dd-hh-mm-ss/``)::

    stereo/centre/<timestamp>.png    front camera (Bumblebee XB3 centre), raw Bayer GBRG
    mono_rear/<timestamp>.png        rear camera (Grasshopper2), raw Bayer RGGB
    stereo.timestamps                "<timestamp> <chunk>" per line, one per front image
    mono_rear.timestamps             the same for the rear camera
    gps/ins.csv                      INS at 50 Hz: timestamp, ..., latitude, longitude, ..., northing, easting, ...
    gps/gps.csv                      GPS only (the same position columns); used when ins.csv is absent
    vo/vo.csv                        visual odometry (optional): relative motions between stereo frames

Timestamps are UNIX microseconds. Images are single-channel 8-bit PNGs holding
the raw Bayer mosaic; the patterns (GBRG for the stereo cameras, RGGB for the
mono cameras) are those the RobotCar SDK's image loader uses. An image already
stored as colour (three channels, e.g. exported by the SDK) is used as is.

Positions are interpolated linearly at each image timestamp from the INS.
Northing/easting (UTM metres) are used when present, since they are comparable
across traverses without any projection; otherwise latitude/longitude.
Images taken before the first or after the last INS sample have no position
and are dropped (noted on the traverse): they could not be evaluated.
Timestamps listed without an image file (chunks not downloaded) are skipped and
noted; an image file that the timestamps file does not list is an error.

Odometry (``Traverse.odometry``), where ``vo/vo.csv`` is there: its relative motions chained into poses
and interpolated at each image timestamp (:func:`lostx.replay.odometry.read_robotcar_vo`). The
sample has no camera calibration, so RobotCar traverses carry no geometry unless given a camera file.
"""

from __future__ import annotations

import csv
import math
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from lostx.core.errors import ImageError, InputError
from lostx.core.frame import Camera
from lostx.core.images import decode_file

from .folder import Traverse
from .odometry import VO_FILE, interpolate_poses, read_robotcar_vo
from .positions import locate
from .store import ImageFiles

# camera -> (image folder, timestamps file, Bayer pattern named from the top-left 2x2 block, row by row)
CAMERAS: dict[str, tuple[str, str, str]] = {
    "front": ("stereo/centre", "stereo.timestamps", "GBRG"),
    "rear": ("mono_rear", "mono_rear.timestamps", "RGGB"),
}
INS_FILES = ("gps/ins.csv", "gps/gps.csv")

# OpenCV >= 4.5 spells the patterns as read from the top-left corner; older versions only
# have the two-letter codes, named after the second row. The two agree on these pairs.
_LEGACY_CODES = {"GBRG": "GR", "RGGB": "BG", "GRBG": "GB", "BGGR": "RG"}


def is_robotcar(folder: str | Path) -> bool:
    """Does ``folder`` look like a RobotCar traverse (a camera folder or its timestamps file)?"""
    folder = Path(folder)
    return any((folder / images).is_dir() or (folder / stamps).is_file() for images, stamps, _ in CAMERAS.values())


def bayer_code(pattern: str) -> int:
    """The OpenCV conversion code from a raw mosaic with ``pattern`` (e.g. 'GBRG') to RGB."""
    pattern = pattern.upper()
    code = getattr(cv2, f"COLOR_Bayer{pattern}2RGB", None)
    if code is None:
        code = getattr(cv2, f"COLOR_Bayer{_LEGACY_CODES[pattern]}2RGB")
    return int(code)


def demosaic(raw: np.ndarray, pattern: str) -> np.ndarray:
    """RGB uint8 H x W x 3 from a single-channel Bayer mosaic (bilinear, OpenCV)."""
    if raw.ndim != 2:
        raise ImageError(f"a Bayer mosaic has one channel, got shape {raw.shape}")
    if raw.dtype == np.uint16:
        # 16-bit raw: keep the top 8 bits, which is what the network and the thumbnails consume.
        raw = (raw >> 8).astype(np.uint8)
    return cv2.cvtColor(raw, bayer_code(pattern))


def load_bayer_image(path: Path, pattern: str) -> np.ndarray:
    """Read a RobotCar image: demosaic a raw single-channel file, pass a colour file through as RGB."""
    image = decode_file(path, cv2.IMREAD_UNCHANGED)
    if image.ndim == 2:
        return demosaic(image, pattern)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        rgb = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)
        return rgb if rgb.dtype == np.uint8 else (rgb >> 8).astype(np.uint8)
    raise ImageError(f"{path}: expected a raw Bayer (1 channel) or colour image, got shape {image.shape}")


def read_timestamps(path: Path) -> np.ndarray:
    """Microsecond timestamps from a RobotCar ``*.timestamps`` file ("<timestamp> <chunk>" per line)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise InputError(f"timestamps file not found: {path}") from None
    stamps: list[int] = []
    for line, content in enumerate(text.splitlines(), start=1):
        tokens = content.split()
        if not tokens:
            continue
        if len(tokens) > 2 or not all(t.lstrip("-").isdigit() for t in tokens):
            raise InputError(f"{path}:{line}: expected '<timestamp> <chunk>' (integers), got {content.strip()!r}")
        stamp = int(tokens[0])
        if stamps and stamp <= stamps[-1]:
            raise InputError(f"{path}:{line}: timestamp {stamp} is not after the previous one ({stamps[-1]})")
        stamps.append(stamp)
    if not stamps:
        raise InputError(f"{path}: no timestamps")
    return np.asarray(stamps, dtype=np.int64)


def read_ins(path: Path) -> tuple[np.ndarray, np.ndarray, bool]:
    """(timestamps in microseconds, (N, 2) positions, geographic) from a RobotCar INS or GPS CSV.

    Positions are (easting, northing) in metres when the file has those columns,
    else (latitude, longitude) in degrees with ``geographic`` True.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"INS file not found: {path}") from None
    rows = csv.reader(text.splitlines())
    header = [h.strip().lower() for h in next(rows, [])]
    col = {name: i for i, name in enumerate(header)}
    if "timestamp" not in col:
        raise InputError(f"{path}:1: no 'timestamp' column in the header {header}")
    if "northing" in col and "easting" in col:
        pair, geographic = (col["easting"], col["northing"]), False
    elif "latitude" in col and "longitude" in col:
        pair, geographic = (col["latitude"], col["longitude"]), True
    else:
        raise InputError(f"{path}:1: header has neither northing,easting nor latitude,longitude columns: {header}")
    need = max(col["timestamp"], *pair)
    stamps: list[int] = []
    values: list[tuple[float, float]] = []
    for line, row in enumerate(rows, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) <= need:
            raise InputError(f"{path}:{line}: expected {len(header)} columns, got {len(row)}")
        try:
            stamp = int(row[col["timestamp"]])
            a, b = float(row[pair[0]]), float(row[pair[1]])
        except ValueError:
            raise InputError(f"{path}:{line}: not a number in the timestamp or position columns: {row}") from None
        if not (math.isfinite(a) and math.isfinite(b)):
            raise InputError(f"{path}:{line}: non-finite position {a}, {b}")
        if stamps and stamp <= stamps[-1]:
            raise InputError(f"{path}:{line}: timestamp {stamp} is not after the previous one ({stamps[-1]})")
        stamps.append(stamp)
        values.append((a, b))
    if len(stamps) < 2:
        raise InputError(f"{path}: needs at least two position rows to interpolate, found {len(stamps)}")
    return np.asarray(stamps, dtype=np.int64), np.asarray(values, dtype=np.float64), geographic


def robotcar_traverse(
    root: str | Path, camera: Camera = "front", ins: str | Path | None = None, mirror: bool = False
) -> Traverse:
    """One camera of a RobotCar traverse, with positions interpolated from its INS (or GPS) file."""
    root = Path(root)
    if camera not in CAMERAS:
        raise InputError(f"RobotCar camera must be one of {', '.join(CAMERAS)}, got {camera!r}")
    folder, stamps_name, pattern = CAMERAS[camera]
    image_dir = root / folder
    if not image_dir.is_dir():
        raise InputError(f"{root}: no {folder}/ folder for the {camera} camera")
    on_disk = {p.stem: p for p in image_dir.iterdir() if p.is_file() and p.suffix.lower() == ".png"}
    if not on_disk:
        raise InputError(f"no PNG images in {image_dir}")
    for stem, p in on_disk.items():
        if not stem.isdigit():
            raise InputError(f"{p}: RobotCar images are named by their microsecond timestamp, got {p.name}")
    notes: list[str] = []
    # Usually at the traverse root; some extractions leave it beside the camera folder (stereo/stereo.timestamps).
    stamps_path = next((p for p in (root / stamps_name, image_dir.parent / stamps_name) if p.is_file()),
                       root / stamps_name)
    if stamps_path.is_file():
        listed = read_timestamps(stamps_path)
        listed_names = {str(t) for t in listed}
        unlisted = sorted(set(on_disk) - listed_names)
        if unlisted:
            raise InputError(f"{on_disk[unlisted[0]]}: not listed in {stamps_path} ({len(unlisted)} such images)")
        present = np.asarray([str(t) in on_disk for t in listed])
        if not present.all():
            notes.append(f"{int((~present).sum())} of {len(listed)} timestamps in {stamps_name} have no image "
                         f"(chunks not downloaded?): skipped")
        times = listed[present]
    else:
        times = np.asarray(sorted(int(s) for s in on_disk), dtype=np.int64)
        notes.append(f"no {stamps_name}: frame times taken from the image file names")
    files = [on_disk[str(t)] for t in times]

    positions = geo = None
    ins_path = Path(ins) if ins is not None else next((root / f for f in INS_FILES if (root / f).is_file()), None)
    if ins_path is not None:
        ins_times, ins_values, geographic = read_ins(ins_path)
        located = locate(ins_times, ins_values, geographic, times)
        inside = located.inside
        if not inside.any():
            raise InputError(
                f"{ins_path}: covers {ins_times[0]}..{ins_times[-1]} us, none of the {len(times)} images of "
                f"{image_dir} ({times[0]}..{times[-1]} us)"
            )
        if not inside.all():
            notes.append(f"{int((~inside).sum())} images outside the time span of {ins_path.name}: dropped")
            files = [f for f, ok in zip(files, inside) if ok]
            times = times[inside]
        positions, geo = located.positions, located.geo
    else:
        notes.append(f"no {' or '.join(INS_FILES)}: no positions")
    odometry = _visual_odometry(root, times, notes)

    return Traverse(
        name=f"{root.name}/{folder}",
        images=ImageFiles(files, partial(load_bayer_image, pattern=pattern)),
        positions=positions,
        timestamps=times.astype(np.float64) / 1e6,
        camera=camera,
        mirror=mirror,
        geo=geo,
        notes=notes,
        odometry=odometry,
    )


def _visual_odometry(root: Path, times: np.ndarray, notes: list[str]) -> np.ndarray | None:
    """Poses at the image ``times`` (microseconds) from ``vo/vo.csv``, where the traverse has one."""
    path = root / VO_FILE
    if not path.is_file():
        return None
    vo_times, poses = read_robotcar_vo(path)
    outside = (times < vo_times[0]) | (times > vo_times[-1])
    if outside.any():
        notes.append(f"{int(outside.sum())} images outside the time span of {VO_FILE}: their odometry is the "
                     f"pose at its nearest end")
    return interpolate_poses(vo_times, poses, times)

"""nuScenes (Caesar et al., CVPR 2020): one camera channel of one scene, from the v1.0 tables.

The tables (``scene``, ``sample``, ``sample_data``, ``ego_pose``, ``calibrated_sensor``,
``sensor`` as JSON) sit in a ``v1.0-*`` folder (``v1.0-mini``, ``v1.0-trainval``, ...).
Two layouts are read:

- a nuScenes download: ``<root>/v1.0-*/`` and ``<root>/samples/<CHANNEL>/<file>``;
  give ``<root>`` (with a scene and a channel) or ``<root>/samples/<CHANNEL>``;
- any folder of nuScenes camera images (their file names as published) with the
  tables in a ``v1.0-*`` folder in it or up to three levels above, e.g.
  ``nuscenes-frontrear/scene-0523/front/`` with ``nuscenes-frontrear/v1.0-mini-extract/``;
  the channel and scene are read from the images' records.

Frames are the channel's key frames (2 Hz) of the scene in time order (a folder of
the frames between them, ``sweeps/<CHANNEL>``, gives those). Positions are the ego
vehicle's (x, y) in the map frame at each image's capture time, or, with ``look_at``,
the point that many metres from it along the direction the camera faces (the
vehicle's heading turned by the channel's nominal mounting direction). Each frame's
metadata holds ``vehicle_yaw_deg`` and ``camera_yaw_deg``. CAM_FRONT declares a front
camera, CAM_BACK a rear one.

The camera's geometry (``Traverse.geometry``) is the channel's ``calibrated_sensor`` record: its
intrinsics, and its pose on the vehicle (camera to ego, the ego frame x forward, y left, z up on the
ground), for images of the size the ``sample_data`` records give; CAM_BACK's frames show the car's own
boot lid along their bottom edge (:data:`CHANNEL_BODY`). The odometry (``Traverse.odometry``) is the ego
pose of each frame: x, y and the heading in radians.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.core.geometry import CameraGeometry, quaternion_matrix
from lostx.core.images import IMAGE_SUFFIXES, decode_file

from .folder import Traverse
from .store import ImageFiles

TABLES = ("scene", "sample", "sample_data", "ego_pose", "sensor")
CHANNEL_YAW_DEG = {
    "CAM_FRONT": 0.0, "CAM_FRONT_LEFT": 55.0, "CAM_FRONT_RIGHT": -55.0,
    "CAM_BACK": 180.0, "CAM_BACK_LEFT": 110.0, "CAM_BACK_RIGHT": -110.0,
}
"""The direction each camera channel is mounted to face, degrees anticlockwise from the vehicle's heading."""
CHANNEL_CAMERA: dict[str, Camera] = {"CAM_FRONT": "front", "CAM_BACK": "rear"}
CHANNEL_BODY = {"CAM_BACK": 0.09}
"""The share of the image height, at the bottom, that shows the car itself. CAM_BACK sees its boot lid:
on scene-0523 its top edge is at row 826 of 900 in the middle of the image (0.082 of the height),
842 a quarter of the way in from either side and 873 at the sides; 0.09 leaves a margin. The other
channels see none of the car."""
DEFAULT_CHANNEL = "CAM_FRONT"
SEARCH_LEVELS = 3


def find_tables(folder: Path) -> Path | None:
    """The ``v1.0-*`` table folder in ``folder`` or up to three levels above it, if any."""
    for candidate in [folder, *list(folder.parents)[:SEARCH_LEVELS]]:
        found = sorted(p for p in candidate.glob("v1.0-*") if (p / "sample_data.json").is_file())
        if len(found) > 1:
            raise InputError(f"{candidate}: several nuScenes table folders ({', '.join(p.name for p in found)}); "
                             f"keep one beside the images")
        if found:
            return found[0]
    return None


def is_nuscenes(folder: str | Path) -> bool:
    """A nuScenes root (``v1.0-*`` tables inside), or a folder of nuScenes camera images with tables near."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    if any((p / "sample_data.json").is_file() for p in folder.glob("v1.0-*")):
        return True
    names = (p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    first = next(names, None)
    return first is not None and "__CAM_" in first and find_tables(folder) is not None


@dataclass
class Tables:
    """The parts of the nuScenes tables a camera traverse needs."""

    folder: Path
    scenes: dict[str, dict]
    """scene token -> scene record."""
    sample_scene: dict[str, str]
    """sample token -> scene token."""
    records: list[dict]
    """camera sample_data records."""
    poses: dict[str, dict]
    sensors: dict[str, dict]
    """calibrated_sensor token -> {channel, ...}."""

    def scene_name(self, record: dict) -> str:
        return self.scenes[self.sample_scene[record["sample_token"]]]["name"]

    def channel(self, record: dict) -> str:
        return self.sensors[record["calibrated_sensor_token"]]["channel"]


def _load(folder: Path, name: str) -> list[dict]:
    path = folder / f"{name}.json"
    try:
        with open(path, encoding="utf-8") as handle:
            table = json.load(handle)
    except FileNotFoundError:
        raise InputError(f"{folder}: no {name}.json (nuScenes tables need {', '.join(TABLES)} "
                         f"and calibrated_sensor)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(table, list):
        raise InputError(f"{path}: expected a list of records")
    return table


def read_tables(folder: Path) -> Tables:
    try:
        sensors = {s["token"]: s["channel"] for s in _load(folder, "sensor") if s.get("modality") == "camera"}
        calibrated = {c["token"]: {**c, "channel": sensors[c["sensor_token"]]}
                      for c in _load(folder, "calibrated_sensor") if c["sensor_token"] in sensors}
        records = [r for r in _load(folder, "sample_data") if r["calibrated_sensor_token"] in calibrated]
        return Tables(
            folder=folder,
            scenes={s["token"]: s for s in _load(folder, "scene")},
            sample_scene={s["token"]: s["scene_token"] for s in _load(folder, "sample")},
            records=records,
            poses={p["token"]: p for p in _load(folder, "ego_pose")},
            sensors=calibrated,
        )
    except (KeyError, TypeError) as exc:
        raise InputError(f"{folder}: a nuScenes table record lacks the field {exc}") from None


def yaw_deg(rotation: list[float]) -> float:
    """Heading (rotation about the vertical axis) of a (w, x, y, z) quaternion, degrees anticlockwise from x."""
    w, x, y, z = rotation
    return math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def look_at_points(positions: np.ndarray, camera_yaw_deg: np.ndarray, distance: float) -> np.ndarray:
    """The points ``distance`` metres from ``positions`` (N, 2) along the headings ``camera_yaw_deg``."""
    angle = np.radians(camera_yaw_deg)
    return positions + distance * np.stack([np.cos(angle), np.sin(angle)], axis=1)


def nuscenes_traverse(
    path: str | Path,
    scene: str | None = None,
    channel: str | None = None,
    camera: Camera | None = None,
    look_at: float | None = None,
    mirror: bool = False,
) -> Traverse:
    """One camera channel of one scene (see the module docstring for the layouts and the fields).

    ``camera`` overrides the direction the channel declares (e.g. rear frames played as a
    forward-facing camera driving the other way).
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"not a folder: {path}")
    tables_dir = find_tables(path)
    if tables_dir is None:
        raise InputError(f"{path}: no nuScenes tables (a v1.0-* folder with sample_data.json) here or "
                         f"up to {SEARCH_LEVELS} levels above")
    if look_at is not None and not (math.isfinite(look_at) and look_at >= 0):
        raise InputError(f"look-at distance must be a number of metres >= 0, got {look_at}")
    tables = read_tables(tables_dir)
    images_here = {p.name: p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES}
    if images_here:
        records, located = _records_of_folder(tables, path, images_here, scene, channel)
    else:
        records, located = _records_of_root(tables, path, scene, channel or DEFAULT_CHANNEL)
    notes: list[str] = []
    present = [r for r in records if r["token"] in located]
    if len(present) < len(records):
        notes.append(f"{len(records) - len(present)} of {len(records)} frames have no image file: skipped")
    if not present:
        raise InputError(f"{path}: none of the {len(records)} images of this scene and channel is here")
    present.sort(key=lambda r: r["timestamp"])
    chosen_channel = tables.channel(present[0])
    scene_name = tables.scene_name(present[0])
    try:
        poses = [tables.poses[r["ego_pose_token"]] for r in present]
    except KeyError as exc:
        raise InputError(f"{tables_dir}: ego_pose has no record {exc}") from None
    positions = np.asarray([p["translation"][:2] for p in poses], dtype=np.float64)
    vehicle_yaw = np.asarray([yaw_deg(p["rotation"]) for p in poses])
    odometry = np.column_stack([positions, np.radians(vehicle_yaw)])
    geometry = camera_geometry(tables, present[0], located[present[0]["token"]])
    camera_yaw = (vehicle_yaw + CHANNEL_YAW_DEG[chosen_channel] + 180.0) % 360.0 - 180.0
    if look_at is not None:
        positions = look_at_points(positions, camera_yaw, look_at)
        notes.append(f"positions {look_at:g} m along the camera's heading from the vehicle")
    return Traverse(
        name=f"{scene_name}/{chosen_channel}",
        images=ImageFiles([located[r["token"]] for r in present]),
        positions=positions,
        timestamps=np.asarray([r["timestamp"] for r in present], dtype=np.float64) / 1e6,
        camera=camera if camera is not None else CHANNEL_CAMERA.get(chosen_channel),
        mirror=mirror,
        notes=notes,
        metadata={"vehicle_yaw_deg": vehicle_yaw, "camera_yaw_deg": camera_yaw},
        geometry=geometry,
        odometry=odometry,
    )


def camera_geometry(tables: Tables, record: dict, image: Path) -> CameraGeometry:
    """The calibrated camera of a ``sample_data`` record: intrinsics and camera-to-ego pose from its
    ``calibrated_sensor`` record, for images of the record's size (or, where it gives none, ``image``'s)."""
    sensor = tables.sensors[record["calibrated_sensor_token"]]
    where = f"{tables.folder / 'calibrated_sensor.json'} ({sensor['channel']}, token {sensor['token']})"
    try:
        intrinsics = np.asarray(sensor["camera_intrinsic"], dtype=np.float64)
        rotation = quaternion_matrix(sensor["rotation"])
        translation = np.asarray(sensor["translation"], dtype=np.float64)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: not a camera calibration ({type(exc).__name__}: {exc})") from None
    if intrinsics.shape != (3, 3) or translation.shape != (3,):
        raise InputError(f"{where}: camera_intrinsic must be 3 x 3 and translation 3 numbers")
    width, height = int(record.get("width") or 0), int(record.get("height") or 0)
    if width <= 0 or height <= 0:
        height, width = decode_file(image).shape[:2]
    return CameraGeometry.from_pose(intrinsics, rotation, translation, width, height,
                                    body=CHANNEL_BODY.get(sensor["channel"], 0.0), source=where)


def _records_of_folder(tables: Tables, folder: Path, images: dict[str, Path], scene: str | None,
                       channel: str | None) -> tuple[list[dict], dict[str, Path]]:
    """The records of a folder of nuScenes images: its one channel, its scene (or ``scene``), and its
    kind of frames (key frames, the frames between them, or both)."""
    by_name = {Path(r["filename"]).name: r for r in tables.records}
    unknown = sorted(name for name in images if name not in by_name)
    if unknown:
        raise InputError(f"{folder / unknown[0]}: not in {tables.folder / 'sample_data.json'} "
                         f"({len(unknown)} such images)")
    mine = [by_name[name] for name in images]
    channels = sorted({tables.channel(r) for r in mine})
    if channel is not None and channel not in channels:
        raise InputError(f"{folder} holds {', '.join(channels)} images, not {channel}")
    if len(channels) > 1:
        raise InputError(f"{folder} mixes the channels {', '.join(channels)}; keep one per folder")
    scene = _pick_scene(folder, sorted({tables.scene_name(r) for r in mine}), scene)
    kinds = {r["is_key_frame"] for r in mine}
    chosen = [r for r in tables.records if tables.scene_name(r) == scene and tables.channel(r) == channels[0]
              and r["is_key_frame"] in kinds]
    return chosen, {r["token"]: images[Path(r["filename"]).name] for r in chosen
                    if Path(r["filename"]).name in images}


def _records_of_root(tables: Tables, root: Path, scene: str | None,
                     channel: str) -> tuple[list[dict], dict[str, Path]]:
    """The key frames of ``channel`` at a nuScenes root, with their files where they are: at their
    ``filename`` (a download), or by name in a folder inside ``<root>/<scene name>/``."""
    if channel not in CHANNEL_YAW_DEG:
        raise InputError(f"unknown nuScenes camera channel {channel!r}; expected one of {', '.join(CHANNEL_YAW_DEG)}")
    of_channel = [r for r in tables.records if tables.channel(r) == channel and r["is_key_frame"]]
    located = {}
    copied: dict[str, dict[str, Path]] = {}
    for r in of_channel:
        at = root / r["filename"]
        if not at.is_file():
            name = tables.scene_name(r)
            if name not in copied:
                copied[name] = {p.name: p for p in (root / name).glob("*/*") if p.is_file()}
            at = copied[name].get(Path(r["filename"]).name, at)
        if at.is_file():
            located[r["token"]] = at
    if scene is None:
        scene = _pick_scene(root, sorted({tables.scene_name(r) for r in of_channel if r["token"] in located}), None)
    else:
        _pick_scene(tables.folder, sorted(s["name"] for s in tables.scenes.values()), scene)
    return [r for r in of_channel if tables.scene_name(r) == scene], located


def _pick_scene(where: Path, scenes: list[str], wanted: str | None) -> str:
    """``wanted`` if it is one of ``scenes``, else the only scene; otherwise an error listing them."""
    if wanted is not None:
        if wanted not in scenes:
            raise InputError(f"{where}: no scene {wanted!r}; scenes: {', '.join(scenes[:20]) or 'none'}"
                             f"{', ...' if len(scenes) > 20 else ''}")
        return wanted
    if len(scenes) == 1:
        return scenes[0]
    if not scenes:
        raise InputError(f"{where}: no camera images of any scene of the tables here")
    raise InputError(f"{where} holds {len(scenes)} scenes ({', '.join(scenes[:10])}"
                     f"{', ...' if len(scenes) > 10 else ''}); choose one with --scene")

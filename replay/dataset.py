"""One entry point for every dataset format: a reference/query pair with its ground truth.

Formats (``format=`` or recognised from the folders):

- ``vprbench``: one folder with ``ref/``, ``query/`` and ``ground_truth_new.npy``
  (given as the reference; there is no separate query folder);
- ``robotcar``: RobotCar traverse folders (``stereo/centre/`` and/or ``mono_rear/``,
  timestamps files, ``gps/ins.csv``); the camera of each side is chosen with
  ``reference_camera`` / ``query_camera`` (front = stereo centre, rear = mono rear);
- ``folder``: folders of images in name order with positions CSVs (given, or a
  ``positions.csv`` inside the folder): ground truth by distance in metres;
- ``pairs``: two folders of images in name order where the same index is the
  same place (Nordland, the RobotCar day/night sample): ground truth in frames.

Recognition: a folder with ``ref/`` and ``query/`` is VPR-Bench; one with a
RobotCar camera folder or timestamps file is RobotCar; two plain image folders
are ``folder`` when both have positions, ``pairs`` when neither has.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.core.groundtruth import GroundTruth, Unit, from_indices, from_positions
from lostx.core.images import list_images

from .folder import Traverse, folder_traverse
from .positions import latlon_to_local
from .robotcar import is_robotcar, robotcar_traverse
from .subsample import subsample_by_distance
from .vprbench import is_vprbench, vprbench_pair

Format = Literal["folder", "robotcar", "vprbench", "pairs"]
FORMATS: tuple[str, ...] = ("folder", "robotcar", "vprbench", "pairs")
POSITIONS_FILE = "positions.csv"


@dataclass
class DatasetPair:
    """A reference traverse (the map) and a query traverse, and how to tell which matches are right."""

    reference: Traverse
    query: Traverse
    format: str
    """The format read ('robotcar', 'pairs', ...; 'robotcar+folder' when the two sides differ)."""
    aligned: bool = False
    """Same index (or, after subsampling, same original frame number) = same place."""
    listed: GroundTruth | None = None
    """The dataset's own ground truth lists (VPR-Bench), indexed like the two traverses."""

    @property
    def has_positions(self) -> bool:
        return self.reference.positions is not None and self.query.positions is not None

    @property
    def default_unit(self) -> Unit:
        """Metres when both sides have positions, else frames."""
        return "m" if self.has_positions else "frames"

    @property
    def notes(self) -> list[str]:
        return [*(f"reference: {n}" for n in self.reference.notes), *(f"query: {n}" for n in self.query.notes)]

    def ground_truth(self, tolerances: float | Sequence[float], unit: Unit | None = None) -> list[GroundTruth]:
        """One ground truth per tolerance: a radius in metres, or a number of frames.

        Frames: for index-aligned pairs, ``|r - q| <= tolerance`` on the original frame
        numbers; for VPR-Bench, the listed references widened by ``tolerance`` frames on
        each side (0 = the file as is). Metres: positions within the radius.
        """
        unit = unit or self.default_unit
        if unit == "m":
            if not self.has_positions:
                missing = [s.name for s in (self.reference, self.query) if s.positions is None]
                raise InputError(
                    f"ground truth in metres needs positions for both traverses; none for {', '.join(missing)} "
                    f"(give a positions CSV, or use frame tolerances on an index-aligned pair)"
                )
            ref_xy, query_xy = shared_positions(self.reference, self.query)
            return from_positions(query_xy, ref_xy, tolerances, source="positions")
        if unit != "frames":
            raise InputError(f"tolerance unit must be 'frames' or 'm', got {unit!r}")
        if self.listed is not None:
            return [self.listed.widened(_whole_frames(t)) for t in _tolerance_list(tolerances)]
        if self.aligned:
            ref_places = _places(self.reference)
            query_places = _places(self.query)
            return from_indices(query_places, len(self.reference), tolerances, ref_places, source="index-aligned")
        raise InputError(
            f"frame tolerances need an index-aligned pair (--format pairs) or a dataset with its own ground truth; "
            f"{self.reference.name} and {self.query.name} are neither: use a radius in metres"
        )

    def subsampled(self, spacing: float) -> "DatasetPair":
        """Both traverses with one frame kept every ``spacing`` metres travelled."""
        if self.listed is not None:
            raise InputError("a VPR-Bench ground truth indexes the full image sets; it cannot be subsampled")
        return replace(
            self,
            reference=subsample_by_distance(self.reference, spacing),
            query=subsample_by_distance(self.query, spacing),
        )


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
    camera: Camera = "front",
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
        return robotcar_traverse(path, camera, ins=positions, mirror=mirror)
    if kind in ("folder", "pairs"):
        if positions is None and (path / POSITIONS_FILE).is_file():
            positions = path / POSITIONS_FILE
        return folder_traverse(path, positions, camera, mirror)
    if kind == "vprbench":
        raise InputError(f"{path}: a VPR-Bench folder is a reference/query pair; open it with open_pair")
    raise InputError(f"unknown dataset format {kind!r}; expected one of {', '.join(FORMATS)}")


def open_pair(
    reference: str | Path,
    query: str | Path | None = None,
    format: str | None = None,
    *,
    reference_camera: Camera = "front",
    query_camera: Camera = "front",
    reference_positions: str | Path | None = None,
    query_positions: str | Path | None = None,
    mirror_query: bool = False,
    spacing: float | None = None,
) -> DatasetPair:
    """Read a reference/query pair in any supported format (see the module docstring).

    ``spacing`` subsamples both traverses by distance travelled (metres). The
    result's :meth:`DatasetPair.ground_truth` gives the true sets at any tolerances.
    """
    if format is not None and format not in FORMATS:
        raise InputError(f"unknown dataset format {format!r}; expected one of {', '.join(FORMATS)}")
    reference = Path(reference)
    if format == "vprbench" or (format is None and query is None):
        if query is not None:
            raise InputError(f"a VPR-Bench dataset holds ref/ and query/ in one folder; give only {reference}")
        if not is_vprbench(reference):
            raise InputError(
                f"{reference}: no query folder given, and this is not a VPR-Bench dataset (ref/, query/, "
                f"ground_truth_new.npy)"
            )
        ref, qry, listed = vprbench_pair(reference, query_camera, reference_camera, mirror_query)
        pair = DatasetPair(ref, qry, "vprbench", listed=listed)
        return pair.subsampled(spacing) if spacing else pair
    if query is None:
        raise InputError(f"no query folder given for the {format} reference {reference}")
    query = Path(query)

    kinds = (format, format) if format else (detect_format(reference), detect_format(query))
    for kind, side in zip(kinds, (reference, query)):
        if kind == "vprbench":
            raise InputError(f"{side} is a VPR-Bench dataset (ref/ and query/ inside); give it alone as the reference")
    ref = open_traverse(reference, kinds[0], reference_camera, reference_positions)
    qry = open_traverse(query, kinds[1], query_camera, query_positions, mirror_query)

    if format == "pairs" or (format is None and kinds == ("folder", "folder") and not _any_positions(ref, qry)):
        check_aligned(ref, qry)
        pair = DatasetPair(ref, qry, "pairs", aligned=True)
    else:
        if format is None and kinds == ("folder", "folder") and not (ref.positions is not None and qry.positions is not None):
            without = reference if ref.positions is None else query
            raise InputError(
                f"{without} has no positions but the other folder has: give positions for both (a "
                f"{POSITIONS_FILE} or a CSV), or use --format pairs for index-aligned folders"
            )
        name = kinds[0] if kinds[0] == kinds[1] else f"{kinds[0]}+{kinds[1]}"
        pair = DatasetPair(ref, qry, name)
    return pair.subsampled(spacing) if spacing else pair


def check_aligned(reference: Traverse, query: Traverse) -> None:
    """Index-aligned pairs must have one query per reference frame."""
    if len(reference) != len(query):
        shorter, longer = (reference, query) if len(reference) < len(query) else (query, reference)
        extra = longer.files[len(shorter)]
        raise InputError(
            f"index-aligned pair of different lengths: {reference.root} has {len(reference)} images, "
            f"{query.root} has {len(query)}; index {len(shorter)} ({extra}) has no counterpart"
        )


def shared_positions(reference: Traverse, query: Traverse) -> tuple[np.ndarray, np.ndarray]:
    """Both traverses' positions in one metric frame.

    Positions read as metres (x,y or UTM easting/northing) are used as they are.
    Positions read as latitude/longitude are re-projected about the reference's
    first position, since each traverse was projected about its own first fix.
    """
    assert reference.positions is not None and query.positions is not None
    if (reference.geo is None) != (query.geo is None):
        geo_side = reference if reference.geo is not None else query
        raise InputError(
            f"{geo_side.name} has latitude/longitude positions but the other traverse has metres; "
            f"give both in the same form"
        )
    if reference.geo is None:
        return reference.positions, query.positions
    assert query.geo is not None
    origin = (float(reference.geo[0, 0]), float(reference.geo[0, 1]))
    return (
        latlon_to_local(reference.geo[:, 0], reference.geo[:, 1], origin),
        latlon_to_local(query.geo[:, 0], query.geo[:, 1], origin),
    )


def _any_positions(*traverses: Traverse) -> bool:
    return any(t.positions is not None for t in traverses)


def _places(traverse: Traverse) -> np.ndarray:
    return traverse.source_indices if traverse.source_indices is not None else np.arange(len(traverse))


def _tolerance_list(tolerances: float | Sequence[float]) -> list[float]:
    return [float(tolerances)] if np.isscalar(tolerances) else [float(t) for t in tolerances]  # type: ignore[union-attr]


def _whole_frames(tolerance: float) -> int:
    if tolerance < 0 or tolerance != int(tolerance):
        raise InputError(f"frame tolerance must be a whole number >= 0, got {tolerance}")
    return int(tolerance)

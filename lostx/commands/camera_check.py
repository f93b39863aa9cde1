"""What ``lostx camera check`` shows: a camera's numbers, and the image rows they put the horizon and the
road at, printed and drawn on one of its frames, so that a person sees whether they are right (the
horizon should lie where the road vanishes, the 10 m line on the road 10 m ahead).

Not a command of its own: ``camera.py`` loads it when the check runs (it imports numpy and OpenCV)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lostx.core.geometry import CameraGeometry

DISTANCES = (10.0, 20.0, 40.0)
"""Metres ahead of the camera at which the road's row is shown."""
LATERAL_M = 60.0
"""How far to either side of the camera's axis the road lines are drawn."""
HORIZON_BGR = (0, 220, 255)
ROAD_BGR = (80, 255, 80)
BODY_BGR = (60, 60, 255)


@dataclass(frozen=True)
class Rows:
    """Where the horizon and the road ahead are in a frame, in its pixels."""

    horizon: float
    road: dict[float, float]
    """Distance in metres -> the image row of the road that far ahead (NaN: not in front of the camera)."""


def rows(geometry: CameraGeometry) -> Rows:
    """The rows of the horizon and of the road at :data:`DISTANCES`, for ``geometry``'s frame size."""
    return Rows(geometry.horizon_row(), {d: geometry.ground_row(d) for d in DISTANCES})


def where(row: float, height: int) -> str:
    """A row as printed: its number, and where it falls outside the image."""
    if not np.isfinite(row):
        return "not in view (behind the camera)"
    if row < 0:
        return f"row {row:.1f} (above the image)"
    if row >= height:
        return f"row {row:.1f} (below the image)"
    return f"row {row:.1f}"


def report(geometry: CameraGeometry, calibrated: CameraGeometry) -> list[str]:
    """The lines printed: the numbers as given (``calibrated``), and the rows in the frame's pixels
    (``geometry``, the same camera scaled to the frame)."""
    g, h = calibrated, geometry.height
    lines = [
        f"geometry   from {g.source or 'the source'}",
        f"intrinsics fx {g.fx:.1f}  fy {g.fy:.1f}  cx {g.cx:.1f}  cy {g.cy:.1f} px, for {g.width} x {g.height} frames",
        f"mounting   height {g.z:.3f} m, at x {g.x:.3f} m forward and y {g.y:.3f} m left of the vehicle's origin",
        (f"angles     yaw {g.yaw:.2f}, pitch {g.pitch:.2f}, roll {g.roll:.2f} degrees: a {g.facing} camera "
         f"(yaw anticlockwise from ahead, pitch > 0 looks down, roll > 0 raises the image's right side)"),
        f"body       {g.body:.3f} of the height: rows {round(h * (1 - g.body))} to {h} show the vehicle"
        if g.body > 0 else "body       none (no rows show the vehicle)",
    ]
    if (g.width, g.height) != (geometry.width, geometry.height):
        lines.append(f"scaled     to the frame's {geometry.width} x {geometry.height} pixels; the rows below are "
                     f"in its pixels")
    found = rows(geometry)
    lines.append(f"horizon    {where(found.horizon, h)}")
    lines += [f"{f'road {d:g} m':10s} {where(row, h)}" for d, row in found.road.items()]
    return lines


BODY_CORRELATION = 0.3
"""A row whose detail correlates this well, or better, between consecutive frames stays the same: the vehicle.
(Rows of road and scene, moving past, correlate near 0; the rear camera's boot lid on nuScenes 0.55 to 0.75.)"""
BODY_WIDTH = 400
"""Frames are compared this wide."""
BODY_AGREES = 0.03
"""Within this share of the height the body the frames show agrees with the camera file's."""


def body_detail(image: np.ndarray) -> np.ndarray:
    """What :func:`seen_body` compares of an RGB frame: its gray image :data:`BODY_WIDTH` wide, less its blur."""
    gray = cv2.cvtColor(np.asarray(image), cv2.COLOR_RGB2GRAY)
    height = max(1, round(gray.shape[0] * BODY_WIDTH / gray.shape[1]))
    gray = cv2.resize(gray, (BODY_WIDTH, height), interpolation=cv2.INTER_AREA).astype(np.float32)
    return gray - cv2.GaussianBlur(gray, (0, 0), 3)


def seen_body(details: list[np.ndarray]) -> float:
    """The share of the image height, at the bottom, that stays the same from frame to frame: the vehicle's own
    body (its bonnet, its boot lid). ``details``: :func:`body_detail` of consecutive frames of one camera, the car
    moving.

    Each row is correlated with the same row of the next frame; the median over the pairs marks the rows that do
    not move, counted up from the bottom until the first that does."""
    if len(details) < 2:
        return 0.0
    correlations = []
    for a, b in zip(details, details[1:]):
        norm = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
        correlations.append(np.where(norm > 0, (a * b).sum(axis=1) / np.maximum(norm, 1e-9), 0.0))
    still = (np.median(correlations, axis=0) >= BODY_CORRELATION)[::-1]
    return float(len(still) if still.all() else int(np.argmin(still))) / len(still)


def body_line(seen: float, pairs: int, declared: float) -> str:
    """The printed verdict on the camera file's ``body`` against what ``pairs`` pairs of frames showed."""
    shown = (f"the bottom {100 * seen:.1f} % of the frames stays the same over {pairs} pairs of frames"
             if seen > 0 else f"no rows at the bottom stay the same over {pairs} pairs of frames")
    if abs(seen - declared) <= BODY_AGREES:
        return f"still      {shown}: agrees with body {declared:.3f}"
    if declared == 0:
        return (f"still      {shown}: the vehicle itself? body = {seen:.2f} in the camera file leaves those rows out "
                f"(of the network's view and visual odometry's)")
    return f"still      {shown}: DISAGREES with body {declared:.3f} in the camera file"


def aspect_warning(image_size: tuple[int, int], calibrated: CameraGeometry) -> str | None:
    """A warning where the frame's shape is not the calibration's (scaling cannot make them agree)."""
    width, height = image_size
    if abs(width / height - calibrated.width / calibrated.height) <= 0.01 * calibrated.width / calibrated.height:
        return None
    return (f"the frame is {width} x {height} pixels but the intrinsics are for {calibrated.width} x "
            f"{calibrated.height}, another shape: they belong to another camera or image mode")


def draw(image_rgb: np.ndarray, geometry: CameraGeometry) -> np.ndarray:
    """The frame (BGR, for writing) with the body's rows shaded, the horizon and the road lines drawn and
    labelled. ``geometry`` is for the frame's size."""
    out = np.ascontiguousarray(image_rgb[:, :, ::-1]).copy()
    height, width = out.shape[:2]
    scale = max(height / 900.0, 0.4)
    if geometry.body > 0:
        top = round(height * (1 - geometry.body))
        shade = out.copy()
        cv2.rectangle(shade, (0, top), (width - 1, height - 1), BODY_BGR, -1)
        out = cv2.addWeighted(shade, 0.35, out, 0.65, 0)
        _label(out, f"body ({geometry.body:.2f})", (8, top - int(8 * scale)), BODY_BGR, scale)
    left, right = geometry.horizon_row(0.0), geometry.horizon_row(width - 1.0)
    if np.isfinite(left) and np.isfinite(right):
        _line(out, [(0.0, left), (width - 1.0, right)], HORIZON_BGR, scale)
        _label(out, f"horizon (row {geometry.horizon_row():.0f})", (8, int(left) - int(8 * scale)), HORIZON_BGR,
               scale)
    for distance in DISTANCES:
        points = road_line(geometry, distance)
        if len(points) >= 2:
            _line(out, points, ROAD_BGR, scale)
            row = geometry.ground_row(distance)
            anchor = min(points, key=lambda p: abs(p[0] - geometry.cx))
            _label(out, f"{distance:g} m (row {row:.0f})", (int(anchor[0]) + int(10 * scale),
                                                           int(anchor[1]) - int(8 * scale)), ROAD_BGR, scale)
    return out


def road_line(geometry: CameraGeometry, distance: float) -> list[tuple[float, float]]:
    """Pixels of the road ``distance`` metres ahead of the camera, across :data:`LATERAL_M` to either side."""
    forward = geometry.rotation[:2, 2]
    forward = forward / np.linalg.norm(forward)
    left = np.array([-forward[1], forward[0]])
    lateral = np.linspace(-LATERAL_M, LATERAL_M, 121)
    ground = geometry.position[:2] + distance * forward + lateral[:, None] * left
    pixels, ahead = geometry.project(np.column_stack([ground, np.zeros(len(ground))]))
    return [(float(u), float(v)) for (u, v), ok in zip(pixels, ahead) if ok and np.isfinite(u) and np.isfinite(v)]


def _line(image: np.ndarray, points: list[tuple[float, float]], colour: tuple[int, int, int], scale: float) -> None:
    # OpenCV clips polylines to the image; far-off points are bounded so its integer maths cannot overflow.
    bounded = np.clip(np.asarray(points), -1e5, 1e5).round().astype(np.int32)
    thickness = max(1, round(2 * scale))
    cv2.polylines(image, [bounded], False, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.polylines(image, [bounded], False, colour, thickness, cv2.LINE_AA)


def _label(image: np.ndarray, text: str, at: tuple[int, int], colour: tuple[int, int, int], scale: float) -> None:
    height, width = image.shape[:2]
    x = int(np.clip(at[0], 2, width - 2))
    y = int(np.clip(at[1], int(24 * scale), height - 4))
    size = 0.8 * scale
    thickness = max(1, round(2 * scale))
    cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, size, (0, 0, 0), thickness + 3, cv2.LINE_AA)
    cv2.putText(image, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, size, colour, thickness, cv2.LINE_AA)

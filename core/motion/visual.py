"""Monocular visual odometry of one camera, made metric by its height over the road.

The fallback motion source for recordings without odometry. Between two consecutive frames of one camera:

1. Turn and direction of travel: corners (GFTT) tracked with pyramidal Lucas-Kanade, checked forward and
   backward and started where the last step's motion puts them; the essential matrix (MAGSAC) and its pose.
   Where that finds no motion a car can make (the first step, a step much longer or a turn much sharper than the
   last: a low frame rate, a fast car), SIFT keypoints matched by their descriptors, which need no guess.
2. Length: the road plane maps the pixels of one frame into the other by the homography
   ``H(s) = K (R - s t n^T / h) K^-1`` for a travel of ``s`` metres (``t`` the unit direction, ``n`` the road's
   normal, ``h`` the camera's height). A search over ``s`` maximises the mean normalised cross-correlation of
   small patches of road texture, coarse to fine (half size, then full size); on the full-size level ``n`` is also
   tilted up to 2 degrees about the camera's x axis, so that a pitch a degree off in the camera file (8 % of every
   length) or a road sloping away from the car's plane does not scale the step. Only pixels whose image gradient
   lies along their flow take part: lane lines running with the motion look the same at any ``s``.
3. A Kalman filter on the step length (filterpy) takes each length, weighted by the step's quality, and gates
   outliers. A step a car cannot make (sideways, a turn of over 30 degrees, a reversal at speed) is not taken.
   Where nothing is measured the step is predicted: the last speed and direction, and the last turn (halved for
   each further step predicted in a row).

4. A check of the camera's pitch: a car travels parallel to the road, so the direction of travel that the
   essential matrix gives lies on the horizon, and its elevation in the image is the camera's pitch. After
   ``PITCH_CHECK_STEPS`` steps along the camera's axis, a median that differs from the geometry's pitch by more
   than ``PITCH_CHECK_DEG`` is said once (:class:`CameraPitchWarning`). It is a check, not a correction: on
   nuScenes it lies 0.3 and 0.6 degrees from the calibration, and the layout needs less than half a degree.

The search runs from the frame in which the stretch of road both frames see is nearer: the current one while
the camera moves forward along its axis (a front camera), the previous one while it moves backwards (a rear
camera); where the step's direction says the camera moved the other way than the last step (or, at the start,
its facing) had it, the length is searched again from the other frame (a rear camera played backwards, a car
reversing). The road is the ``ground`` mask where one is given, else the image of the road plane 4-25 m ahead and
within 8 m to either side; ``movers`` (and the rows of the vehicle's own body, ``geometry.body``) are never looked
at. Costs about 50-70 ms per frame at 800 x 450 on one core, and about 80 ms more for a frame whose keypoints
are matched.

Motions are given in the camera's ground frame: on the road under the camera, x along its level optical axis,
y to its left (:func:`.pose.camera_on_vehicle`). The rear camera of a car driving forward moves backwards in it.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import cv2
import numpy as np
from filterpy.kalman import KalmanFilter

from ..geometry import CameraGeometry
from .pose import inverse

__all__ = ["CameraPitchWarning", "Step", "VisualOdometry"]

NEAR_M, FAR_M, SIDE_M = 4.0, 25.0, 8.0
"""The road used for the length: 4-25 m ahead of the camera along its axis, within 8 m to either side (and in the
``ground`` mask where one is given)."""
LENGTH_RANGE_M = (0.05, 12.0)
"""The lengths of one step the search considers."""

PITCH_CHECK_STEPS = 15
"""Steps along the camera's axis whose direction of travel is measured before the pitch is checked."""
PITCH_CHECK_DEG = 1.5
"""A pitch this far from the geometry's is said (the direction's own error on real frames is about half this)."""
PITCH_SAMPLES = 100
"""Directions of travel kept for :meth:`VisualOdometry.seen_pitch` (the first ones; a stream may run for days)."""
_ALONG_AXIS = 0.95  # a step's direction counts for the pitch where its component along the camera's axis is this

# Tracking and the essential matrix (pixels at the working size).
_LK = {"winSize": (15, 15), "maxLevel": 3, "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}
_FEATURES = 800
_MIN_TRACKS = 30  # fewer tracks, or fewer inliers of the essential matrix: no measurement
_STILL_PX = 0.25  # a median flow under this: standing still
_SIFT_FEATURES = 2000  # where tracking from the guess fails: keypoints matched by their descriptors
_MATCH_RATIO = 0.8  # a match's distance against the second nearest's
# The length search.
_PATCH = 2  # patches of (2 * _PATCH + 1)^2 pixels of their level
_PATCHES = 1200
_PYRAMID = ((1, 300), (0, 1200))  # the search's levels (0 full size, 1 half), coarse first, and their patches
_COARSE_STEP = 1.10  # ratio of neighbouring lengths on the coarse level's grid
_TILTS = tuple(math.radians(a) for a in (-2.0, -1.0, 0.0, 1.0, 2.0))  # the road's tilts tried on the finest level
# What a car can do between frames.
_SLIP_DEG = 8.0  # how far off the camera's axis (beyond the turn) a step may head
_MAX_TURN_DEG = 30.0


class CameraPitchWarning(UserWarning):
    """The frames' direction of travel disagrees with the camera geometry's pitch."""


@dataclass(frozen=True)
class Step:
    motion: np.ndarray
    """(3,) dx, dy (metres), dyaw (radians): the current camera ground frame in the previous one."""
    quality: float
    """In [0, 1]; low where the measurement was weak (the filter then predicted)."""
    measured: bool
    """False where the step is the filter's prediction only."""


class VisualOdometry:
    """Motion of one camera between consecutive frames of a stream."""

    def __init__(self, geometry: CameraGeometry, width: int = 800) -> None:
        self.geometry = geometry
        self.width = int(width)
        self._view: _View | None = None
        self._elevations: list[float] = []  # degrees, of the directions of travel measured so far
        self.reset()

    def reset(self) -> None:
        self._previous: _Frame | None = None
        self._length = _LengthFilter()
        self._last: np.ndarray | None = None  # the last step's motion: the guess for the next
        self._unmeasured = 0  # steps predicted in a row

    def state(self) -> dict:
        """What carries to the next frame, as plain values and arrays: the previous frame at the working size (its
        band-passed pyramid is recomputed from it), the step length's filter and the last step."""
        previous = self._previous
        return {"previous": None if previous is None else {"gray": previous.gray, "usable": previous.usable,
                                                           "road": previous.road},
                "length": self._length.state(), "last": self._last, "unmeasured": self._unmeasured}

    def restore(self, state: dict) -> None:
        """Continue from :meth:`state` (of visual odometry on the same camera)."""
        self.reset()
        previous = state["previous"]
        if previous is not None:
            gray = np.asarray(previous["gray"], dtype=np.uint8)
            if self._view is None or self._view.shape != gray.shape:
                self._view = _View(self.geometry, gray.shape)
            self._previous = _Frame(gray, _detail(gray), np.asarray(previous["usable"], dtype=np.uint8),
                                    np.asarray(previous["road"], dtype=bool))
        self._length.restore(state["length"])
        self._last = None if state["last"] is None else np.asarray(state["last"], dtype=np.float64)
        self._unmeasured = int(state["unmeasured"])

    def step(self, image: np.ndarray, ground: np.ndarray | None = None,
             movers: np.ndarray | None = None) -> Step | None:
        """image: RGB uint8 H x W x 3 (the geometry is scaled to its size with geometry.scaled_to). ground / movers:
        optional boolean masks at any resolution covering the whole frame (road-plane pixels; pixels of things
        that move: cars, people), e.g. from a segmentation. Returns None for the first frame after a reset."""
        gray = _working_gray(image, self.width)
        if self._view is None or self._view.shape != gray.shape:
            self._view = _View(self.geometry, gray.shape)
            self._previous = None
        frame = self._view.frame(gray, ground, movers)
        previous, self._previous = self._previous, frame
        if previous is None:
            return None
        measurement = self._measure(previous, frame)
        if measurement is not None and measurement.elevation is not None:
            self._check_pitch(measurement.elevation)
        return self._filtered(measurement)

    def seen_pitch(self) -> tuple[float, int] | None:
        """The camera's pitch (degrees, positive looking down) that the directions of travel measured so far put it
        at (their median), and how many there were; None before the first."""
        if not self._elevations:
            return None
        return float(np.median(self._elevations)), len(self._elevations)

    def _check_pitch(self, elevation: float) -> None:
        """Gather the elevation of a direction of travel (up to ``PITCH_SAMPLES``); at the ``PITCH_CHECK_STEPS``-th,
        say once whether their median disagrees with the geometry's pitch."""
        if len(self._elevations) < PITCH_SAMPLES:
            self._elevations.append(elevation)
        if len(self._elevations) != PITCH_CHECK_STEPS:
            return
        seen, declared = float(np.median(self._elevations)), self.geometry.pitch
        if abs(seen - declared) > PITCH_CHECK_DEG:
            where = f"{self.geometry.source}: " if self.geometry.source else ""
            warnings.warn(f"{where}the direction of travel in the frames puts the camera's pitch at {seen:.1f} "
                          f"degrees (positive looking down), its geometry says {declared:.1f}: ground distances and "
                          f"the layout depend on it to within half a degree; check the camera file with "
                          f"'lostx camera check'", CameraPitchWarning, stacklevel=3)

    def _measure(self, previous: _Frame, current: _Frame) -> _Measurement | None:
        """The current frame's pose in the previous one's, from the frames alone."""
        guess = self._last if self._last is not None else np.zeros(3)
        backwards = guess[0] < -0.1 or (abs(guess[0]) <= 0.1 and self.geometry.facing == "rear")
        measurement = self._measure_from(previous, current, guess, backwards)
        if measurement is None or not (measurement.still or self._plausible(measurement.pose)):
            matched = self._measure_from(previous, current, None, backwards)
            if matched is not None and self._plausible(matched.pose):
                measurement, guess = matched, None
        if (measurement is not None and not measurement.still and measurement.quality < _LengthFilter.MIN_QUALITY
                and (measurement.pose[0] < 0) != backwards):
            # The camera moved the other way along its axis than the last step (or its facing) said: the length is
            # searched again from the frame in which the road both frames see is nearer.
            other = self._measure_from(previous, current, guess, not backwards)
            if other is not None and other.quality > measurement.quality and self._plausible(other.pose):
                measurement = other
        return measurement

    def _measure_from(self, previous: _Frame, current: _Frame, guess: np.ndarray | None,
                      backwards: bool) -> _Measurement | None:
        """The measurement searched from the frame in which the stretch of road both frames see is nearer."""
        assert self._view is not None
        if backwards:
            return self._view.measure(previous, current, guess)
        measurement = self._view.measure(current, previous, None if guess is None else inverse(guess))
        return None if measurement is None else replace(measurement, pose=inverse(measurement.pose))

    def _filtered(self, m: _Measurement | None) -> Step:
        """The step from the measurement and the filter's prediction.

        A plausible measurement gives the turn and the direction of travel, and its length where the filter takes
        it. Where there is none, the step is predicted: the last step's speed and direction, and its turn for one
        step, halved for each further step without a measurement (turns end; a rate held for long drifts)."""
        quality = 0.0 if m is None else m.quality
        if m is not None and m.still:
            self._length = _LengthFilter()  # at rest now, and no idea how fast next: the next length decides
            self._last, self._unmeasured = np.zeros(3), 0
            return Step(self._last.copy(), quality, True)
        last = self._last if self._last is not None else np.zeros(3)
        if m is not None and self._plausible(m.pose):
            heading, turn = math.atan2(m.pose[1], m.pose[0]), float(m.pose[2])
            length, measured = self._length.update(float(np.hypot(m.pose[0], m.pose[1])), quality)
            self._unmeasured = 0
        else:
            heading, turn = math.atan2(last[1], last[0]), float(last[2]) * (0.5 if self._unmeasured else 1.0)
            length, measured = self._length.predict(), False
            self._unmeasured += 1
        self._last = np.array([length * math.cos(heading), length * math.sin(heading), turn])
        return Step(self._last.copy(), float(quality), bool(measured))

    def _plausible(self, pose: np.ndarray) -> bool:
        """Whether a measured step is one a car makes: along the camera's axis, forwards or backwards, give or
        take its turn and a margin (it does not slide sideways), a turn under 30 degrees, and no reversal at
        speed from one frame to the next."""
        heading, turn = math.atan2(pose[1], pose[0]), abs(float(pose[2]))
        off_axis = min(abs(heading), math.pi - abs(heading))
        if off_axis > turn + math.radians(_SLIP_DEG) or turn > math.radians(_MAX_TURN_DEG):
            return False
        last = self._last
        return last is None or np.hypot(last[0], last[1]) < 0.3 or last[0] * pose[0] > 0


@dataclass(frozen=True)
class _Measurement:
    pose: np.ndarray  # (3,) the target frame's ground pose in the source frame's
    quality: float  # of the length; the direction and turn hold wherever there is a measurement
    still: bool = False
    elevation: float | None = None  # degrees: of the direction of travel in the image (a step along the axis)


@dataclass
class _Frame:
    """One frame at the working size, as the measurement needs it."""

    gray: np.ndarray  # uint8 at working size
    detail: list[np.ndarray]  # float32 band-pass of gray's pyramid (full size, half, ...): what patches compare
    usable: np.ndarray  # uint8 255 where features and samples may lie: not the vehicle's body, not movers
    road: np.ndarray  # bool: road pixels within the range band
    _gradient: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def gradient(self) -> tuple[np.ndarray, np.ndarray]:
        if self._gradient is None:
            d = self.detail[0]
            self._gradient = (cv2.Sobel(d, cv2.CV_32F, 1, 0), cv2.Sobel(d, cv2.CV_32F, 0, 1))
        return self._gradient


class _View:
    """The camera at one working size: intrinsics, its pose in its ground frame, the fixed masks."""

    def __init__(self, geometry: CameraGeometry, shape: tuple[int, int]) -> None:
        height, width = shape
        g = geometry.scaled_to(width, height)
        level = replace(g, x=0.0, y=0.0, yaw=0.0)  # the camera in its own ground frame
        self.shape = shape
        self.K = np.array([[g.fx, 0.0, g.cx], [0.0, g.fy, g.cy], [0.0, 0.0, 1.0]])
        self.K_inv = np.linalg.inv(self.K)
        self.R = level.rotation  # camera axes in the ground frame
        self.h = g.z
        self.normal = self.R[2].copy()  # the road's up direction in camera coordinates
        self.usable = np.full(shape, 255, np.uint8)
        self.usable[math.floor(height * (1.0 - g.body)):] = 0
        v, u = np.mgrid[0:height, 0:width]
        xy, below = level.ground(u, v)
        with np.errstate(invalid="ignore"):
            self.band = below & (xy[..., 0] >= NEAR_M) & (xy[..., 0] <= FAR_M) & (np.abs(xy[..., 1]) <= SIDE_M)
        self.band &= self.usable > 0
        self.ring = max(3, round(width / 100))  # margin kept from movers and the road's edges, in pixels

    def frame(self, gray: np.ndarray, ground: np.ndarray | None, movers: np.ndarray | None) -> _Frame:
        detail = _detail(gray)
        usable = self.usable
        if movers is not None:
            moving = cv2.dilate(_resized(movers, self.shape), np.ones((2 * self.ring + 1,) * 2, np.uint8))
            usable = np.where(moving > 0, 0, usable).astype(np.uint8)
        road = self.band & (usable > 0)
        if ground is not None:
            kernel = np.ones((2 * (self.ring // 2) + 1,) * 2, np.uint8)
            road &= cv2.erode(_resized(ground, self.shape), kernel) > 0
        return _Frame(gray, detail, usable, road)

    # Motion between the camera frames: X_target = R X_source + t (camera coordinates).

    def camera_motion(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of a planar ground pose (the target frame's ground pose in the source frame's)."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        turn_back = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        return self.R.T @ turn_back @ self.R, self.R.T @ turn_back @ np.array([-pose[0], -pose[1], 0.0])

    def ground_pose(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """The planar ground pose of the camera motion (R, t): inverse of :meth:`camera_motion`."""
        turn = self.R @ R.T @ self.R.T
        position = -self.R @ R.T @ t
        return np.array([position[0], position[1], math.atan2(turn[1, 0], turn[0, 0])])

    def tilted(self, angle: float) -> np.ndarray:
        """The road's normal in camera coordinates tilted ``angle`` radians about the camera's x axis (positive: the
        road rising ahead of the camera, as if it looked further down)."""
        if angle == 0.0:
            return self.normal
        c, s = math.cos(angle), math.sin(angle)
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]) @ self.normal

    def homography(self, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Source pixels to target pixels for points on the road plane."""
        return self.K @ (R - np.outer(t, self.normal) / self.h) @ self.K_inv

    # The measurement.

    def measure(self, source: _Frame, target: _Frame, guess: np.ndarray | None) -> _Measurement | None:
        """The target frame's ground pose in the source frame's; None where the frames do not say. The points are
        tracked from where the ``guess`` puts them; without one (the step is longer, or the turn sharper, than the
        guess allows), keypoints are matched by their descriptors anywhere in the frames."""
        if guess is not None:
            tracks = self._tracks(source, target, guess)
            if tracks is not None and np.median(np.linalg.norm(tracks[1] - tracks[0], axis=1)) < _STILL_PX:
                return _Measurement(np.zeros(3), 1.0, still=True)
        else:
            tracks = self._matches(source, target)
        motion = None if tracks is None else self._essential(*tracks)
        if motion is None:
            return None
        R, t, n_inliers = motion
        elevation = _elevation(R, t)
        length, sharpness = self._length(source, target, R, t)
        if length is None:
            return _Measurement(self.ground_pose(R, t), 0.0, elevation=elevation)  # the direction alone: unit length
        quality = sharpness * min(1.0, n_inliers / 60.0)
        return _Measurement(self.ground_pose(R, length * t), float(quality), elevation=elevation)

    def _essential(self, p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, int] | None:
        """The rotation and unit translation of the camera between corresponding points, and the inliers' count."""
        E, inliers = cv2.findEssentialMat(p0, p1, self.K, cv2.USAC_MAGSAC, 0.999, 0.75)
        if E is None or E.shape[0] < 3:
            return None
        n_inliers, R, t, _ = cv2.recoverPose(E[:3], p0, p1, self.K, mask=inliers)
        if n_inliers < _MIN_TRACKS:
            return None
        return R, t.ravel(), int(n_inliers)

    def _matches(self, source: _Frame, target: _Frame) -> tuple[np.ndarray, np.ndarray] | None:
        """Corresponding points of the two frames from SIFT keypoints matched both ways by their descriptors (the
        nearest clearly nearer than the second): slower than tracking, but they need no guess and survive the
        change of scale of a long step."""
        sift = cv2.SIFT_create(_SIFT_FEATURES)
        k0, d0 = sift.detectAndCompute(source.gray, source.usable)
        k1, d1 = sift.detectAndCompute(target.gray, target.usable)
        if d0 is None or d1 is None or len(k0) < _MIN_TRACKS or len(k1) < _MIN_TRACKS:
            return None
        matcher = cv2.BFMatcher(cv2.NORM_L2)
        forward = matcher.knnMatch(d0, d1, k=2)
        backward = {m.queryIdx: m.trainIdx for m in matcher.match(d1, d0)}
        pairs = [(m.queryIdx, m.trainIdx) for m, *rest in (f for f in forward if f)
                 if (not rest or m.distance < _MATCH_RATIO * rest[0].distance)
                 and backward.get(m.trainIdx) == m.queryIdx]
        if len(pairs) < _MIN_TRACKS:
            return None
        i0, i1 = np.array(pairs).T
        p0 = np.array([k0[i].pt for i in i0], dtype=np.float32)
        p1 = np.array([k1[i].pt for i in i1], dtype=np.float32)
        return p0, p1

    def _tracks(self, source: _Frame, target: _Frame, guess: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        p0 = cv2.goodFeaturesToTrack(source.gray, _FEATURES, 0.01, 8, mask=source.usable, blockSize=7)
        if p0 is None or len(p0) < _MIN_TRACKS:
            return None
        p0 = p0.reshape(-1, 2)
        # Start the search where the guessed motion takes the points: the road's by the plane, the rest as if far.
        R, t = self.camera_motion(guess)
        near = self._on_road(p0, within=40.0)
        start = np.where(near[:, None], _apply(self.homography(R, t), p0), _apply(self.K @ R @ self.K_inv, p0))
        start = np.where(np.isfinite(start), start, p0)
        p1, found, _ = cv2.calcOpticalFlowPyrLK(source.gray, target.gray, p0, start.astype(np.float32),
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_LK)
        back, found_back, _ = cv2.calcOpticalFlowPyrLK(target.gray, source.gray, p1, p0.copy(),
                                                       flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_LK)
        height, width = self.shape
        ok = (found.ravel() == 1) & (found_back.ravel() == 1) & (np.linalg.norm(back - p0, axis=1) < 1.0)
        ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= width - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= height - 1)
        if ok.sum() < _MIN_TRACKS:
            return None
        return p0[ok], p1[ok]

    def _on_road(self, points: np.ndarray, within: float) -> np.ndarray:
        """Whether the rays of pixels meet the road within ``within`` metres."""
        rays = (np.c_[points, np.ones(len(points))] @ self.K_inv.T) @ self.R.T
        down = rays[:, 2] < -1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            reach = self.h * np.hypot(rays[:, 0], rays[:, 1]) / -rays[:, 2]
        return down & (reach < within)

    def _length(self, source: _Frame, target: _Frame, R: np.ndarray, t: np.ndarray) -> tuple[float | None, float]:
        """The length of the unit translation t that best maps the source's road onto the target's (the road tilted as
        fits it best), and how sharply the correlation peaks there (0 to 1)."""
        centres = self._road_samples(source, R, t)
        if centres is None:
            return None, 0.0
        return _best_length([_Level(self, source, target, R, t, centres[:n], level) for level, n in _PYRAMID])

    def _road_samples(self, source: _Frame, R: np.ndarray, t: np.ndarray) -> np.ndarray | None:
        """(N, 2) centres of road patches whose gradient lies along their flow under the motion's direction."""
        stride = 3
        mask = np.zeros(self.shape, bool)
        mask[::stride, ::stride] = source.road[::stride, ::stride]
        v, u = np.nonzero(mask)
        if len(u) < 100:
            return None
        points = np.c_[u, v].astype(np.float64)
        flow = _apply(self.homography(R, t), points) - _apply(self.K @ R @ self.K_inv, points)
        flow /= np.linalg.norm(flow, axis=1, keepdims=True) + 1e-9
        gx, gy = source.gradient
        along = np.abs(gx[v, u] * flow[:, 0] + gy[v, u] * flow[:, 1])
        keep = along >= np.quantile(along, 0.75)
        points = points[keep]
        return points[np.random.default_rng(0).permutation(len(points))[:_PATCHES]]  # any prefix spreads out


class _Level:
    """The source's road patches at one level of the image pyramid, and their mean correlation with the target
    where H(s) puts them, for many s at once."""

    def __init__(self, view: _View, source: _Frame, target: _Frame, R: np.ndarray, t: np.ndarray,
                 centres: np.ndarray, level: int) -> None:
        self.zoom = 0.5 ** level
        offsets = np.arange(-_PATCH, _PATCH + 1) / self.zoom  # a patch spans (2 * _PATCH + 1) pixels of its level
        du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
        self.size, self.n = len(du), len(centres)
        u = (centres[:, :1] + du).ravel()
        v = (centres[:, 1:] + dv).ravel()
        x = np.stack([u, v, np.ones_like(u)])
        # H(s) x = rotated - s * shifted, in the level's pixels (as cv2.pyrDown places them)
        to_level = np.array([[self.zoom, 0.0, 0.5 * self.zoom - 0.5], [0.0, self.zoom, 0.5 * self.zoom - 0.5],
                             [0.0, 0.0, 1.0]])
        self.rotated = (to_level @ view.K @ R @ view.K_inv @ x).astype(np.float32)
        # (t n^T / h) x = t (n . ray) / h: the direction in the level's pixels, and each pixel's ray to meet the road
        self.direction = (to_level @ view.K @ t).astype(np.float32)[:, None]
        self.rays = (view.K_inv @ x / view.h).astype(np.float32)
        self.view = view
        self.detail = target.detail[level]
        height, width = self.detail.shape
        margin = _PATCH + 1
        self.bounds = (margin, width - 1 - margin, margin, height - 1 - margin)
        self.usable = cv2.resize(target.usable, (width, height), interpolation=cv2.INTER_NEAREST)
        a = self._sample(source.detail[level], (to_level @ x)[:1], (to_level @ x)[1:2])[0]
        a -= a.mean(axis=1, keepdims=True)
        self.a = a / (np.linalg.norm(a, axis=1, keepdims=True) + 1e-6)  # zero mean, unit norm

    def _sample(self, image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(S, n, size) bilinear samples of the level's image at (S, n * size) positions."""
        shape = (len(u) * self.size, self.n)  # cv2.remap takes maps of under 32767 rows and columns
        mu, mv = u.astype(np.float32).reshape(shape), v.astype(np.float32).reshape(shape)
        return cv2.remap(image, mu, mv, cv2.INTER_LINEAR).reshape(len(u), self.n, self.size)

    def scores(self, lengths: np.ndarray, tilt: float = 0.0) -> np.ndarray:
        """The mean patch correlation for each length, the road's normal tilted ``tilt`` radians about the camera's
        x axis (patches that leave the view or land on the vehicle's body or a mover count as 0)."""
        s = np.asarray(lengths, dtype=np.float32)[:, None]
        shifted = self.direction * (self.view.tilted(tilt).astype(np.float32) @ self.rays)[None, :]
        z = np.maximum(self.rotated[2] - s * shifted[2], 1e-6)
        u = (self.rotated[0] - s * shifted[0]) / z
        v = (self.rotated[1] - s * shifted[1]) / z
        centre = self.size // 2
        cu = u.reshape(len(s), self.n, self.size)[..., centre]
        cv_ = v.reshape(len(s), self.n, self.size)[..., centre]
        left, right, top, bottom = self.bounds
        inside = (cu > left) & (cu < right) & (cv_ > top) & (cv_ < bottom)
        inside[inside] = self.usable[cv_[inside].astype(np.intp), cu[inside].astype(np.intp)] > 0
        b = self._sample(self.detail, u, v)
        # a has zero mean, so a . (b - mean b) = a . b
        spread = np.maximum(np.einsum("spk,spk->sp", b, b) - b.sum(axis=2) ** 2 / self.size, 0.0)
        ncc = np.einsum("spk,pk->sp", b, self.a) / (np.sqrt(spread) + 1e-6)
        return np.where(inside, ncc, 0.0).sum(axis=1) / self.n


def _best_length(levels: list[_Level]) -> tuple[float | None, float]:
    """The length that maximises the mean patch correlation, and how clearly the correlation peaks there (0 to 1).

    Searched coarse to fine: the whole range on the coarsest level, then around the best length on each finer
    one, the finest jointly with the road's tilt about the camera's x axis (``_TILTS``: what the geometry's pitch
    misses, a degree being 8 % of every length, and the road's own slope), finished by a parabola. How sharply
    the correlation peaks is taken at the length found, tilted as found or as the geometry has it, and at the
    geometry's own best length: the clearest of the three."""
    lo, hi = LENGTH_RANGE_M
    step = math.log(_COARSE_STEP)
    grid = np.exp(np.arange(math.log(lo), math.log(hi) + step, step))
    scores = levels[0].scores(grid)
    k = int(np.argmax(scores))
    if scores[k] <= 0:
        return None, 0.0
    length, tilt = float(grid[k]), 0.0
    for index, level in enumerate(levels[1:], start=1):
        tilts = _TILTS if index == len(levels) - 1 else (0.0,)
        around = length * np.exp(np.linspace(-step, step, 5))
        table = np.stack([level.scores(around * _tilt_scale(a), a) for a in tilts])
        plain = float(around[int(np.argmax(table[tilts.index(0.0)]))])  # the geometry's own best
        i, j = np.unravel_index(int(np.argmax(table)), table.shape)
        tilt = float(tilts[i])
        values, around = table[i], around * _tilt_scale(tilt)
        length, step = float(around[j]), step / 2
    if 0 < j < len(around) - 1:
        y0, y1, y2 = values[j - 1: j + 2]
        curvature = y0 - 2 * y1 + y2
        if curvature < 0:
            length *= math.exp(0.5 * (y0 - y2) / curvature * step)
    away = scores[np.abs(np.log(grid / length)) > 0.35]
    second = float(away.max()) if len(away) else -1.0
    distinct = np.clip((scores[k] - second) / 0.15, 0, 1)
    peaks = []
    for a, at in {(tilt, length), (0.0, length), (0.0, plain)}:
        peak, below, above = levels[-1].scores([at, at / 1.25, at * 1.25], a)
        peaks.append(np.clip((peak - max(below, above) - 0.1) / 0.25, 0, 1))
    return length, float(max(peaks) * distinct)


def _tilt_scale(tilt: float) -> float:
    """Where the road tilted by ``tilt`` puts the length found untilted: about 8 % shorter per degree (the road's
    patches 4-25 m away, seen from about 1.5 m up)."""
    return math.exp(-0.08 * math.degrees(tilt))


class _LengthFilter:
    """A 1-D Kalman filter on the length of a step (metres per frame, constant speed), gating outliers.

    Noises are 5 cm + 5 % of the length, the measurement's divided by its quality. A length of quality under
    ``MIN_QUALITY`` is not taken, nor one far from the prediction: over ``GATE`` standard deviations of the
    innovation, or over ``CHANGE`` times longer or shorter (give or take ``SLACK`` metres; a car's speed does not
    change that much between frames). Where ``RESTART`` such lengths in a row agree with one another, the speed
    really changed (or the filter had locked on a wrong one): it restarts from the latest."""

    GATE = 3.0
    CHANGE, SLACK = 1.5, 0.3
    RESTART = 3
    MIN_QUALITY = 0.05

    def __init__(self) -> None:
        self.kf: KalmanFilter | None = None
        self.rejected: list[float] = []

    @staticmethod
    def _process_sigma(length: float) -> float:
        return 0.05 + 0.05 * length

    @staticmethod
    def _measurement_sigma(length: float, quality: float) -> float:
        return (0.05 + 0.05 * length) / max(quality, 0.02)

    def restart(self, length: float, quality: float = 1.0) -> None:
        kf = KalmanFilter(dim_x=1, dim_z=1)
        kf.x = np.array([[length]])
        kf.P = np.array([[self._measurement_sigma(length, quality) ** 2]])
        kf.F = kf.H = np.eye(1)
        self.kf = kf
        self.rejected.clear()

    def predict(self) -> float:
        if self.kf is None:
            return 0.0
        self.kf.predict(Q=self._process_sigma(float(self.kf.x[0, 0])) ** 2)
        return max(0.0, float(self.kf.x[0, 0]))

    def update(self, z: float, quality: float) -> tuple[float, bool]:
        """The filtered length after measuring z, and whether z was taken."""
        if quality < self.MIN_QUALITY:
            return self.predict(), False
        if self.kf is None:
            self.restart(z, quality)
            return z, True
        predicted = self.predict()
        kf = self.kf
        r = self._measurement_sigma(predicted, quality) ** 2
        far = (z - float(kf.x[0, 0])) ** 2 > self.GATE ** 2 * (float(kf.P[0, 0]) + r)
        if far or not predicted / self.CHANGE - self.SLACK <= z <= predicted * self.CHANGE + self.SLACK:
            self.rejected = [*self.rejected[1 - self.RESTART:], z]
            recent = self.rejected
            if len(recent) == self.RESTART and max(recent) <= 1.2 * min(recent) + 0.1:
                self.restart(z, quality)
                return z, True
            return predicted, False
        self.rejected.clear()
        kf.update(np.array([[z]]), R=r)
        return max(0.0, float(kf.x[0, 0])), True

    def state(self) -> dict:
        return {"x": None if self.kf is None else self.kf.x, "P": None if self.kf is None else self.kf.P,
                "rejected": list(self.rejected)}

    def restore(self, state: dict) -> None:
        self.kf, self.rejected = None, [float(z) for z in state["rejected"]]
        if state["x"] is not None:
            self.restart(0.0)
            assert self.kf is not None
            self.kf.x = np.asarray(state["x"], dtype=np.float64).reshape(1, 1)
            self.kf.P = np.asarray(state["P"], dtype=np.float64).reshape(1, 1)
            self.rejected = [float(z) for z in state["rejected"]]


def _working_gray(image: np.ndarray, width: int) -> np.ndarray:
    image = np.asarray(image)
    gray = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    if gray.dtype != np.uint8:
        gray = np.clip(gray, 0, 255).astype(np.uint8)
    height, w = gray.shape
    if w > width:
        gray = cv2.resize(gray, (width, max(1, round(height * width / w))), interpolation=cv2.INTER_AREA)
    return gray


def _detail(gray: np.ndarray) -> list[np.ndarray]:
    """The band-passed pyramid of a working-size frame, every level the search compares."""
    return [_band_pass(image) for image in _pyramid(gray, max(level for level, _ in _PYRAMID) + 1)]


def _pyramid(gray: np.ndarray, levels: int) -> list[np.ndarray]:
    images = [gray]
    for _ in range(levels - 1):
        images.append(cv2.pyrDown(images[-1]))
    return images


def _band_pass(gray: np.ndarray) -> np.ndarray:
    g = gray.astype(np.float32)
    return cv2.GaussianBlur(g, (0, 0), 1.2) - cv2.GaussianBlur(g, (0, 0), 6.0)


def _resized(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    mask = np.asarray(mask).astype(np.uint8)
    if mask.shape != shape:
        mask = cv2.resize(mask, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return mask


def _elevation(R: np.ndarray, t: np.ndarray) -> float | None:
    """The angle in degrees by which the direction of travel of the motion (R, t) (X_target = R X_source + t) lies
    above the optical axis: the camera's pitch (positive looking down) for a car travelling parallel to the road;
    None for a step off the camera's axis."""
    centre = -R.T @ t  # the target camera's centre in the source camera's coordinates (x right, y down, z ahead)
    centre = centre / max(float(np.linalg.norm(centre)), 1e-12)
    if abs(centre[2]) < _ALONG_AXIS:
        return None
    direction = centre if centre[2] > 0 else -centre  # a camera moving backwards sees the direction behind it
    return math.degrees(math.atan2(-direction[1], direction[2]))


def _apply(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = np.c_[points, np.ones(len(points))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[:, :2] / p[:, 2:]

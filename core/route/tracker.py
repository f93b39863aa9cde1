"""A recursive filter over the position along the reference route and the speed (filterpy).

Why a Kalman filter and not a discrete Bayes filter over places: the sequence
filter already turns the evidence into one position and speed per frame, so
the state left to track is two numbers with a near-linear motion model
(position advances by the speed each frame). A two-state Kalman filter carries
that exactly, costs O(1) per frame whatever the map size, and gives the
innovation's standard deviation that the gate needs. A Bayes filter over N
places would cost O(N) per frame and repeat what the sequence search does.

A track starts from a confident answer, or, while the trajectories follow the
frames, from ``acquire_after`` answers in a row that move together as one
vehicle would (a short map seldom makes an answer confident; such a track holds the answer through a bad frame but trusts nothing
by itself, and narrows the speeds the sequence filter searches only once a
confident answer has confirmed it). The filter then gates the sequence
answers: one within ``gate_sigma`` standard deviations of the prediction is
accepted; one further away is an implausible jump and is not trusted. An
accepted answer more than ``agree_within`` map frames from the prediction is
plausible but not trusted either: the trajectory has changed its speed, and
a margin that says the place is unique does not say the position is right
to the frame. (Also trusting weak answers that agree with the track raised
recall on Nordland but let wrong answers through where the route leaves the
map, so agreement only ever removes trust.) If confident rejected answers keep
agreeing with one another for ``relocalise_after`` frames, the vehicle really
did jump (a kidnapped robot, a gap in the map) and the track restarts there;
after ``lost_after`` rejections in a row the track is dropped.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from ..config import TrackerConfig


@dataclass
class TrackStep:
    accepted: bool
    """The sequence answer agreed with the prediction (or started or restarted the track)."""
    position: float
    """Filtered position when accepted, else the prediction."""
    speed: float
    relocalised: bool = False
    """The track was (re)started at this frame."""
    innovation: float = 0.0
    """The answer less the track's prediction, in reference frames (0 where the answer starts the track)."""


class RouteTracker:
    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.kf: KalmanFilter | None = None
        self.misses = 0
        self.confirmed = False
        """The track has had a confident answer (started from one, or accepted one since)."""
        self._rejected: deque[tuple[float, float]] = deque(maxlen=max(1, self.config.relocalise_after))
        self._untracked: deque[tuple[float, float]] = deque(maxlen=max(1, self.config.acquire_after))

    @property
    def tracking(self) -> bool:
        return self.kf is not None

    def _start(self, position: float, speed: float) -> None:
        cfg = self.config
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.array([[position], [speed]])
        kf.F = np.array([[1.0, 1.0], [0.0, 1.0]])  # position advances by the speed every frame
        kf.H = np.array([[1.0, 0.0]])
        kf.P = np.diag([cfg.position_sigma**2, cfg.speed_sigma**2])
        kf.R = np.array([[cfg.position_sigma**2]])
        kf.Q = Q_discrete_white_noise(dim=2, dt=1.0, var=cfg.acceleration_sigma**2)
        self.kf = kf
        self.misses = 0
        self._rejected.clear()
        self._untracked.clear()

    def speed_range(self) -> tuple[float, float] | None:
        """Plausible speeds for the next frame's sequence search; None while not tracking, or while the track has
        had no confident answer (the search then keeps every speed, free to leave a track acquired wrongly)."""
        if self.kf is None or self.misses or not self.confirmed:
            return None
        v, sigma = float(self.kf.x[1, 0]), float(np.sqrt(self.kf.P[1, 1]))
        return v - 3.0 * sigma, v + 3.0 * sigma

    def step(self, position: float, speed: float, confident: bool, acquire: bool = True) -> TrackStep:
        """Feed one sequence answer; ``confident``: its margin reaches the localized threshold; ``acquire``: answers
        that move together may start a track without a confident one."""
        if self.kf is None:
            self._untracked.append((position, speed))
            acquired = acquire and self.config.acquire_after > 0 and _together(self._untracked, self.config.acquire_after,
                                                                   self.config.position_sigma)
            if not (confident or acquired):
                return TrackStep(False, position, speed)
            self._start(position, speed)
            self.confirmed = confident
            return TrackStep(True, position, speed, relocalised=True)
        kf = self.kf
        kf.predict()
        predicted = float(kf.x[0, 0])
        innovation_sigma = float(np.sqrt((kf.H @ kf.P @ kf.H.T + kf.R)[0, 0]))
        if abs(position - predicted) <= self.config.gate_sigma * innovation_sigma:
            kf.update(np.array([[position]]))
            self.confirmed = self.confirmed or confident
            self.misses = 0
            self._rejected.clear()
            return TrackStep(True, float(kf.x[0, 0]), float(kf.x[1, 0]), innovation=position - predicted)
        self.misses += 1
        if confident:
            self._rejected.append((position, speed))
        else:
            self._rejected.clear()
        if self._consistent():
            self._start(position, speed)
            self.confirmed = confident
            return TrackStep(True, position, speed, relocalised=True)
        if self.misses >= self.config.lost_after:
            self.reset()
        return TrackStep(False, predicted, float(kf.x[1, 0]))

    def _consistent(self) -> bool:
        """The last ``relocalise_after`` rejected answers move together, as one vehicle would."""
        return _together(self._rejected, self.config.relocalise_after, self.config.position_sigma)

    def state(self) -> dict:
        """The track (position and speed with their covariance, None while not tracking), whether a confident
        answer confirmed it, the misses, the rejected answers and those not yet tracked, as plain values and
        arrays."""
        return {"x": None if self.kf is None else self.kf.x, "P": None if self.kf is None else self.kf.P,
                "confirmed": self.confirmed, "misses": self.misses, "rejected": [list(r) for r in self._rejected],
                "untracked": [list(r) for r in self._untracked]}

    def restore(self, state: dict) -> None:
        self.reset()
        if state["x"] is not None:
            self._start(0.0, 0.0)
            assert self.kf is not None
            self.kf.x = np.asarray(state["x"], dtype=np.float64).reshape(2, 1)
            self.kf.P = np.asarray(state["P"], dtype=np.float64).reshape(2, 2)
        self.confirmed = bool(state["confirmed"])
        self.misses = int(state["misses"])
        self._rejected.extend((float(p), float(v)) for p, v in state["rejected"])
        self._untracked.extend((float(p), float(v)) for p, v in state["untracked"])


def _together(answers: deque[tuple[float, float]], count: int, position_sigma: float) -> bool:
    """The last ``count`` (position, speed) answers move together: each advanced from the one before by its
    speed, within two position sigmas."""
    if len(answers) < count:
        return False
    points = list(answers)[-count:]
    return all(abs((b[0] - a[0]) - b[1]) <= position_sigma * 2 for a, b in zip(points, points[1:]))

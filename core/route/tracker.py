"""A recursive filter over the position along the reference route and the speed (filterpy).

Why a Kalman filter and not a discrete Bayes filter over places: the sequence
filter already turns the evidence into one position and speed per frame, so
the state left to track is two numbers with a near-linear motion model
(position advances by the speed each frame). A two-state Kalman filter carries
that exactly, costs O(1) per frame whatever the map size, and gives the
innovation's standard deviation that the gate needs. A Bayes filter over N
places would cost O(N) per frame and repeat what the sequence search does.

A track starts from a confident answer. The filter then gates the sequence
answers: one within ``gate_sigma`` standard deviations of the prediction is
accepted; one further away is an implausible jump and is not trusted. (Also
trusting weak answers that agree with the track raised recall on Nordland but
let wrong answers through where the route leaves the map, so agreement only
ever removes trust.) If confident rejected answers keep
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


class RouteTracker:
    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.kf: KalmanFilter | None = None
        self.misses = 0
        self._rejected: deque[tuple[float, float]] = deque(maxlen=max(1, self.config.relocalise_after))

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

    def speed_range(self) -> tuple[float, float] | None:
        """Plausible speeds for the next frame's sequence search; None while not tracking."""
        if self.kf is None or self.misses:
            return None
        v, sigma = float(self.kf.x[1, 0]), float(np.sqrt(self.kf.P[1, 1]))
        return v - 3.0 * sigma, v + 3.0 * sigma

    def step(self, position: float, speed: float, confident: bool) -> TrackStep:
        """Feed one sequence answer; ``confident``: its margin reaches the localized threshold."""
        if self.kf is None:
            if not confident:
                return TrackStep(False, position, speed)
            self._start(position, speed)
            return TrackStep(True, position, speed, relocalised=True)
        kf = self.kf
        kf.predict()
        predicted = float(kf.x[0, 0])
        innovation_sigma = float(np.sqrt((kf.H @ kf.P @ kf.H.T + kf.R)[0, 0]))
        if abs(position - predicted) <= self.config.gate_sigma * innovation_sigma:
            kf.update(np.array([[position]]))
            self.misses = 0
            self._rejected.clear()
            return TrackStep(True, float(kf.x[0, 0]), float(kf.x[1, 0]))
        self.misses += 1
        if confident:
            self._rejected.append((position, speed))
        else:
            self._rejected.clear()
        if self._consistent():
            self._start(position, speed)
            return TrackStep(True, position, speed, relocalised=True)
        if self.misses >= self.config.lost_after:
            self.reset()
        return TrackStep(False, predicted, float(kf.x[1, 0]))

    def _consistent(self) -> bool:
        """The last ``relocalise_after`` rejected answers move together, as one vehicle would."""
        if len(self._rejected) < self.config.relocalise_after:
            return False
        points = list(self._rejected)
        return all(
            abs((b[0] - a[0]) - b[1]) <= self.config.position_sigma * 2 for a, b in zip(points, points[1:])
        )

    def state(self) -> dict:
        """The track (position and speed with their covariance, None while not tracking), the misses and the
        rejected answers, as plain values and arrays."""
        return {"x": None if self.kf is None else self.kf.x, "P": None if self.kf is None else self.kf.P,
                "misses": self.misses, "rejected": [list(r) for r in self._rejected]}

    def restore(self, state: dict) -> None:
        self.reset()
        if state["x"] is not None:
            self._start(0.0, 0.0)
            assert self.kf is not None
            self.kf.x = np.asarray(state["x"], dtype=np.float64).reshape(2, 1)
            self.kf.P = np.asarray(state["P"], dtype=np.float64).reshape(2, 2)
        self.misses = int(state["misses"])
        self._rejected.extend((float(p), float(v)) for p, v in state["rejected"])


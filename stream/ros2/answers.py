"""Each answer as the ROS 2 messages ``lostx ros2`` publishes: the full answer (``lostx_msgs/msg/Place``) and,
where the map has positions, the matched place as a ``geometry_msgs/msg/PoseWithCovarianceStamped``.

The pose's covariance says how far the vehicle may be from the matched place given the answer's confidence
``c`` (the probability that the answer is right): right, it is within half a map step of it; wrong, it is
anywhere on the map. So the variance about the matched place is, per axis,
``c * (step / 2)^2 + (1 - c) * mean over the map's frames of (distance to the place)^2 / 2``. Its heading is
the route's direction at the place, reversed when the vehicle drives the map's route backwards (a negative
speed); with the speed not yet known, the heading's variance is that of a heading anywhere on the circle.
The answer is planar: z, roll and pitch are 0, as 2D localizers publish them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lostx.core.decide.estimate import Estimate

from . import msgs

ANY_HEADING_VARIANCE = math.pi ** 2 / 3.0
"""The variance of a heading drawn uniformly from the circle: the heading is not known."""
RIGHT_HEADING_SIGMA = 0.1
"""Radians: how far a rightly placed vehicle's heading is taken to be from the route's (lanes, lane changes)."""
BAD_FRAME = "bad_frame"


@dataclass(frozen=True)
class PlacePose:
    x: float
    y: float
    yaw: float
    covariance: list[float]
    """6 x 6, row-major (x, y, z, rotation about x, y, z), as PoseWithCovariance holds it."""


class MapPlaces:
    """Where each map frame is and which way the route runs there, to place answers on the map."""

    def __init__(self, positions: np.ndarray) -> None:
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        self.positions = p
        steps = np.hypot(*np.diff(p, axis=0).T) if len(p) > 1 else np.zeros(0)
        moving = steps[steps > 0]
        self.step = float(np.median(moving)) if len(moving) else 0.0
        self.centre = p.mean(axis=0)
        self.spread = float(np.mean(np.sum((p - self.centre) ** 2, axis=1)))
        """Mean squared distance of the map's frames from their centre."""
        ahead = p[np.minimum(np.arange(len(p)) + 1, len(p) - 1)] - p[np.maximum(np.arange(len(p)) - 1, 0)]
        self.route_yaw = np.where(np.hypot(*ahead.T) > 0, np.arctan2(ahead[:, 1], ahead[:, 0]), np.nan)

    def pose(self, index: int, confidence: float, speed: float | None) -> PlacePose:
        x, y = (float(v) for v in self.positions[index])
        c = min(max(float(confidence), 0.0), 1.0)
        # Mean squared distance from this place to the map's frames: to its centre, plus their spread about it.
        far = float(np.sum((self.positions[index] - self.centre) ** 2)) + self.spread
        position = c * (self.step / 2.0) ** 2 + (1.0 - c) * far / 2.0
        route = float(self.route_yaw[index])
        known = speed is not None and speed != 0.0 and math.isfinite(route)
        if known:
            yaw = math.remainder(route + (math.pi if speed < 0 else 0.0), 2.0 * math.pi)  # type: ignore[operator]
            heading = c * RIGHT_HEADING_SIGMA ** 2 + (1.0 - c) * ANY_HEADING_VARIANCE
        else:
            yaw = route if math.isfinite(route) else 0.0
            heading = ANY_HEADING_VARIANCE
        covariance = [0.0] * 36
        covariance[0] = covariance[7] = position
        covariance[35] = heading
        return PlacePose(x, y, yaw, covariance)


@dataclass
class FrameAnswer:
    """One frame's answer before it becomes messages."""

    stream: str
    frame: int
    stamp_ns: int
    frame_id: str
    estimate: Estimate | None = None
    error: str = ""
    """Why there is no estimate (a bad frame)."""
    latency_ms: dict[str, float] = field(default_factory=dict)
    """The node's own stages (decoding, the whole frame), beside the localizer's."""


def _finite(value: float | None) -> float:
    return math.nan if value is None or not math.isfinite(value) else float(value)


def header(answer: FrameAnswer, frame_id: str | None = None) -> msgs.Header:
    return msgs.Header(msgs.Time.from_ns(answer.stamp_ns), answer.frame_id if frame_id is None else frame_id)


def place_message(answer: FrameAnswer) -> msgs.Place:
    """The full answer: the estimate's fields, or state ``bad_frame`` and why."""
    estimate = answer.estimate
    message = msgs.Place(header=header(answer), stream=answer.stream, frame=answer.frame)
    latency = dict(estimate.latency_ms) if estimate is not None else {}
    latency.update(answer.latency_ms)
    message.latency = [msgs.Latency(stage, float(ms)) for stage, ms in latency.items()]
    if estimate is None:
        message.state, message.error = BAD_FRAME, answer.error
        return message
    message.state = estimate.state
    message.warming_up = bool(estimate.warming_up)
    message.match_index = int(estimate.match_index)
    message.match_name = estimate.match_name
    if estimate.position is not None:
        message.has_position = True
        message.x, message.y = (float(v) for v in estimate.position)
    message.confidence = float(estimate.confidence)
    message.score = _finite(estimate.score)
    message.single_match_index = int(estimate.single_match_index)
    message.heading = estimate.heading
    message.heading_confidence = float(estimate.heading_confidence)
    message.speed = _finite(estimate.speed)
    message.sequence_score = _finite(estimate.sequence_score)
    message.margin = _finite(estimate.margin)
    message.window = int(estimate.window)
    message.candidates = [msgs.Candidate(int(c.index), _finite(c.distance), _finite(c.score), int(c.correspondences))
                          for c in estimate.candidates]
    return message


def pose_message(answer: FrameAnswer, places: MapPlaces | None,
                 map_frame: str) -> msgs.PoseWithCovarianceStamped | None:
    """The matched place on the map, stamped as the frame; None for a bad frame or a map without positions."""
    estimate = answer.estimate
    if estimate is None or places is None:
        return None
    placed = places.pose(int(estimate.match_index), float(estimate.confidence), estimate.speed)
    pose = msgs.Pose(msgs.Point(placed.x, placed.y, 0.0), msgs.Quaternion.from_yaw(placed.yaw))
    return msgs.PoseWithCovarianceStamped(header(answer, map_frame), msgs.PoseWithCovariance(pose, placed.covariance))

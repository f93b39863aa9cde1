"""Planar poses (x, y, yaw): where a frame of reference stands on the road plane and which way it faces,
in metres and radians, as arrays whose last axis holds the three numbers."""

from __future__ import annotations

import numpy as np

from ..geometry import CameraGeometry


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a then b: the pose b, given in a's frame, in the frame a is given in."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     wrap(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], -a[..., 2]], axis=-1)


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose b in a's frame (both given in one frame)."""
    return compose(inverse(a), b)


def wrap(angle: np.ndarray | float) -> np.ndarray:
    """Angles in (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=np.float64), 2.0 * np.pi)


def camera_on_vehicle(geometry: CameraGeometry) -> np.ndarray:
    """The camera's ground frame (on the road under the camera, along its level axis) in the vehicle's frame."""
    return np.array([geometry.x, geometry.y, np.radians(geometry.yaw)])


def camera_ground_pose(vehicle: np.ndarray, geometry: CameraGeometry) -> np.ndarray:
    """The camera's ground frame in the odometry frame, from the vehicle's pose there."""
    return compose(vehicle, camera_on_vehicle(geometry))

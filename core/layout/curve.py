"""Where the camera that views a map frame's stretch of road from its other end stands, from the map's own route.

A grid turned 180 degrees is the stretch seen from its other end only where the road is straight. On a bend the
camera looking back at the stretch from its other end stands where the road already points another way: the two
views' axes differ by the road's turn between the two places, 10 to 30 degrees on the bends of a city street. A
map knows its route, so for each of its frames it knows where such a camera would stand: on the route (taken to
go on straight beyond its ends), facing against the map camera's direction there, with the map camera's centre
point ``centre`` metres along its own axis. The map's grid is then also gathered in that camera's frame
(:func:`lostx.core.layout.describer.map_grid`), with no resampling.

Only the map's own motion is used: no query's trajectory, so the turn is no evidence of where a query is.
"""

from __future__ import annotations

import numpy as np

from ..motion.pose import wrap

STEP = 0.5
"""Metres between the route points searched for the other end's camera."""


def faces_forward(poses: np.ndarray) -> float:
    """+1 where the camera at ``poses`` ((N, 3) ground poses along a route, in order) faces the way it moves (a
    front camera: the road it views lies ahead along the route), -1 where it faces back (a rear camera)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    moved = np.diff(poses[:, :2], axis=0)
    return 1.0 if np.sum(moved[:, 0] * np.cos(poses[:-1, 2]) + moved[:, 1] * np.sin(poses[:-1, 2])) >= 0 else -1.0


def opposite_turns(poses: np.ndarray, centre: float, rows: np.ndarray | None = None) -> np.ndarray:
    """Degrees, anticlockwise seen from above: how much the camera viewing map frame ``rows``' (default all)
    centre point from the other end of its stretch is turned beyond 180 degrees from that frame's camera.

    ``poses`` (N, 3) are the map camera's ground poses along its route, in order; 0 on a straight road. The other
    end's camera lies about ``2 * centre`` metres along the route (ahead of a camera that faces the way it moves,
    behind one that faces back); the route points within ``centre`` metres of there are searched."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    n = len(poses)
    rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
    if n < 2:
        return np.zeros(len(rows))
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])
    heading = np.unwrap(poses[:, 2])
    ahead = faces_forward(poses)
    # The route points searched for each row, beyond the route's ends along its first and last headings.
    s = along[rows, None] + ahead * 2.0 * centre + np.arange(-centre, centre + STEP / 2, STEP)
    yaw = np.interp(s, along, heading)
    x, y = np.interp(s, along, poses[:, 0]), np.interp(s, along, poses[:, 1])
    for end, beyond in ((0, np.minimum(s, 0.0)), (n - 1, np.maximum(s - along[-1], 0.0))):
        x = x + ahead * beyond * np.cos(heading[end])  # the way the camera moved there
        y = y + ahead * beyond * np.sin(heading[end])
    # Facing against the route's camera there, the other end's camera has its centre point behind that one's.
    gap = np.hypot(x - centre * np.cos(yaw) - (poses[rows, 0] + centre * np.cos(poses[rows, 2]))[:, None],
                   y - centre * np.sin(yaw) - (poses[rows, 1] + centre * np.sin(poses[rows, 2]))[:, None])
    best = yaw[np.arange(len(rows)), np.argmin(gap, axis=1)]
    return np.degrees(wrap(best - heading[rows]))


def turned_about_centre(pose: np.ndarray, degrees: float, centre: float) -> np.ndarray:
    """(3,) the camera ground pose ``pose`` turned by ``degrees`` (anticlockwise from above) about its centre point
    ``centre`` metres along its axis: a grid gathered there is the grid at ``pose`` turned by ``-degrees``."""
    x, y, yaw = np.asarray(pose, dtype=np.float64)
    turned = yaw + np.radians(degrees)
    cx, cy = x + centre * np.cos(yaw), y + centre * np.sin(yaw)
    return np.array([cx - centre * np.cos(turned), cy - centre * np.sin(turned), float(wrap(turned))])

"""Monocular visual odometry (lostx.core.motion.visual) against the ego poses of nuScenes scene-0523.

Front and rear camera, 40 frames each at 2 Hz (about 3 m apart, 126 m with a roundabout). Per camera: the
per-step error of the translation (metres) and of the turn (degrees), the distance travelled against the ego
poses, the drift per 30 m of travel (the position error at the end of every 30 m window, the estimate started at
the true pose at the window's start), the share of steps whose length was measured (not predicted), and the cost
per frame at the working width (wall clock and CPU, OpenCV's default threads; JPEG decoding not counted); the
same for the frames played backwards and for every other frame (steps of about 6 m). Then how the distance (and
the median length of the steps both runs measured) moves when the camera's height is off by +5 cm and its pitch
by +-1 degree, and (with ``--masks``) the same figures with the default backbone's road and mover masks instead of
the geometric road.

    python benchmarks/bench_odometry.py [--width 800] [--masks] [--quick] [--out benchmarks/results/odometry.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import csv
import json
import math
import time
from dataclasses import replace

import cv2
import numpy as np

from common import parse, print_table, write_json
from lostx.core.geometry import CameraGeometry, quaternion_matrix
from lostx.core.motion.pose import camera_ground_pose, compose, relative, wrap
from lostx.core.motion.visual import VisualOdometry
from lostx.core.paths import data_dir

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
BODY = {"front": 0.0, "rear": 0.12}  # the rear camera sees the boot lid along its bottom edge
WINDOW_M = 30.0


PLAYS = {
    "played backwards": lambda n: np.arange(n)[::-1],
    "every other frame (1 Hz)": lambda n: np.arange(0, n, 2),
    "every other frame, backwards": lambda n: np.arange(0, n, 2)[::-1],
}
"""Other ways through the frames (geometric road): the frame order of each, for ``n`` frames."""


def geometry(camera: str) -> CameraGeometry:
    calibration = json.loads((SCENE / "calibration.json").read_text())[camera]
    width, height = calibration.get("image_size_wh", (1600, 900))
    return CameraGeometry.from_pose(np.array(calibration["camera_intrinsic"]),
                                    quaternion_matrix(calibration["rotation_in_ego_wxyz"]),
                                    np.array(calibration["translation_in_ego_m"]), width, height,
                                    body=BODY[camera], source=f"{SCENE.name} {camera}")


def load(camera: str) -> tuple[list[np.ndarray], np.ndarray]:
    """The frames (RGB) and the vehicle's poses (x, y, yaw) at their capture times."""
    with open(SCENE / camera / "positions.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    frames = [cv2.cvtColor(cv2.imread(str(SCENE / camera / row["file"])), cv2.COLOR_BGR2RGB) for row in rows]
    poses = np.array([[float(row["x"]), float(row["y"]), math.radians(float(row["vehicle_yaw_deg"]))] for row in rows])
    return frames, poses


def run(geometry_: CameraGeometry, frames: list[np.ndarray], width: int,
        masks: list[dict[str, np.ndarray]] | None = None) -> dict:
    odometry = VisualOdometry(geometry_, width)
    steps, wall, cpu = [], [], []
    for i, frame in enumerate(frames):
        start_wall, start_cpu = time.perf_counter(), time.process_time()
        step = odometry.step(frame, **(masks[i] if masks else {}))
        wall.append(1e3 * (time.perf_counter() - start_wall))
        cpu.append(1e3 * (time.process_time() - start_cpu))
        if step is not None:
            steps.append(step)
    return {"motion": np.array([s.motion for s in steps]), "quality": np.array([s.quality for s in steps]),
            "measured": np.array([s.measured for s in steps]), "wall_ms": wall[1:], "cpu_ms": cpu[1:]}


def scores(result: dict, truth: np.ndarray) -> dict:
    """truth: (n, 3) the camera's ground poses at the frames."""
    motion = result["motion"]
    true_steps = relative(truth[:-1], truth[1:])
    translation = np.linalg.norm(motion[:, :2] - true_steps[:, :2], axis=1)
    turn = np.degrees(np.abs(wrap(motion[:, 2] - true_steps[:, 2])))
    travelled = np.r_[0.0, np.cumsum(np.linalg.norm(true_steps[:, :2], axis=1))]
    drift = []
    for i in range(len(truth)):
        j = int(np.searchsorted(travelled, travelled[i] + WINDOW_M))
        if j >= len(truth):
            break
        pose = truth[i]
        for k in range(i, j):
            pose = compose(pose, motion[k])
        drift.append(float(np.linalg.norm(pose[:2] - truth[j, :2])))
    distance = float(np.linalg.norm(motion[:, :2], axis=1).sum())
    return {
        "steps": len(motion),
        "translation_error_m": {"mean": float(translation.mean()), "median": float(np.median(translation)),
                                "max": float(translation.max())},
        "yaw_error_deg": {"mean": float(turn.mean()), "median": float(np.median(turn)), "max": float(turn.max())},
        "distance_m": distance, "true_distance_m": float(travelled[-1]),
        "distance_error_pct": 100.0 * (distance / travelled[-1] - 1.0),
        "yaw_change_deg": float(np.degrees(motion[:, 2].sum())),
        "true_yaw_change_deg": float(np.degrees(true_steps[:, 2].sum())),
        "drift_per_30m_m": {"mean": float(np.mean(drift)), "max": float(np.max(drift)), "windows": len(drift)},
        "measured_share": float(result["measured"].mean()),
        "median_quality": float(np.median(result["quality"])),
        "median_wall_ms": float(np.median(result["wall_ms"])),
        "median_cpu_ms": float(np.median(result["cpu_ms"])),
    }


def median_length_ratio(base: dict, other: dict) -> float:
    """The median ratio of the step lengths of two runs over the steps both measured (not predicted)."""
    both = base["measured"] & other["measured"]
    lengths = [np.linalg.norm(r["motion"][both, :2], axis=1) for r in (base, other)]
    return float(np.median(lengths[1] / np.maximum(lengths[0], 1e-6)))


def segmentation_masks(frames: list[np.ndarray]) -> list[dict[str, np.ndarray]]:
    """Road and mover masks from the default backbone's label map (its resolution, not the frame's)."""
    from lostx.core.backbones import load_backbone

    backbone = load_backbone()
    names = backbone.info.class_names
    road = [names.index("road")]
    movers = [i for i, name in enumerate(names) if name in ("person", "car", "bus", "truck", "van", "bicycle",
                                                             "minibike", "motorbike")]
    out = []
    for frame in frames:
        labels = backbone(frame).label_map
        out.append({"ground": np.isin(labels, road), "movers": np.isin(labels, movers)})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=800, help="working width of the odometry (pixels)")
    parser.add_argument("--masks", action="store_true", help="also run with the default backbone's masks")
    args = parse(parser, "odometry", quick="the front camera only")
    cameras = ("front",) if args.quick else ("front", "rear")

    results: dict = {"scene": SCENE.name, "width": args.width, "opencv_threads": cv2.getNumThreads(), "cameras": {}}
    rows, sensitivity_rows = [], []
    for camera in cameras:
        frames, vehicle = load(camera)
        nominal = geometry(camera)
        truth = camera_ground_pose(vehicle, nominal)
        variants = {"geometric road": run(nominal, frames, args.width)}
        if args.masks:
            variants["segmentation masks"] = run(nominal, frames, args.width, segmentation_masks(frames))
        entry = {name: scores(result, truth) for name, result in variants.items()}
        # The same frames played backwards (the camera then moves the other way along its axis: a rear camera
        # towards what it sees), and every other frame (steps twice as long: a 1 Hz stream, or twice the speed).
        for name, order in PLAYS.items():
            entry[name] = scores(run(nominal, [frames[i] for i in order(len(frames))], args.width),
                                 truth[order(len(frames))])
        for name, s in entry.items():
            rows.append([camera, name, s["translation_error_m"]["mean"], s["translation_error_m"]["median"],
                         s["translation_error_m"]["max"], s["yaw_error_deg"]["mean"], s["yaw_error_deg"]["max"],
                         f"{s['distance_error_pct']:+.1f}", s["drift_per_30m_m"]["mean"], s["drift_per_30m_m"]["max"],
                         s["measured_share"], s["median_wall_ms"], s["median_cpu_ms"]])
        perturbed = {"height +5 cm": replace(nominal, z=nominal.z + 0.05),
                     "pitch +1 deg (down)": replace(nominal, pitch=nominal.pitch + 1.0),
                     "pitch -1 deg (up)": replace(nominal, pitch=nominal.pitch - 1.0)}
        base = variants["geometric road"]
        entry["sensitivity"] = {}
        for name, changed in perturbed.items():
            result = run(changed, frames, args.width)
            s = scores(result, truth)
            change = 100.0 * (s["distance_m"] / entry["geometric road"]["distance_m"] - 1.0)
            step_change = 100.0 * median_length_ratio(base, result) - 100.0
            entry["sensitivity"][name] = {"distance_error_pct": s["distance_error_pct"], "distance_change_pct": change,
                                          "median_step_length_change_pct": step_change}
            sensitivity_rows.append([camera, name, f"{s['distance_error_pct']:+.1f}", f"{change:+.1f}",
                                     f"{step_change:+.1f}"])
        results["cameras"][camera] = entry

    print_table(f"visual odometry, nuScenes {SCENE.name}, {args.width} px wide, against the ego poses",
                ["camera", "frames, road", "step err mean m", "median m", "max m", "yaw err mean deg", "max deg",
                 "distance %", "drift/30 m mean m", "max m", "measured", "wall ms/frame", "cpu ms/frame"], rows)
    print_table("distance travelled when the mounting is off (geometric road)",
                ["camera", "mounting", "distance %", "change %", "step length change % (median)"], sensitivity_rows)
    write_json(args.out, {"benchmark": "odometry", **results})


if __name__ == "__main__":
    main()

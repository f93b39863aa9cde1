"""Per-frame network time of each backbone, and its RobotCar day/night single-frame result; ESPNetv2 through
PyTorch and through its ONNX export side by side.

Network time: the backbone call alone (resize, network, probabilities on the
feature grid), over the twenty real RobotCar frames (day and night), cycled;
the backbones take turns frame by frame, so a change in the machine's load
hits them alike. Day/night: a map of the ten day frames, the ten night frames
localized against it in order (the k-th night frame's true match is day frame
k), for each scoring: the single-frame answer and the sequence filter's
(window of 3 frames by default, as in ``lostx demo``: the sample has only ten).
ONNX against PyTorch: the largest feature difference (relative to the largest
feature), the largest probability difference and the share of equal labels,
over the twenty frames. The machine is shared, so the load average before and
after is recorded.

    python benchmarks/bench_backbones.py [--backbones NAME ...] [--repeat 30] [--threads 2] [--window 3] [--quick]
                                         [--out benchmarks/results/backbones.json]
"""

from __future__ import annotations

import os

# Before torch loads: OpenMP threads that spin after each layer would take the cores from the backbone
# timed next (the backbones take turns); sleeping ones let each be timed alone.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import common  # noqa: E402,F401  (first of the rest: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import itertools
import tempfile
from pathlib import Path

import numpy as np

from common import parse, print_table, summary, time_call, write_json
from lostx.core import Config, Localizer, LostDescriber, ReferenceMap, build_map, load_backbone
from lostx.core.backbones import Backbone
from lostx.core.backbones.espnet_onnx import export_onnx
from lostx.core.config import BackboneConfig, SequenceConfig, VerifyConfig
from lostx.core.paths import data_dir, models_dir
from lostx.replay.folder import folder_traverse

SCORINGS = ("eq4-lost", "eq4", "released")


def network_times(backbones: dict[str, Backbone], images: list[np.ndarray], repeat: int) -> dict[str, dict]:
    """Each backbone's time per frame, the backbones taking turns on every frame."""
    samples: dict[str, list[float]] = {name: [] for name in backbones}
    for name, backbone in backbones.items():  # warm-up
        backbone(images[0])
    for image in itertools.islice(itertools.cycle(images), repeat):
        for name, backbone in backbones.items():
            samples[name] += time_call(lambda: backbone(image), 1, warmup=0)
    return {name: summary(times) for name, times in samples.items()}


def network_time(backbone: Backbone, images: list[np.ndarray], repeat: int) -> dict[str, float]:
    """One backbone's time per frame (for a study of one backbone's settings)."""
    return network_times({"": backbone}, images, repeat)[""]


def agreement(reference: Backbone, other: Backbone, images: list[np.ndarray]) -> dict[str, float]:
    """How far ``other``'s features, probabilities and labels are from ``reference``'s on the same frames."""
    features = probs = 0.0
    labels = []
    for image in images:
        a, b = reference(image), other(image)
        features = max(features, float(np.abs(a.features - b.features).max() / np.abs(a.features).max()))
        probs = max(probs, float(np.abs(a.probs - b.probs).max()))
        labels.append(float((a.labels() == b.labels()).mean()))
    return {"feature_max_rel_diff": features, "prob_max_abs_diff": probs, "equal_labels_min": min(labels)}


def counts(found: np.ndarray, truth: np.ndarray) -> dict[str, object]:
    return {"matches": found.tolist(), "exact": int((found == truth).sum()),
            "within_one": int((np.abs(found - truth) <= 1).sum())}


def day_night(backbone: Backbone, config: Config, window: int) -> dict[str, dict[str, dict[str, object]]]:
    """Per scoring, the single-frame and the sequence filter's night -> day result."""
    root = data_dir() / "robotcar-daynight"
    night = list(folder_traverse(root / "night"))
    truth = np.array([frame.id for frame in night])
    results: dict[str, dict[str, dict[str, object]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        build_map(folder_traverse(root / "day"), Path(tmp) / "day", config, LostDescriber(backbone, config.lost),
                  {"camera": "front"}, progress=False)
        refmap = ReferenceMap.open(Path(tmp) / "day")
        for scoring in SCORINGS:
            localizer = Localizer(refmap, dataclasses.replace(
                config, verify=VerifyConfig(scoring=scoring), sequence=SequenceConfig(length=window)), backbone)
            estimates = [localizer.step(frame) for frame in night]
            results[scoring] = {
                "single": counts(np.array([e.single_match_index for e in estimates]), truth),
                "sequence": counts(np.array([e.match_index for e in estimates]), truth),
            }
    return results


ONNX = "espnetv2-cityscapes (onnx)"
BUILT_IN = ["mosaic-ade20k", "espnetv2-cityscapes", ONNX]


def configs(names: list[str], threads: int, workdir: Path) -> dict[str, BackboneConfig]:
    """The backbones to measure; ESPNetv2's ONNX export is made in ``workdir`` first."""
    out: dict[str, BackboneConfig] = {}
    for name in names:
        if name == ONNX:
            exported = export_onnx(models_dir() / "espnetv2-s2.0-cityscapes-1024x512.pth", workdir / "espnetv2.onnx")
            out[name] = BackboneConfig(name="onnx", model_path=exported.model, device="cpu", threads=threads)
        else:
            out[name] = BackboneConfig(name=name, device="cpu", threads=threads)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backbones", nargs="+", default=BUILT_IN, help="backbones to measure")
    parser.add_argument("--repeat", type=int, default=30, help="timed frames per backbone")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for the networks")
    parser.add_argument("--window", type=int, default=3, help="frames in the sequence filter's window")
    args = parse(parser, "backbones", quick=f"{BUILT_IN[0]} only, 3 timed frames")
    if args.quick:
        args.backbones, args.repeat = BUILT_IN[:1], 3

    root = data_dir() / "robotcar-daynight"
    images = [frame.image for folder in ("day", "night") for frame in folder_traverse(root / folder)]
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as workdir:
        chosen = configs(args.backbones, args.threads, Path(workdir))
        backbones = {name: load_backbone(cfg) for name, cfg in chosen.items()}
        times = network_times(backbones, images, args.repeat)
        measured: dict[str, dict[str, object]] = {}
        for name, backbone in backbones.items():
            info = backbone.info
            measured[name] = {
                "grid": list(info.grid),
                "feature_dim": info.feature_dim,
                "classes": len(info.class_names),
                "network": times[name],
                "day_night": day_night(backbone, Config(backbone=chosen[name]), args.window),
            }
        compared = None
        if ONNX in backbones and "espnetv2-cityscapes" in backbones:
            compared = agreement(backbones["espnetv2-cityscapes"], backbones[ONNX], images)
    load_after = os.getloadavg()[0]

    print_table(f"network time per frame ({args.threads} threads, 1024 x 640 RobotCar frames, taking turns)",
                ["backbone", "grid", "D", "median ms", "p90 ms"],
                [[name, "x".join(map(str, m["grid"])), m["feature_dim"], m["network"]["median_ms"],
                  m["network"]["p90_ms"]] for name, m in measured.items()])
    for answer in ("single", "sequence"):
        print_table(f"RobotCar night -> day, {answer}, of 10: exact / within one frame",
                    ["backbone", *SCORINGS],
                    [[name, *(cell(m["day_night"][s][answer]) for s in SCORINGS)] for name, m in measured.items()])
    if compared is not None:
        same = {s: {a: measured[ONNX]["day_night"][s][a]["matches"] ==
                    measured["espnetv2-cityscapes"]["day_night"][s][a]["matches"] for a in ("single", "sequence")}
                for s in SCORINGS}
        compared["same_matches"] = same
        ratio = measured["espnetv2-cityscapes"]["network"]["median_ms"] / measured[ONNX]["network"]["median_ms"]
        compared["pytorch_over_onnx_time"] = ratio
        print_table("ESPNetv2: ONNX (onnxruntime) against PyTorch on the 20 RobotCar frames",
                    ["max |feature diff| / max |feature|", "max |prob diff|", "equal labels (worst frame)",
                     "same matches (all scorings, single + sequence)", "PyTorch time / ONNX time"],
                    [[f"{compared['feature_max_rel_diff']:.1e}", f"{compared['prob_max_abs_diff']:.1e}",
                      f"{compared['equal_labels_min']:.3f}",
                      "yes" if all(all(v.values()) for v in same.values()) else "no", f"{ratio:.2f}"]])
    print(f"\nload average (1 min): {load_before:.2f} before, {load_after:.2f} after")
    write_json(args.out, {"benchmark": "backbones", "threads": args.threads, "repeat": args.repeat, "window": args.window,
                          "load_average": [load_before, load_after], "backbones": measured,
                          "onnx_against_pytorch": compared})


def cell(result: dict[str, object]) -> str:
    return f"{result['exact']} / {result['within_one']}"


if __name__ == "__main__":
    main()

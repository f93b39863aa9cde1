"""How sure the heading is, against how often it is right: the reliability table on both nuScenes scenes.

Every pairing of the front and rear cameras (S1 to S4, the heading opposite; S0, the front camera's even frames
against its odd ones, the heading the same) on ``scene-0523`` and ``scene-0916``, at 2 Hz (``--rates`` adds 1 Hz),
heading not declared (:mod:`scenes`). For each setting of ``[heading] misled``: the frames whose heading is right,
and every frame's heading confidence binned against the share of its bin that is right. The setting is chosen by the
log-likelihood of the frames' headings under their confidences (how well calibrated they are), its worse scene best,
the default kept unless that gains more than :data:`NATS`.

    python benchmarks/study_heading.py [--quick] [--rates "2 Hz,1 Hz"] [--out benchmarks/results/study_heading.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
from contextlib import nullcontext
from pathlib import Path

import numpy as np

from common import markdown_table, parse, print_table, write_json
from lostx.core import Config
from scenes import PAIRINGS, RATES, SAME, SCENES, Counts, Study, variant

NATS = 2.0
"""The default's calibration is kept unless another setting's is better by more than this (a likelihood ratio of
e^2, about 7: the frames' headings are strongly correlated, so a nat or two is noise)."""
BINS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99, 1.0001)
VARIANTS = {
    **{f"misled {e:g}{' (default)' if e == Config().heading.misled else ''}": (variant(heading=dict(misled=e)), None)
       for e in (0.02, 0.05, 0.1, 0.2)},
}


def reliability(counts: Counts) -> list[tuple[int, int]]:
    """(right, frames) per confidence bin."""
    confidence, right = np.array(counts.confidences), np.array(counts.right_headings)
    which = np.digitize(confidence, BINS) - 1
    return [(int(right[which == b].sum()), int((which == b).sum())) for b in range(len(BINS) - 1)]


def log_likelihood(counts: Counts) -> float:
    """sum log P(the heading found is right) over the frames: the better calibrated, the higher."""
    p = np.clip(np.array(counts.confidences), 1e-6, 1 - 1e-6)
    right = np.array(counts.right_headings)
    return float(np.sum(np.where(right, np.log(p), np.log(1 - p))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="2 Hz", help="comma-separated: " + ", ".join(RATES))
    args = parse(parser, "study_heading", quick="the default only, S1 at 2 Hz")
    variants, pairings, rates = VARIANTS, (*PAIRINGS, *SAME), tuple(r.strip() for r in args.rates.split(","))
    if args.quick:
        default = next(n for n in VARIANTS if "(default)" in n)
        variants, pairings, rates = {default: VARIANTS[default]}, ("S1",), ("2 Hz",)
    report: dict[str, dict] = {}
    rows, tables = [], []
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for name, (config, patch) in variants.items():
            pooled = {scene: Counts() for scene in SCENES}
            cells = []
            for scene in SCENES:
                for rate in rates:
                    for pairing in pairings:
                        if pairing in SAME and rate != "2 Hz":
                            continue
                        c = study.counts(config, scene, pairing, RATES[rate], patch or nullcontext)["sequence"]
                        pooled[scene].add(c)
                        cells.append(f"{c.heading}/{c.frames}")
            likelihood = {scene: log_likelihood(pooled[scene]) for scene in SCENES}
            rows.append([name, *cells, *(f"{likelihood[s]:.0f}" for s in SCENES)])
            for scene in SCENES:
                tables.append([name if scene == SCENES[0] else "", scene[-4:],
                               *(f"{r}/{n}" if n else "" for r, n in reliability(pooled[scene]))])
            report[name] = {"log_likelihood": likelihood,
                            "reliability": {s: reliability(pooled[s]) for s in SCENES},
                            "right": {s: [pooled[s].heading, pooled[s].frames] for s in SCENES}}
            print(f"{name} done", flush=True)
    columns = [f"{s[-4:]} {p}{'' if r == '2 Hz' else ' 1 Hz'}" for s in SCENES for r in rates for p in pairings
               if not (p in SAME and r != "2 Hz")]
    first = ("The heading, undeclared: frames right / frames (sequence mode), and the log-likelihood of the frames' "
             "headings under their confidences", ["variant", *columns, *(f"{s[-4:]} log-lik" for s in SCENES)], rows)
    second = ("Reliability: frames right / frames, by heading confidence",
              ["variant", "scene", *(f"{lo:g}-{min(hi, 1):g}" for lo, hi in zip(BINS, BINS[1:]))], tables)
    markdown = [f"# {__doc__.splitlines()[0]}\n", "Written by `python benchmarks/study_heading.py`.\n"]
    for table in (first, second):
        print_table(*table)
        markdown.append(markdown_table(*table))
    misled = {n: r for n, r in report.items() if n.startswith("misled")}
    if len(misled) > 1:
        worse = {n: min(r["log_likelihood"].values()) for n, r in misled.items()}
        best = max(worse, key=worse.__getitem__)
        default = next((n for n in worse if "(default)" in n), best)
        chosen = best if worse[best] - worse[default] > NATS else default
        note = (f"the rule's choice (its worse scene's log-likelihood best, the default kept within {NATS:g} nats): "
                f"{chosen} (best: {best}, {worse[best]:.1f} against {worse[default]:.1f})")
        print(note)
        markdown.append(f"- {note}\n")
    if not args.quick:
        args.out.with_suffix(".md").write_text("\n".join(markdown))
    write_json(args.out, {"benchmark": "study_heading", "bins": BINS, "variants": report})


if __name__ == "__main__":
    main()

"""The headline figures: each nuScenes scene with the settings chosen on the other one, beside LoST-X without the
layout and appearance (GeM) on the same frames.

Every family of ``study_layout.py`` (its JSON, ``benchmarks/results/study_layout.json``) has a variant chosen on
each scene (:func:`scenes.chosen_on`). The settings chosen on one scene are those variants together; they run on the
other scene, both ways, all four pairings, at 2 Hz and 1 Hz, heading not declared (:mod:`scenes`). The defaults run beside them (chosen on
both scenes by the rule: in-sample, secondary).

    python benchmarks/study_scenes.py [--families benchmarks/results/study_layout.json] [--quick]
        [--out benchmarks/results/study_scenes.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import json
import tempfile
from contextlib import ExitStack, nullcontext
from pathlib import Path

from common import RESULTS, markdown_table, parse, print_table, write_json
from lostx.core import Config
from scenes import MODES, PAIRINGS, RATES, SCENES, Counts, Study, chosen_on, variant
from study_layout import FAMILIES, MEASURED

BASELINES = {
    "LoST-X without the layout": variant(layout=dict(enabled="off"), cues=dict(appearance=False)),
    "appearance (GeM)": variant(layout=dict(enabled="off"), cues=dict(weights={"lostx": 0.01, "appearance": 1.0})),
}


def changes(config: Config) -> dict[str, dict]:
    """The settings ``config`` changes from the defaults, by section."""
    base = Config()
    out: dict[str, dict] = {}
    for section in dataclasses.fields(Config):
        mine, theirs = getattr(config, section.name), getattr(base, section.name)
        changed = {f.name: getattr(mine, f.name) for f in dataclasses.fields(mine)
                   if getattr(mine, f.name) != getattr(theirs, f.name)}
        if changed:
            out[section.name] = changed
    return out


def chosen_settings(families: dict, scene: str) -> tuple[Config, list, list[str]]:
    """The variants chosen on ``scene`` by every family, together: their settings, their patches, their names."""
    sections: dict[str, dict] = {}
    patches, names = [], []
    for family, report in families.items():
        if family in MEASURED or family not in FAMILIES:
            continue
        results = {name: counted(r) for name, r in report["results"].items() if name in FAMILIES[family]}
        name = chosen_on(results, scene)
        config, patch = FAMILIES[family][name]
        if "(default" not in name:
            names.append(f"{family}: {name}")
        for section, values in changes(config).items():
            sections.setdefault(section, {}).update(values)
        if patch is not None and not isinstance(patch, tuple):
            patches.append(patch)
    return variant(**sections), patches, names


def counted(figures: dict) -> dict:
    """A variant's figures as study_layout.py wrote them (scene -> rate -> pairing -> mode -> fields), as Counts."""
    return {s: {r: {p: {m: Counts(**c) for m, c in by_p.items()} for p, by_p in by_r.items()}
                for r, by_r in by_s.items()} for s, by_s in figures.items()}


def together(patches: list):
    """One patch applying every patch of ``patches``."""
    def apply():  # noqa: ANN202
        stack = ExitStack()
        for patch in patches:
            stack.enter_context(patch())
        return stack
    return apply if patches else nullcontext


def row(label: str, results: dict, scene: str, rate: str) -> list[str]:
    by_pairing = results[scene][rate]
    out = [label]
    for pairing in by_pairing:
        single, sequence = by_pairing[pairing]["single"], by_pairing[pairing]["sequence"]
        out += [single.figure, sequence.figure, f"{sequence.heading}/{sequence.frames}"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", type=Path, default=RESULTS / "study_layout.json")
    args = parse(parser, "study_scenes", quick="the defaults on S1 at 2 Hz")
    families = json.loads(args.families.read_text())["families"] if args.families.is_file() else {}
    rates = ("2 Hz",) if args.quick else tuple(RATES)
    pairings = ("S1",) if args.quick else tuple(PAIRINGS)
    runs: dict[str, tuple[Config, list, list[str]]] = {"the defaults (chosen on both)": (Config(), [], [])}
    if not args.quick:
        for scene in SCENES:
            runs[f"chosen on {scene}"] = chosen_settings(families, scene)
        for label, config in BASELINES.items():
            runs[label] = (config, [], [])
    report: dict[str, dict] = {}
    markdown = ["# Each nuScenes scene with the settings chosen on the other one\n",
                "Written by `python benchmarks/study_scenes.py`. Recall@1 at 7.5 m of the look-at points (single, "
                "sequence) and frames whose heading is right, heading not declared.\n"]
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        results = {}
        for label, (config, patches, names) in runs.items():
            results[label] = study.figures(config, rates, pairings, (together(patches),))
            report[label] = {"changes": names, "figures": {
                s: {r: {p: {m: vars(c) for m, c in by_p.items()} for p, by_p in by_r.items()}
                    for r, by_r in by_s.items()} for s, by_s in results[label].items()}}
            print(f"{label} done" + (f" ({'; '.join(names)})" if names else ""), flush=True)
    header = ["settings", *(f"{p} {what}" for p in pairings for what in ("single", "sequence", "heading"))]
    for rate in rates:
        for scene in SCENES:
            other = next(s for s in SCENES if s != scene)
            rows = [row(f"chosen on {other}", results[f"chosen on {other}"], scene, rate)] if not args.quick else []
            rows += [row(label, results[label], scene, rate) for label in results if not label.startswith("chosen")]
            title = f"{scene}, {rate}"
            print_table(title, header, rows)
            markdown.append(markdown_table(title, header, rows))
    for scene in SCENES:
        label = f"chosen on {scene}"
        if label in report:
            markdown.append(f"- {label}: " + ("; ".join(report[label]["changes"]) or "the defaults") + "\n")
    if not args.quick:
        args.out.with_suffix(".md").write_text("\n".join(markdown))
    write_json(args.out, {"benchmark": "study_scenes", "modes": MODES, "runs": report})


if __name__ == "__main__":
    main()

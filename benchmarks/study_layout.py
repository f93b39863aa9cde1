"""Every setting of the opposite view, chosen on one nuScenes scene and reported on the other (docs/opposite-view.md).

Each family of variants runs on both scenes (``scene-0523`` and ``scene-0916``), the four pairings of the front and
rear cameras (S1, S2 headline; S3, S4 beside), single frame and with the sequence filter, heading not declared
(:mod:`scenes`). For each family: the variant chosen on each scene and its figures on the other, and the variant the
rule makes the default (the least short of the family's best on its worse scene, :func:`scenes.rule`). Recall@1 at 7.5 m of the look-at points; heading: frames answered
``opposite`` (the truth).

    python benchmarks/study_layout.py [--families cues,voters,...] [--rates "2 Hz,1 Hz"] [--pairings S1,S2,S3,S4]
        [--quick] [--out benchmarks/results/study_layout.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import tempfile
from contextlib import nullcontext
from pathlib import Path
from unittest import mock

import numpy as np

from common import markdown_table, parse, print_table, write_json
from lostx.core import Config
from lostx.core.layout.compare import TURNS
from scenes import HEADLINE, MODES, NOISE, PAIRINGS, RATES, SCENES, Study, carries, chosen_on, figure, rule, variant


def _voters(*kept: str):
    """The heading's votes with only ``kept`` voters."""
    from lostx.core.route.heading import HeadingFilter

    update = HeadingFilter.update

    def only(self, votes, declared=None):  # noqa: ANN001, ANN202
        return update(self, {k: v for k, v in votes.items() if k in kept}, declared)

    return lambda: mock.patch.object(HeadingFilter, "update", only)


def _straight_in_frames():  # noqa: ANN202
    """The sequence's trajectories straight in frames although the frames have motion (they follow the distance
    travelled wherever there is motion)."""
    from lostx.core.localizer import Localizer

    follow = Localizer._follow
    return mock.patch.object(Localizer, "_follow", lambda self, progress: follow(self, None))


def _turns(angles: tuple[float, ...]):  # noqa: ANN202
    """The query's grid turned by ``angles`` (degrees) when the most similar map grids are compared again."""
    from lostx.core.layout import compare

    return lambda: mock.patch.object(compare, "TURNS", angles)


def _lane(metres: float):  # noqa: ANN202
    """Each live frame's grid gathered as by a camera ``metres`` to its left (negative: right): the road driven the
    other way in another lane."""
    from lostx.core.layout.describer import LiveLayout
    from lostx.core.motion.pose import compose

    add = LiveLayout.add

    def beside(self, frame):  # noqa: ANN001, ANN202
        gathering = add(self, frame)
        return dataclasses.replace(gathering, current=compose(gathering.current, np.array([0.0, metres, 0.0])))

    return lambda: mock.patch.object(LiveLayout, "add", beside)


LANES = (nullcontext, _lane(-3.5), _lane(3.5))
"""The sideways shift exists for a car driving the road the other way, in another lane: its family is judged over the
map's own lane and a lane to either side (3.5 m), summed."""

FAMILIES: dict[str, dict[str, tuple[Config, object]]] = {
    "cues": {
        "weights earned (default)": (Config(), None),
        "fixed: LoST-X 1, layout 3": (variant(cues=dict(weights={"lostx": 1.0, "layout": 3.0})), None),
        "fixed: LoST-X 1, layout 3, appearance 1": (
            variant(cues=dict(weights={"lostx": 1.0, "layout": 3.0, "appearance": 1.0})), None),
        "earned, appearance off": (variant(cues=dict(appearance=False)), None),
        "LoST-X alone": (variant(layout=dict(enabled="off"), cues=dict(appearance=False)), None),
        "the layout alone": (variant(cues=dict(appearance=False, weights={"lostx": 0.01, "layout": 1.0})), None),
        "appearance alone": (variant(layout=dict(enabled="off"),
                                     cues=dict(weights={"lostx": 0.01, "appearance": 1.0})), None),
    },
    "agree": {f"agree within {e:g} map frames{' (default)' if e == Config().cues.agree_within else ''}":
              (variant(cues=dict(agree_within=e)), None) for e in (2.0, 3.0, 4.0)},
    "voters": {
        "mirror and motion (default)": (Config(), None),
        "mirror alone": (Config(), _voters("mirror")),
        "motion alone": (Config(), _voters("motion")),
    },
    "misled": {f"a voter misled with probability {e:g}{' (default)' if e == Config().heading.misled else ''}":
               (variant(heading=dict(misled=e)), None) for e in (0.05, 0.1, 0.2)},
    "sure": {f"heading sure at {p:g}{' (default)' if p == Config().heading.min_confidence else ''}":
             (variant(heading=dict(min_confidence=p)), None) for p in (0.7, 0.8, 0.9)},
    "window": {f"distance window {d:g} m{' (default)' if d == Config().sequence.distance_window else ''}":
               (variant(sequence=dict(distance_window=d)), None) for d in (30.0, 45.0, 60.0)},
    "switch": {f"switch cost {j:g}{' (default)' if j == Config().sequence.switch_cost else ''}":
               (variant(sequence=dict(switch_cost=j)), None) for j in (4.0, 8.0, float("inf"))},
    "follow": {"sequence straight in frames": (Config(), _straight_in_frames),
               "sequence following the distance (default)": (Config(), None)},
    "vehicles": {f"vehicles weighted {w:g}{' (default)' if w == Config().layout.vehicle_weight else ''}":
                 (variant(layout=dict(vehicle_weight=w)), None) for w in (1.0, 0.5, 0.0)},
    "shift": {f"sideways shift +-{s:g} m{' (default)' if s == Config().layout.across_shift else ''}":
              (variant(layout=dict(across_shift=s)), LANES) for s in (0.0, 2.0, 4.0)},
    "turns": {f"turns +-{t:g} degrees{' (default)' if (-t, 0.0, t) == TURNS else ''}":
              (Config(), _turns((-t, 0.0, t) if t else (0.0,))) for t in (0.0, 2.0, 5.0, 8.0)},
    "smoothing": {f"smoothed {b:g} m{' (default)' if b == Config().layout.blur else ''}":
                  (variant(layout=dict(blur=b)), None) for b in (0.5, 1.0, 2.0)},
    "gathering": {"query 12 m, map +-9 m": (variant(layout=dict(query_travel=12.0, map_travel=9.0)), None),
                  "query 24 m, map +-18 m (default)": (Config(), None),
                  "query 36 m, map +-27 m": (variant(layout=dict(query_travel=36.0, map_travel=27.0)), None)},
    "motion": {"ego poses (default source)": (Config(), None),
               "visual odometry": (variant(motion=dict(source="visual")), None)},
    "lane": {"the map's own lane": (Config(), None),
             "a lane to the right (3.5 m)": (Config(), _lane(-3.5)),
             "a lane to the left (3.5 m)": (Config(), _lane(3.5))},
}
CONDITIONS = {"motion", "lane"}
"""Families that measure a condition, not a setting."""
RETIRED = {"follow", "turns"}
"""Families whose choice did not carry from one scene to the other (:func:`scenes.carries`): no longer settings, the
code keeps the rule's variant; measured here so that the reason stays visible."""
MEASURED = CONDITIONS | RETIRED
"""Families nothing is chosen among."""
QUICK = {"cues": ["weights earned (default)", "LoST-X alone"]}


def cell(results: dict, scene: str, rate: str, pairing: str) -> str:
    r = results[scene][rate][pairing]
    return f"{r['single'].figure} {r['sequence'].figure} h{r['single'].heading}"


def run_family(study: Study, family: dict[str, tuple[Config, object]], rates: tuple[str, ...],
               pairings: tuple[str, ...]) -> dict[str, dict]:
    out = {}
    for name, (config, patch) in family.items():
        patches = patch if isinstance(patch, tuple) else (patch if patch is not None else nullcontext,)
        out[name] = study.figures(config, rates, pairings, patches)
        print(f"  {name}: " + ", ".join(f"{s[-4:]} {figure(out[name], s)}" for s in SCENES), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", default=",".join(FAMILIES), help="comma-separated: " + ", ".join(FAMILIES))
    parser.add_argument("--rates", default="2 Hz", help="comma-separated: " + ", ".join(RATES))
    parser.add_argument("--pairings", default=",".join(HEADLINE),
                        help="comma-separated, of " + ", ".join(PAIRINGS) + " (the rule reads S1 and S2; "
                             "study_scenes.py runs all four with the settings chosen)")
    args = parse(parser, "study_layout", quick="two variants, S1 only")
    rates = tuple(r.strip() for r in args.rates.split(","))
    families = {f: FAMILIES[f] for f in args.families.split(",")}
    pairings = tuple(p.strip() for p in args.pairings.split(","))
    if args.quick:
        families = {f: {n: FAMILIES[f][n] for n in names} for f, names in QUICK.items()}
        pairings, rates = ("S1",), ("2 Hz",)
    report: dict[str, dict] = {}
    markdown = [f"# {__doc__.splitlines()[0]}\n", "Written by `python benchmarks/study_layout.py`. Recall@1 at 7.5 m of "
                "the look-at points, single frame and sequence; h: frames whose heading is right (opposite), of 40 "
                "(scene-0523) or 41 (scene-0916); figure: S1 and S2, single and sequence, summed.\n"]
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for family, variants in families.items():
            print(f"{family}:", flush=True)
            results = run_family(study, variants, rates, pairings)
            rows = []
            for name, r in results.items():
                rows.append([name, *(cell(r, s, rate, p) for rate in rates for s in SCENES for p in pairings),
                             *(figure(r, s) for s in SCENES)])
            header = ["variant", *(f"{s[-4:]} {p}{'' if len(rates) == 1 else ' ' + rate}"
                                   for rate in rates for s in SCENES for p in pairings),
                      *(f"{s[-4:]} figure" for s in SCENES)]
            title = f"{family}: Recall@1 at 7.5 m, single and sequence, heading right in frames"
            print_table(title, header, rows)
            markdown.append(markdown_table(title, header, rows))
            choosing = not args.quick and family not in MEASURED
            choices = {s: chosen_on(results, s) for s in SCENES} if not args.quick and family not in CONDITIONS else {}
            notes = []
            for on, name in choices.items():
                other = next(s for s in SCENES if s != on)
                notes.append(f"chosen on {on}: {name} -> on {other}: "
                             + ", ".join(f"{p} {cell(results[name], other, '2 Hz', p)}" for p in pairings))
            if choices:
                notes.append(f"carries (each scene's choice within {NOISE} queries of the other scene's best): "
                             + ("yes" if carries(results) else "no" + (", no longer a setting" if family in RETIRED
                                                                       else "")))
            default = rule(results) if choosing else None
            if default is not None:
                notes.append(f"the rule's choice (least short of the best on its worse scene; the default kept "
                             f"within two queries): {default}")
            for note in notes:
                print(note)
            markdown.append("".join(f"- {note}\n" for note in notes))
            report[family] = {"results": {name: {s: {rate: {p: {m: vars(c) for m, c in by_p.items()}
                                                            for p, by_p in by_rate.items()}
                                                     for rate, by_rate in by_scene.items()}
                                                 for s, by_scene in r.items()} for name, r in results.items()},
                              "chosen": choices, "default": default}
    if not args.quick:
        args.out.with_suffix(".md").write_text("\n".join(markdown))
    write_json(args.out, {"benchmark": "study_layout", "tolerance_m": 7.5, "headline": HEADLINE, "modes": MODES,
                          "families": report})


if __name__ == "__main__":
    main()

"""The per-frame text: the status block, the top-10 table and the image captions (Markdown and plain text).

Two scores must never be confused in these: the answer's own score (the sequence
cost with the sequence filter, the single-frame verification score without) and
each candidate's single-frame verification score in the table.
"""

from __future__ import annotations

import math

from lostx.core.decide.estimate import Candidate, Estimate
from lostx.core.frame import Frame
from lostx.core.maps.refmap import ReferenceMap

NAME_CHARS = 28
"""File names longer than this are shown by their end (where frame numbers and stamps are)."""


def fmt(value: float | None, digits: int = 3) -> str:
    """A number for people: ``digits`` significant digits, a true minus sign; a dash for None, inf and NaN."""
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.{digits}g}".replace("-", "−")


def short_name(name: str, limit: int = NAME_CHARS) -> str:
    return name if len(name) <= limit else "…" + name[-(limit - 1):]


def matched_candidate(est: Estimate) -> Candidate | None:
    """The candidate behind the answer; None where the answer is not among this frame's top-k."""
    return next((c for c in est.candidates if c.index == est.match_index), None)


def confidence_text(confidence: float) -> str:
    """The calibrated confidence (a rank in [0, 1]) to three decimals, rounded down, so that it reads
    0.999 (the default bar for ``localized``, ``decision.min_confidence``) only once it is there."""
    return f"{math.floor(confidence * 1000 + 1e-9) / 1000:.3f}"


def heading_text(est: Estimate) -> str:
    return f"{est.heading} ({100 * est.heading_confidence:.0f} % sure)"


CUE_NAMES = {"lostx": "LoST-X", "layout": "layout", "appearance": "appearance"}


def status_markdown(frame: Frame, est: Estimate, refmap: ReferenceMap) -> str:
    state = "**localized**" if est.state == "localized" else "**not localized**"
    if est.warming_up:
        state += f" (warming up, {est.window} frames)"
    lines = [
        f"**frame {frame.id}** · {state} · confidence **{confidence_text(est.confidence)}**",
        f"answer **reference {est.match_index}** · {short_name(est.match_name)}",
        f"single-frame answer {est.single_match_index} · heading **{heading_text(est)}**"
        + (": the query is shown mirrored" if est.opposite else ""),
    ]
    if est.sequence_score is not None:
        lines.append(f"sequence cost **{fmt(est.sequence_score)}** (lower is better) · speed {fmt(est.speed)} "
                     f"reference frames per frame · window {est.window}")
    else:
        lines.append(f"score **{fmt(est.score)}** (single-frame verification, lower is better) · sequence filter off")
    if est.cue_weights:
        cues = " · ".join(f"{CUE_NAMES.get(k, k)} {v:.2f}" for k, v in est.cue_weights.items())
        lines.append(f"cues (weights earned by agreeing with the motion): {cues}"
                     + (" · **the motion and the matches disagree**" if est.disagrees else ""))
    elif est.disagrees:
        lines.append("**the motion and the matches disagree**")
    if est.latency_ms:
        parts = " · ".join(f"{k} {v:.0f}" for k, v in est.latency_ms.items() if k != "total")
        lines.append(f"latency **{fmt(est.latency_ms.get('total'))} ms**: {parts}")
    # Hard line breaks, not paragraphs: the block fits the panel at 1280 x 720.
    return "  \n".join(lines)


def candidates_markdown(est: Estimate) -> str:
    rows = ["| # | ref | distance | score | corr. |", "|---:|---:|---:|---:|---:|"]
    for rank, c in enumerate(est.candidates, start=1):
        ref = f"**{c.index} ◀**" if c.index == est.match_index else str(c.index)
        rows.append(f"| {rank} | {ref} | {fmt(c.distance)} | {fmt(c.score)} | {c.correspondences} |")
    note = "distance: descriptor · score: verification, lower is better · corr.: correspondences · ◀ answer"
    if matched_candidate(est) is None:
        note += f"  \nthe answer, reference {est.match_index}, comes from the sequence filter: not in this top 10"
    return "\n".join(rows) + "\n\n" + note


def captions(frame: Frame, est: Estimate, map_camera: str | None, lines: int) -> list[str]:
    """The query's and the reference's caption (two lines each); a mirrored query says so and why.
    ``lines``: the correspondences drawn to the reference."""
    query = f"query {frame.id}" + (f" · {short_name(frame.name)}" if frame.name else "")
    if est.opposite:
        why = f"heading {heading_text(est)}"
        if frame.camera is not None and map_camera:
            why = f"{frame.camera} camera, {map_camera} map · " + why
        query += f"\nMIRRORED: {why}"
    else:
        query += f"\nheading {heading_text(est)}"
    return [query, f"reference {est.match_index} · {short_name(est.match_name)}\n{lines} correspondences"]

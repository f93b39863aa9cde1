"""The per-frame text panels: a status line block and the top-10 table (Markdown)."""

from __future__ import annotations

import math

from lostx.core.estimate import Candidate, Estimate
from lostx.core.frame import Frame
from lostx.core.refmap import ReferenceMap


def fmt(value: float | None, digits: int = 3) -> str:
    """A number for people: ``digits`` significant digits; a dash for None, inf and NaN."""
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value:.{digits}g}"


def matched_candidate(est: Estimate) -> Candidate | None:
    """The candidate behind the answer; None where the answer is not among this frame's top-k."""
    return next((c for c in est.candidates if c.index == est.match_index), None)


def status_markdown(frame: Frame, est: Estimate, refmap: ReferenceMap) -> str:
    state = "**localized**" if est.state == "localized" else "**not localized**"
    if est.warming_up:
        state += " (warming up)"
    lines = [
        f"**frame {frame.id}** · match **{est.match_index}** ({est.match_name}) · {state}",
        f"confidence **{est.confidence:.2f}** · score {fmt(est.score)} · single-frame match {est.single_match_index}",
        f"sequence score {fmt(est.sequence_score)} · speed {fmt(est.speed)} · window {est.window}",
    ]
    if est.opposite:
        lines.append(f"query camera **{frame.camera}**, map **{refmap.camera}**: the query is shown mirrored")
    if est.latency_ms:
        parts = ", ".join(f"{k} {v:.0f}" for k, v in est.latency_ms.items() if k != "total")
        lines.append(f"latency {fmt(est.latency_ms.get('total'))} ms ({parts})")
    return "\n\n".join(lines)


def candidates_markdown(est: Estimate, refmap: ReferenceMap) -> str:
    rows = ["| rank | ref | name | distance | score | corr. |", "|---:|---:|---|---:|---:|---:|"]
    for rank, c in enumerate(est.candidates, start=1):
        mark = " ◀" if c.index == est.match_index else ""
        rows.append(f"| {rank} | **{c.index}**{mark} | {refmap.names[c.index]} | {fmt(c.distance)} | "
                    f"{fmt(c.score)} | {c.correspondences} |")
    return "\n".join(rows)

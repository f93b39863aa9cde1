"""Reading back the per-query CSV that ``lostx match`` writes, to score it without re-running anything."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lostx.core.errors import InputError

REQUIRED = ("query_index", "match_index", "score")


@dataclass
class MatchTable:
    """One row per query, in query order."""

    query_index: np.ndarray
    """(N,) int: 0..N-1."""
    predictions: np.ndarray
    """(N,) int reference index; -1 where the row has none."""
    scores: np.ndarray
    """(N,) float, lower is better (NaN where empty)."""
    confidence: np.ndarray | None
    """(N,) float in [0, 1], higher is better, when the file has it."""
    candidates: np.ndarray | None
    """(N, k) int best first, padded with -1, when the file has them."""


def read_matches_csv(path: str | Path) -> MatchTable:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"matches file not found: {path}") from None
    reader = csv.DictReader(text.splitlines())
    fields = reader.fieldnames or []
    missing = [c for c in REQUIRED if c not in fields]
    if missing:
        raise InputError(f"{path}:1: header lacks {', '.join(missing)} (found {', '.join(fields) or 'nothing'})")
    queries, preds, scores, confs, cands = [], [], [], [], []
    for line, row in enumerate(reader, start=2):
        try:
            q = int(row["query_index"])
            pred = int(row["match_index"]) if row["match_index"].strip() else -1
            score = float(row["score"]) if row["score"].strip() else math.nan
            conf = float(row["confidence"]) if (row.get("confidence") or "").strip() else math.nan
            cand = [int(c) for c in (row.get("candidates") or "").split()]
        except (TypeError, ValueError, AttributeError):
            raise InputError(f"{path}:{line}: malformed row {row}") from None
        if q != len(queries):
            raise InputError(f"{path}:{line}: query_index {q} where {len(queries)} was expected (rows in query order)")
        queries.append(q)
        preds.append(pred)
        scores.append(score)
        confs.append(conf)
        cands.append(cand)
    if not queries:
        raise InputError(f"{path}: no rows after the header")
    width = max(len(c) for c in cands)
    candidates = None
    if width:
        candidates = np.full((len(cands), width), -1, dtype=np.int64)
        for i, c in enumerate(cands):
            candidates[i, : len(c)] = c
    confidence = np.asarray(confs) if "confidence" in fields else None
    return MatchTable(np.asarray(queries), np.asarray(preds, dtype=np.int64), np.asarray(scores), confidence, candidates)

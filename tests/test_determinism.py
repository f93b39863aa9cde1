"""Answers do not depend on how many BLAS threads the host process runs numpy with.

A threaded BLAS sums a product in an order that depends on its thread count;
the method's sums therefore run in numpy's own loops. Checked against the
process's BLAS at one thread and at four (OpenBLAS threads products of these
sizes when it may).
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from lostx.core.describe.describer import LostDescriber
from lostx.core.localizer import Localizer
from lostx.core.describe.lost import standardise
from lostx.core.match.search import cosine_distances
from lostx.replay.folder import folder_traverse


def _parts(semantic, describer: LostDescriber, refs: np.ndarray) -> dict[str, np.ndarray]:
    frame = describer.from_semantic(semantic)
    raw = describer.descriptor(frame, frame.means)
    query = standardise(raw[None], np.zeros(raw.size, np.float32), np.ones(raw.size, np.float32))[0]
    return {"means": frame.means, "descriptor": raw, "grouped": describer.groups.group(semantic.probs),
            "distances": cosine_distances(query, refs)}


def test_descriptor_stages_are_bit_identical_at_any_blas_thread_count(robotcar, mosaic, rng):
    semantic = mosaic(next(iter(folder_traverse(robotcar / "night"))).image)
    describer = LostDescriber(mosaic)
    refs = rng.standard_normal((5000, 3 * semantic.features.shape[0])).astype(np.float32)
    refs /= np.linalg.norm(refs, axis=1, keepdims=True)
    with threadpool_limits(limits=1, user_api="blas"):
        one = _parts(semantic, describer, refs)
    with threadpool_limits(limits=4, user_api="blas"):
        many = _parts(semantic, describer, refs)
    for key in one:
        assert np.array_equal(one[key], many[key]), key


def test_localizer_answers_are_identical_at_any_blas_thread_count(robotcar, day_map, mosaic):
    def answers() -> list[dict]:
        localizer = Localizer(day_map, backbone=mosaic)
        out = []
        for frame in folder_traverse(robotcar / "night"):
            summary = localizer.step(frame).summary()
            summary.pop("latency_ms")
            out.append(summary)
        return out

    with threadpool_limits(limits=1, user_api="blas"):
        one = answers()
    with threadpool_limits(limits=4, user_api="blas"):
        many = answers()
    assert one == many

"""The map's approximate index on real maps: its recall against exact search, and when the search uses it."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lostx.cli import main
from lostx.core import ReferenceMap, build_map
from lostx.core.config import SearchConfig
from lostx.core.errors import MapError
from lostx.core.match.indexcheck import index_recall, sample_frames
from lostx.core.match.search import CandidateSearch
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.replay.folder import folder_traverse


@pytest.fixture(scope="module")
def summer_map(tmp_path_factory, nordland) -> ReferenceMap:
    """SeqSLAM thumbnails of the 3576 Nordland summer frames."""
    out = tmp_path_factory.mktemp("index") / "summer"
    build_map(folder_traverse(nordland / "summer"), out, describer=ThumbnailDescriber(), progress=False)
    return ReferenceMap.open(out)


def test_map_info_verify_reports_the_index_recall_on_a_real_map(summer_map, capsys):
    assert main(["map", "info", str(summer_map.path), "--verify"]) == 0
    out = capsys.readouterr().out
    assert "checksums  all files match" in out
    found = re.search(r"Recall@10 (\d\.\d+) against exact search \(worst frame (\d\.\d+)\) on (\d+) map frames", out)
    assert found, out
    recall, worst, queries = float(found.group(1)), float(found.group(2)), int(found.group(3))
    # Measured: 0.885. Thumbnails are near-uniform (most Nordland distances lie within 0.6 to 0.8 grey
    # levels), and the index ranks by L2 where the search ranks by mean absolute difference.
    assert 0.85 <= recall < 1.0 and worst < recall and queries == 500


def test_a_wider_search_of_the_index_finds_more_of_the_exact_nearest(summer_map):
    narrow = index_recall(summer_map, SearchConfig(index_breadth=16, index_shortlist=10), samples=200)
    default = index_recall(summer_map, SearchConfig(), samples=200)
    wide = index_recall(summer_map, SearchConfig(index_breadth=256, index_shortlist=160), samples=200)
    assert narrow.recall < default.recall <= wide.recall
    assert default.queries == wide.queries == 200 and default.k == 10
    assert default.shortlist == 40 and default.breadth == 64


def test_recall_of_a_lost_map_whose_every_frame_the_index_reaches(day_map):
    recall = index_recall(day_map, samples=10)
    # Ten frames, each searched without itself: its nine others are all the index holds.
    assert (recall.recall, recall.worst, recall.k, recall.queries) == (1.0, 1.0, 9, 10)


def test_sampled_frames_are_evenly_spaced_and_distinct():
    assert sample_frames(3576, 5).tolist() == [0, 894, 1788, 2681, 3575]
    assert sample_frames(4, 500).tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize(("index", "min_frames", "approximate"), [
    ("auto", 3576, True), ("auto", 3577, False), ("on", 10**6, True), ("off", 1, False),
])
def test_the_index_is_searched_only_from_its_map_size_on_unless_forced(summer_map, index, min_frames, approximate):
    search = CandidateSearch(summer_map, SearchConfig(index=index, index_min_frames=min_frames))
    assert search.approximate is approximate


def test_index_searches_give_exact_distances_ranked_as_exact_search_ranks_them(summer_map):
    exact = CandidateSearch(summer_map, SearchConfig(index="off"))
    indexed = CandidateSearch(summer_map, SearchConfig(index="on"))
    for frame in sample_frames(summer_map.n_frames, 20):
        query = summer_map.descriptor_rows(np.array([frame]))[0]
        found, distances = indexed.nearest(query, 10, slice(frame, frame + 1))
        assert frame not in found and len(found) == 10
        np.testing.assert_array_equal(distances, exact.distances(query, found))
        assert np.all(np.diff(distances) >= 0)
        # Never nearer than exact search's nearest: the index only ever misses frames.
        assert distances[0] >= exact.nearest(query, 1, slice(frame, frame + 1))[1][0]


def test_a_map_without_an_index_is_searched_exactly_or_refused_when_the_index_is_forced(summer_map, tmp_path):
    import json
    import shutil

    copy = tmp_path / "old"
    shutil.copytree(summer_map.path, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    del manifest["index"]
    (copy / "index.faiss").unlink()
    (copy / "manifest.json").write_text(json.dumps(manifest))
    old = ReferenceMap.open(copy)
    assert not CandidateSearch(old, SearchConfig(index="auto", index_min_frames=10**6)).approximate
    with pytest.raises(MapError, match="no approximate index"):
        CandidateSearch(old, SearchConfig(index="on"))
    with pytest.raises(MapError, match="no approximate index"):
        index_recall(old)

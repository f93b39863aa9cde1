"""The dataset entry point: format recognition, index-aligned pairs, VPR-Bench, subsampling by distance."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.evaluation.metrics import evaluate
from lostx.core.match.search import sad_distances, top_k
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.evaluation.datasets import open_pair, shared_positions
from lostx.replay.dataset import detect_format, open_traverse
from lostx.replay.folder import Traverse
from lostx.replay.subsample import distance_subsample_indices, subsample_by_distance


def copy_frames(robotcar, dest, which="day", n=3, names=None):
    dest.mkdir(parents=True)
    sources = sorted((robotcar / which).iterdir())[:n]
    for k, src in enumerate(sources):
        shutil.copy(src, dest / (names[k] if names else src.name))
    return dest


# --- index-aligned pairs ---------------------------------------------------------------------------------


def test_nordland_is_an_index_aligned_pair(nordland):
    pair = open_pair(nordland / "summer", nordland / "winter")
    assert pair.format == "pairs" and pair.aligned and pair.default_unit == "frames"
    assert len(pair.reference) == len(pair.query) == 3576
    assert pair.reference.files[1234].name == pair.query.files[1234].name  # same file number, same place
    tol0, tol2 = pair.ground_truth([0, 2])
    assert tol0.matches(1234).tolist() == [1234]
    assert tol2.matches(0).tolist() == [0, 1, 2] and tol2.matches(3575).tolist() == [3573, 3574, 3575]


def test_thumbnails_on_the_first_300_nordland_frames_beat_chance(nordland):
    """The readers, ground truth and metrics together on real data (summer map, winter queries)."""
    full = open_pair(nordland / "summer", nordland / "winter")
    n = 300
    pair = replace(full, reference=full.reference.subset(range(n)), query=full.query.subset(range(n)))
    describe = ThumbnailDescriber()
    ref = np.stack([describe(frame.image) for frame in pair.reference])
    query = np.stack([describe(frame.image) for frame in pair.query])
    candidates = np.stack([top_k(sad_distances(q, ref), 10) for q in query])
    scores = np.array([sad_distances(q, ref)[c[0]] for q, c in zip(query, candidates)])
    (gt,) = pair.ground_truth(2)
    assert gt.n_queries == gt.n_references == n
    ev = evaluate(candidates[:, 0], scores, gt, candidates)
    chance = 5 / n  # five true references out of 300 for most queries
    assert ev.recall_at_n[1] > 3 * chance
    assert ev.recall_at_n[1] <= ev.recall_at_n[5] <= ev.recall_at_n[10]
    assert 0 < ev.auc_pr <= 1 and 0 < ev.max_f1 <= 1


def test_robotcar_sample_is_an_index_aligned_pair_with_different_names(robotcar):
    pair = open_pair(robotcar / "day", robotcar / "night")
    assert pair.format == "pairs" and len(pair.query) == 10
    assert pair.reference.files[0].name != pair.query.files[0].name
    assert pair.ground_truth(1)[0].matches(9).tolist() == [8, 9]


def test_mismatched_lengths_name_folders_and_index(tmp_path, robotcar):
    ref = copy_frames(robotcar, tmp_path / "ref", n=3)
    query = copy_frames(robotcar, tmp_path / "query", "night", n=2)
    with pytest.raises(InputError, match=r"ref has 3 images, .*query has 2; index 2 \(.*0000040\.png\) has no counterpart"):
        open_pair(ref, query)


def test_frame_tolerance_needs_alignment_and_metres_need_positions(tmp_path, robotcar):
    ref = copy_frames(robotcar, tmp_path / "ref", n=3)
    query = copy_frames(robotcar, tmp_path / "query", "night", n=3)
    pair = open_pair(ref, query, format="folder")
    with pytest.raises(InputError, match="frame tolerances need an index-aligned pair"):
        pair.ground_truth(1, "frames")
    with pytest.raises(InputError, match="metres needs positions for both traverses"):
        pair.ground_truth(5.0, "m")


# --- folders with positions --------------------------------------------------------------------------------


def test_folders_with_positions_csv_inside_give_metric_ground_truth(tmp_path, robotcar):
    ref = copy_frames(robotcar, tmp_path / "ref", n=3)
    query = copy_frames(robotcar, tmp_path / "query", "night", n=2)
    (ref / "positions.csv").write_text("x,y\n0,0\n5,0\n10,0\n")
    (query / "positions.csv").write_text("x,y\n4,1\n30,0\n")
    pair = open_pair(ref, query)
    assert pair.format == "folder" and pair.default_unit == "m"
    near, far = pair.ground_truth([2.0, 10.0])
    assert near.matches(0).tolist() == [1] and near.matches(1).tolist() == []
    assert far.matches(0).tolist() == [0, 1, 2]


def test_positions_on_one_side_only_is_an_error(tmp_path, robotcar):
    ref = copy_frames(robotcar, tmp_path / "ref", n=2)
    query = copy_frames(robotcar, tmp_path / "query", "night", n=2)
    (ref / "positions.csv").write_text("x,y\n0,0\n5,0\n")
    with pytest.raises(InputError, match=r"query has no positions but the other traverse has"):
        open_pair(ref, query)


def test_latitude_longitude_traverses_share_one_origin():
    # Each traverse is projected about its own first fix when read; the query starts 111 m north.
    files = [Path("a.png"), Path("b.png")]
    ref = Traverse("ref", files, positions=np.zeros((2, 2)), geo=np.array([[51.750, -1.25], [51.7501, -1.25]]))
    qry = Traverse("query", files, positions=np.zeros((2, 2)), geo=np.array([[51.751, -1.25], [51.7511, -1.25]]))
    ref_xy, query_xy = shared_positions(ref, qry)
    np.testing.assert_allclose(ref_xy[1], [0, 11.12], atol=0.01)
    np.testing.assert_allclose(query_xy[0], [0, 111.19], atol=0.01)
    mixed = Traverse("metres", files, positions=np.zeros((2, 2)))
    with pytest.raises(InputError, match="latitude/longitude positions but the other traverse has metres"):
        shared_positions(ref, mixed)


# --- VPR-Bench -------------------------------------------------------------------------------------------


def make_vprbench(root, robotcar, rows):
    copy_frames(robotcar, root / "ref", n=3, names=["1.jpg", "2.jpg", "10.jpg"])
    copy_frames(robotcar, root / "query", "night", n=2, names=["0.jpg", "1.jpg"])
    data = np.empty((len(rows), 2), dtype=object)
    for i, (q, refs) in enumerate(rows):
        data[i, 0], data[i, 1] = q, refs
    np.save(root / "ground_truth_new.npy", data, allow_pickle=True)
    return root


def test_vprbench_dataset_in_integer_order_with_its_ground_truth(tmp_path, robotcar):
    root = make_vprbench(tmp_path / "bench", robotcar, [(0, [2]), (1, [])])
    assert detect_format(root) == "vprbench"
    pair = open_pair(root)
    assert pair.format == "vprbench"
    assert [f.name for f in pair.reference.files] == ["1.jpg", "2.jpg", "10.jpg"]  # 10 after 2, as VPR-Bench
    exact, wide = pair.ground_truth([0, 1])
    assert exact.matches(0).tolist() == [2] and exact.matches(1).tolist() == []
    assert wide.matches(0).tolist() == [1, 2] and wide.tolerance == 1


def test_vprbench_ground_truth_that_does_not_fit_the_folders(tmp_path, robotcar):
    root = make_vprbench(tmp_path / "bench", robotcar, [(0, [2]), (1, [3])])
    with pytest.raises(InputError, match=r"ground_truth_new\.npy: row 1: reference index 3 is outside 0..2"):
        open_pair(root)
    (root / "query" / "1.jpg").unlink()
    with pytest.raises(InputError, match=r"ground_truth_new\.npy: 2 rows for 1 query images"):
        open_pair(root)


def test_vprbench_folder_given_with_a_query_is_refused(tmp_path, robotcar):
    root = make_vprbench(tmp_path / "bench", robotcar, [(0, [2]), (1, [])])
    with pytest.raises(InputError, match="give it alone as the reference"):
        open_pair(root, root / "query")


def test_unknown_format_and_empty_folder(tmp_path):
    with pytest.raises(InputError, match="unknown dataset format 'kitti'"):
        open_pair(tmp_path, tmp_path, format="kitti")
    with pytest.raises(InputError, match="no images in"):
        detect_format(tmp_path)
    with pytest.raises(InputError, match="not a VPR-Bench dataset"):
        open_pair(tmp_path)


# --- subsampling by distance ---------------------------------------------------------------------------------


def test_subsample_keeps_a_frame_each_time_the_path_reaches_the_spacing():
    x = np.array([0, 0.5, 1.0, 2.1, 2.5, 4.0, 4.2, 6.3])
    pos = np.stack([x, np.zeros_like(x)], axis=1)
    # path since last kept: 0.5, 1.0, 2.1 -> keep 3; 0.4, 1.9, 2.1 -> keep 6; 2.1 -> keep 7
    np.testing.assert_array_equal(distance_subsample_indices(pos, 2.0), [0, 3, 6, 7])


def test_subsample_measures_path_length_not_displacement():
    # Out 1.5 m and back: 3 m of path but 0 m displacement from the start.
    pos = np.array([[0, 0], [1.5, 0], [0, 0], [0.5, 0]], dtype=float)
    np.testing.assert_array_equal(distance_subsample_indices(pos, 2.0), [0, 2])
    still = np.zeros((5, 2))
    np.testing.assert_array_equal(distance_subsample_indices(still, 2.0), [0])  # standing still: one frame


def test_subsampled_aligned_pair_keeps_original_frame_numbers(tmp_path, robotcar):
    ref = copy_frames(robotcar, tmp_path / "ref", n=6)
    query = copy_frames(robotcar, tmp_path / "query", "night", n=6)
    (ref / "positions.csv").write_text("x,y\n" + "".join(f"{k},0\n" for k in range(6)))
    # The query moves 2 m in its first step: it keeps other frame numbers than the reference.
    (query / "positions.csv").write_text("x,y\n" + "".join(f"{x},0\n" for x in (0, 2, 3, 4, 5, 6)))
    pair = open_pair(ref, query, format="pairs", spacing=2.0)
    np.testing.assert_array_equal(pair.reference.source_indices, [0, 2, 4])
    np.testing.assert_array_equal(pair.query.source_indices, [0, 1, 3, 5])
    assert [f.name for f in pair.query.files] == ["0000062.png", "0000070.png", "0000086.png", "0000102.png"]
    exact, one = pair.ground_truth([0, 1], "frames")
    # query frames 0, 1, 3, 5 against reference frames 0, 2, 4 (same number = same place)
    assert [exact.matches(q).tolist() for q in range(4)] == [[0], [], [], []]
    assert [one.matches(q).tolist() for q in range(4)] == [[0], [0, 1], [1, 2], [2]]
    assert any("kept 3 of 6 frames" in n for n in pair.notes)
    assert any("kept 4 of 6 frames" in n for n in pair.notes)


def test_subsampling_needs_positions(robotcar):
    traverse = open_traverse(robotcar / "day")
    with pytest.raises(InputError, match="subsampling by distance needs positions"):
        subsample_by_distance(traverse, 2.0)
    with pytest.raises(InputError, match="positive number of metres"):
        distance_subsample_indices(np.zeros((3, 2)), 0.0)


def test_a_reversed_traverse_runs_backwards_with_increasing_time(tmp_path):
    import cv2

    names = [f"{i:03d}.png" for i in range(4)]
    for name in names:
        cv2.imwrite(str(tmp_path / name), np.zeros((8, 8, 3), np.uint8))
    (tmp_path / "positions.csv").write_text(
        "file,x,y,timestamp\n" + "".join(f"{n},{i},0,{10 + 2 * i ** 2}\n" for i, n in enumerate(names)))
    forward = open_traverse(tmp_path)
    backward = forward.reversed()
    assert [f.name for f in backward.files] == names[::-1]
    assert backward.positions[:, 0].tolist() == [3, 2, 1, 0]
    assert backward.source_indices.tolist() == [3, 2, 1, 0]
    # Reflected clock: starts where the forward run started, keeps each gap, runs forward.
    assert backward.timestamps.tolist() == [10, 20, 26, 28]

"""Ground truth by radius, by frame tolerance, from lists and from VPR-Bench files."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.evaluation.groundtruth import from_indices, from_lists, from_positions, index_aligned, load_vprbench


def sets(gt):
    return [gt.matches(q).tolist() for q in range(gt.n_queries)]


def test_radius_in_metres_is_inclusive_and_empty_far_away():
    ref = np.stack([np.arange(10.0), np.zeros(10)], axis=1)  # a straight road, one frame per metre
    query = np.array([[2.4, 0.0], [3.0, 0.0], [100.0, 0.0], [5.0, 0.6]])
    small, large = from_positions(query, ref, [0.5, 1.0])
    assert sets(small) == [[2], [3], [], []]
    assert sets(large) == [[2, 3], [2, 3, 4], [], [5]]  # 3 m +- 1 m: both ends included
    assert (small.unit, small.tolerance, large.tolerance) == ("m", 0.5, 1.0)
    np.testing.assert_array_equal(large.has_match, [True, True, False, True])


def test_several_radii_match_separate_calls():
    rng = np.random.default_rng(3)
    ref = rng.uniform(0, 50, (40, 2))
    query = rng.uniform(0, 50, (25, 2))
    together = from_positions(query, ref, [2.0, 5.0, 10.0])
    for gt, radius in zip(together, [2.0, 5.0, 10.0]):
        alone = from_positions(query, ref, radius)[0]
        np.testing.assert_array_equal(gt.to_dense(), alone.to_dense())
        dense = np.linalg.norm(query[:, None] - ref[None], axis=2) <= radius
        np.testing.assert_array_equal(gt.to_dense(), dense)


def test_unknown_position_matches_nothing():
    ref = np.array([[0.0, 0.0], [np.nan, np.nan]])
    query = np.array([[np.nan, 0.0], [0.0, 0.0]])
    (gt,) = from_positions(query, ref, 1e6)
    assert sets(gt) == [[], [0]]


def test_frame_tolerance_on_index_aligned_sets():
    tol0, tol1, tol2 = index_aligned(5, 5, [0, 1, 2])
    assert sets(tol0) == [[0], [1], [2], [3], [4]]
    assert sets(tol1) == [[0, 1], [0, 1, 2], [1, 2, 3], [2, 3, 4], [3, 4]]
    assert sets(tol2)[0] == [0, 1, 2] and sets(tol2)[4] == [2, 3, 4]
    assert tol1.unit == "frames" and tol1.tolerance == 1


def test_frame_tolerance_with_subsampled_reference_places():
    # The reference kept original frames 0, 3, 6, 9; a query shows original frame 4.
    ref_places = np.array([0, 3, 6, 9])
    one, two = from_indices(np.array([4, -1, 9]), 4, [1, 2], reference_places=ref_places)
    assert sets(one) == [[1], [], [3]]
    assert sets(two) == [[1, 2], [], [3]]
    with pytest.raises(InputError, match="strictly increasing"):
        from_indices(np.array([0]), 2, 1, reference_places=np.array([3, 1]))


def test_bad_tolerances_are_refused():
    with pytest.raises(InputError, match="whole number"):
        index_aligned(3, 3, 1.5)
    with pytest.raises(InputError, match="radius"):
        from_positions(np.zeros((1, 2)), np.zeros((1, 2)), -1.0)


def test_contains_and_is_correct_agree_with_the_dense_matrix():
    gt = from_lists([[4, 1, 1], [], [0, 2]], n_references=5)
    assert sets(gt) == [[1, 4], [], [0, 2]]  # sorted, duplicates merged
    dense = gt.to_dense()
    q, r = np.meshgrid(np.arange(3), np.arange(-1, 6), indexing="ij")
    expected = np.zeros(q.shape, bool)
    inside = (r >= 0) & (r < 5)
    expected[inside] = dense[q[inside], r[inside]]
    np.testing.assert_array_equal(gt.contains(q, r), expected)
    np.testing.assert_array_equal(gt.is_correct(np.array([4, 0, 1])), [True, False, False])
    with pytest.raises(InputError, match="2 predictions for 3 queries"):
        gt.is_correct(np.array([0, 1]))


def test_lists_out_of_range_name_the_query():
    with pytest.raises(InputError, match="query 1: reference index 9 is outside 0..4"):
        from_lists([[0], [9]], n_references=5)


def test_widened_lists():
    gt = from_lists([[0], [3], []], n_references=5, source="x")
    wide = gt.widened(1)
    assert sets(wide) == [[0, 1], [2, 3, 4], []]
    assert wide.tolerance == 1 and wide.unit == "frames"


def write_vprbench(path, rows):
    data = np.empty((len(rows), 2), dtype=object)
    for i, (q, refs) in enumerate(rows):
        data[i, 0] = q
        data[i, 1] = refs
    np.save(path, data, allow_pickle=True)
    return path


def test_vprbench_file_round_trip(tmp_path):
    path = write_vprbench(tmp_path / "ground_truth_new.npy", [(0, [0, 1]), (1, range(1, 3)), (2, []), (3, 4)])
    gt = load_vprbench(path, n_queries=4, n_references=5)
    assert sets(gt) == [[0, 1], [1, 2], [], [4]]
    np.testing.assert_array_equal(gt.has_match, [True, True, False, True])


def test_vprbench_file_that_does_not_fit_the_folders(tmp_path):
    path = write_vprbench(tmp_path / "ground_truth_new.npy", [(0, [0]), (1, [7])])
    with pytest.raises(InputError, match=r"ground_truth_new.npy: 2 rows for 3 query images"):
        load_vprbench(path, n_queries=3, n_references=5)
    with pytest.raises(InputError, match=r"ground_truth_new.npy: row 1: reference index 7 is outside 0..4"):
        load_vprbench(path, n_queries=2, n_references=5)
    shuffled = write_vprbench(tmp_path / "shuffled.npy", [(1, [0]), (0, [1])])
    with pytest.raises(InputError, match=r"shuffled.npy: row 0 is for query 1"):
        load_vprbench(shuffled, n_queries=2, n_references=5)
    (tmp_path / "junk.npy").write_bytes(b"not numpy")
    with pytest.raises(InputError, match="junk.npy: not a readable .npy"):
        load_vprbench(tmp_path / "junk.npy", 1, 1)
    flat = tmp_path / "flat.npy"
    np.save(flat, np.arange(3))
    with pytest.raises(InputError, match=r"flat.npy: expected rows of \[query_index, reference_indices\]"):
        load_vprbench(flat, 3, 3)

"""The layout: where road, ground and what stands on it lie around the road, from one calibrated camera and
its motion, compared as it is and turned 180 degrees."""

from __future__ import annotations

import dataclasses
import os
import pickle
import subprocess
import sys

import numpy as np
import pytest

from lostx.core.build import _with_grids
from lostx.core.config import Config, LayoutConfig
from lostx.core.layout.classes import CHANNELS, CONTACTS, GROUND, OBJECT, ROAD, LayoutClasses
from lostx.core.layout.compare import GridStack, shifted, similarities, similarity
from lostx.core.layout.curve import opposite_turns, turned_about_centre
from lostx.core.layout.describer import FramePlacer, LiveLayout, Placed, map_grid, spread
from lostx.core.layout.grid import (
    LayoutGrid,
    accumulate,
    cell_weights,
    grid_shape,
    pack,
    pack_both,
    stored_half,
    unpack,
    unpack_levels,
)
from lostx.core.layout.projection import FramePoints, GroundProjector
from lostx.core.match.costs import EveryFrameCosts
from lostx.core.match.matcher import PlaceMatcher
from lostx.core.match.scores import MapScores
from lostx.core.motion.pose import compose, inverse, relative
from lostx.core.paths import data_dir
from lostx.core.route.sequence import SequenceFilter, signed
from lostx.replay.dataset import open_traverse

SCENE = data_dir() / "nuscenes-frontrear" / "scene-0523"
WEIGHTS = np.array([1, 1, 1, 1, 0.5, 1.0])


def _grid(rng: np.random.Generator, shape=(20, 15), seen: float = 0.8) -> LayoutGrid:
    mask = rng.random(shape) < seen
    values = rng.random((len(CHANNELS), *shape)).astype(np.float32) * mask
    return LayoutGrid(values, mask)


def test_a_grid_is_most_like_itself_and_a_turned_grid_like_its_turn(rng):
    grids = [_grid(rng) for _ in range(5)]
    stack = GridStack.of(grids)
    scores = similarity(grids[2], stack, WEIGHTS)
    assert scores[2] == pytest.approx(1.0) and np.all(scores[[0, 1, 3, 4]] < 0.5)
    turned = GridStack.of([g.turned() for g in grids])
    assert similarity(grids[2].turned(), turned, WEIGHTS)[2] == pytest.approx(1.0)
    assert np.array_equal(grids[2].turned().turned().values, grids[2].values)


@pytest.mark.parametrize("n", [257, 385])
def test_a_stack_whose_last_block_holds_one_grid_more_compares_every_grid(rng, n):
    """Grids are compared in blocks of 128, the last taking a lone grid in: 257 grids (or any 128 k + 1, as the rows a
    city map's sequence filter looks up often are) compare as each grid alone does."""
    grids = [_grid(rng, shape=(8, 6)) for _ in range(n)]
    query = grids[n - 1]
    scores = similarity(query, GridStack.of(grids), WEIGHTS)
    alone = [similarity(query, GridStack.of([g, g]), WEIGHTS)[0] for g in grids[-3:]]
    assert scores[n - 1] == pytest.approx(1.0)
    np.testing.assert_allclose(scores[-3:], alone, rtol=1e-5)


def test_a_sideways_shift_within_reach_is_found(rng):
    grid = _grid(rng, seen=1.0)
    moved = LayoutGrid(np.roll(grid.values, 1, axis=2), np.roll(grid.mask, 1, axis=1))
    stack = GridStack.of([moved])
    assert similarity(grid, stack, WEIGHTS, shifts=0)[0] < 0.5
    assert similarity(grid, stack, WEIGHTS, shifts=1)[0] == pytest.approx(1.0)


def test_both_headings_in_one_pass_equal_each_compared_alone(rng, monkeypatch):
    """Every map frame compared under both headings at once, and (on a map too large for that) one row's asked
    frames alone: the same similarities as one grid against the map, best over its shifts. The turned grid is
    compared with the other ends' grids where the map has them (the opposite heading)."""
    from lostx.core.match import combined

    grids = [_grid(rng) for _ in range(30)]  # fewer than REFINE: every frame is refined either way
    stack, other_ends, query = GridStack.of(grids), GridStack.of([_grid(rng) for _ in grids]), _grid(rng)
    monkeypatch.setattr(combined, "EVERY_FRAME_MAX", 10)
    refs = np.array([3, 17, 29])
    for opposite, turned_against in ((None, stack), (other_ends, other_ends)):
        alone = [similarity(query, stack, WEIGHTS, 1, 5), similarity(query.turned(), turned_against, WEIGHTS, 1, 5)]
        comparison = combined.LayoutComparison(query, stack, WEIGHTS, shifts=1, min_cells=5, opposite=opposite)
        # The shifted grids are compared again in one batch, their sums taken in another order: float32's precision.
        assert np.allclose(comparison.compute(), alone, atol=1e-5)
        for row in (combined.SAME, combined.OPPOSITE):
            large = combined.LayoutComparison(query, stack, WEIGHTS, shifts=1, min_cells=5, opposite=opposite)
            assert np.allclose(large.heading(row).at(refs), alone[row][refs], atol=1e-6)


def _smooth_grid(rng: np.random.Generator, shape=(20, 15)) -> LayoutGrid:
    import cv2

    values = np.stack([cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 1.0) for _ in CHANNELS])
    return LayoutGrid(values, np.ones(shape, dtype=bool))


def test_the_best_grids_are_compared_again_turned_a_few_degrees(rng):
    """A map grid of the same place seen 2 degrees apart (a curve's two ends) is found as itself by the query turned
    2 degrees; the refined scores equal every turn and shift compared with every map frame, one pair at a time."""
    from lostx.core.match import combined

    query = _smooth_grid(rng)
    grids = [_smooth_grid(rng) for _ in range(30)]
    grids[11] = query.rotated(2.0)
    stack = GridStack.of(grids)
    plain = combined.LayoutComparison(query, stack, WEIGHTS, shifts=1, min_cells=5).every()[0]
    turning = combined.LayoutComparison(query, stack, WEIGHTS, shifts=1, min_cells=5, turns=(-2.0, 0.0, 2.0))
    scores = turning.every()
    assert scores[0, 11] == pytest.approx(1.0, abs=1e-5) and plain[11] < 0.99
    for heading, view in enumerate((query, query.turned())):
        exact = _best_turned_and_shifted(view, grids, 5)
        assert np.allclose(scores[heading], exact, atol=5e-5)  # float32 sums of smooth grids


def _pearson_mean(query: LayoutGrid, grid: LayoutGrid, weights: np.ndarray, min_cells: int) -> float:
    """The similarity as defined, one pair at a time: the weighted mean over channels of the Pearson correlation
    over the cells both grids observed (0 for a channel constant there)."""
    common = query.mask & grid.mask
    if common.sum() < min_cells:
        return -np.inf
    r = []
    for x, y in zip(query.values[:, common].astype(np.float64), grid.values[:, common].astype(np.float64)):
        x, y = x - x.mean(), y - y.mean()
        var = (x @ x) * (y @ y)
        r.append((x @ y) / np.sqrt(var) if var > 1e-12 else 0.0)
    return float(np.average(r, weights=weights))


def _best_turned_and_shifted(view: LayoutGrid, maps: list[LayoutGrid], min_cells: int) -> np.ndarray:
    """Each map grid's best similarity with ``view`` turned 2 degrees either way or not and shifted a cell either way
    or not, each pair compared alone (:func:`_pearson_mean`)."""
    variants = [shifted(view.rotated(angle), s) for angle in (-2.0, 0.0, 2.0) for s in (-1, 0, 1)]
    return np.max([[_pearson_mean(v, g, WEIGHTS, min_cells) for g in maps] for v in variants], axis=0)


def _stored(packed: list[tuple[np.ndarray, np.ndarray]], shape: tuple[int, int]) -> GridStack:
    """Packed grids (:func:`pack`) as a map holds and compares them: one-byte levels."""
    return GridStack(*unpack_levels(np.stack([v for v, _ in packed]), np.stack([b for _, b in packed]), shape))


@pytest.mark.parametrize("seen", [0.3, 0.6, 0.97])
def test_comparisons_equal_each_pair_compared_alone(rng, seen):
    """A stack's sums over the cells a query observed (the grids' totals less the cells it missed, or the cells it
    saw, whichever are fewer), a map's grids kept as their stored levels: the similarity of each pair as defined (to
    the query's values rounded to whole levels against the stored levels: lostx.core.layout.compare.query_levels)."""
    shape = (20, 15)
    grids = [_grid(rng, shape, seen=rng.uniform(0.5, 1.0)) for _ in range(40)]
    grids[7] = LayoutGrid(grids[7].values, np.ones(shape, dtype=bool))
    grids[9] = LayoutGrid(grids[9].values * 0 + 0.5, grids[9].mask)  # constant: no correlation
    stored = [pack(g) for g in grids]
    levels = _stored(stored, shape)
    for query in (_grid(rng, shape, seen=seen), _grid(rng, shape, seen=seen).turned()):
        for stack, maps, atol in ((GridStack.of(grids), grids, 1e-5),
                                  (levels, [unpack(v, b, shape) for v, b in stored], 1e-3)):
            expected = [_pearson_mean(query, g, WEIGHTS, 25) for g in maps]
            assert np.allclose(similarity(query, stack, WEIGHTS, min_cells=25), expected, atol=atol)
            assert np.allclose(similarities([query, query.turned()], stack, WEIGHTS, min_cells=25)[1],
                               [_pearson_mean(query.turned(), g, WEIGHTS, 25) for g in maps], atol=atol)


def test_identical_grids_score_alike_wherever_they_lie(rng):
    """A stack's grids are compared alike wherever they lie in it, and in any subset of it (a map frame repeated where
    the camera stood still scores as its copies do). A map's grids (one-byte levels) tie exactly: every sum is of
    whole numbers, exact in any order. Grids of any values agree to float32's rounding, since BLAS may add up the
    rows of one product in different orders (OpenBLAS's AVX-512 kernels do, in the last bits)."""
    grid, other = _grid(rng, seen=0.95), _grid(rng, seen=0.95)
    for n in (5, 77, 128, 1001):
        grids = [grid if i % 3 else other for i in range(n)]
        for stack, atol in ((GridStack.of(grids), 1e-5), (_stored([pack(g) for g in grids], grid.mask.shape), 0.0)):
            for query in (_grid(rng, seen=0.9), _grid(rng, seen=0.4)):
                scores = similarities([query, query.turned()], stack, WEIGHTS, shifts=1, min_cells=5)
                assert np.allclose(scores[:, 1::3], scores[:, 1:2], rtol=0, atol=atol)
                assert np.allclose(scores[:, ::3], scores[:, :1], rtol=0, atol=atol)
                sub = stack.rows(np.arange(0, n, 2))
                assert np.allclose(similarities([query], sub, WEIGHTS, 1, 5)[0], scores[0, ::2], rtol=0, atol=atol)


_THREADS_SCRIPT = """
import sys
import numpy as np
from lostx.core.layout.compare import GridStack, similarities
from lostx.core.layout.grid import LayoutGrid, unpack_levels
data = np.load(sys.argv[1])
stack = GridStack(*unpack_levels(data["levels"], data["bits"], data["mask"].shape))
query = LayoutGrid(data["values"], data["mask"])
np.save(sys.argv[2], similarities([query, query.turned()], stack, data["weights"], shifts=1, min_cells=5))
"""


def test_a_maps_comparisons_do_not_depend_on_blas_threads(rng, tmp_path):
    """The comparison with a map's grids gives the same bits with one BLAS thread and with four (a comparison process
    and its caller may run different counts; OpenBLAS's AVX-512 kernels split a product's rows by thread, and sum
    them in another order)."""
    packed = [pack(_grid(rng, seen=0.9)) for _ in range(300)]
    query = _grid(rng, seen=0.8)
    stack = _stored(packed, query.mask.shape)
    np.savez(tmp_path / "in.npz", levels=np.stack([v for v, _ in packed]), bits=np.stack([b for _, b in packed]),
             values=query.values, mask=query.mask, weights=WEIGHTS)
    got = []
    for threads in ("1", "4"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        out = tmp_path / f"{threads}.npy"
        subprocess.run([sys.executable, "-c", _THREADS_SCRIPT, str(tmp_path / "in.npz"), str(out)], check=True, env=env,
                       timeout=120)
        got.append(np.load(out))
    assert np.array_equal(got[0], got[1])
    assert np.array_equal(got[0], similarities([query, query.turned()], stack, WEIGHTS, shifts=1, min_cells=5))


def test_too_few_cells_in_common_give_no_similarity(rng):
    grid = _grid(rng, seen=1.0)
    sparse = LayoutGrid(grid.values, np.zeros_like(grid.mask))
    sparse.mask[0, :10] = True
    assert similarity(grid, GridStack.of([sparse]), WEIGHTS, min_cells=25)[0] == -np.inf
    assert np.isfinite(similarity(grid, GridStack.of([sparse]), WEIGHTS, min_cells=5)[0])


def test_a_map_keeps_a_grid_within_one_quantisation_step(rng):
    grid = _grid(rng)
    grid.values[2:] *= 3.0  # contacts in log(1 + metres)
    values, bits = pack(grid)
    assert values.dtype == np.uint8 and values.nbytes + bits.nbytes <= 4096
    back = unpack(values, bits, grid.mask.shape)
    assert np.array_equal(back.mask, grid.mask)
    assert np.abs(back.values[:2] - grid.values[:2]).max() <= 0.5 / 255 + 1e-6
    assert np.abs(back.values[2:] - grid.values[2:]).max() <= 0.5 * 4.0 / 255 + 1e-6


def test_poses_compose_and_invert():
    a, b = np.array([3.0, -1.0, 0.4]), np.array([1.0, 2.0, -1.2])
    assert np.allclose(compose(a, inverse(a)), 0.0, atol=1e-12)
    assert np.allclose(compose(a, relative(a, b)), b)
    # Two metres forward after turning left a quarter: two metres to the left.
    assert np.allclose(compose(np.array([0.0, 0.0, np.pi / 2]), np.array([2.0, 0.0, 0.0])), [0.0, 2.0, np.pi / 2])


def _arc(radius: float, length: float, spacing: float, facing_back: bool) -> np.ndarray:
    """(N, 3) camera ground poses driving anticlockwise round a circle of ``radius`` from (radius, 0), the camera
    facing the way the car moves or back."""
    phi = np.arange(0.0, length, spacing) / radius
    yaw = phi + np.pi / 2 + (np.pi if facing_back else 0.0)
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), np.arctan2(np.sin(yaw), np.cos(yaw))], axis=1)


def test_the_other_end_of_a_bend_is_turned_by_the_angle_between_its_two_tangents():
    """The two cameras viewing one point from the two ends of a bend stand where the two tangents from that point
    touch the circle: equally far from it, their headings 2 atan(centre / radius) apart. A camera facing back on
    the same drive looks the other way round the bend; a straight road turns nothing."""
    centre, radius = 15.0, 50.0
    expected = np.degrees(2 * np.arctan(centre / radius))  # 33.4 degrees
    middle = np.arange(40, 60)  # the other ends lie on the route, not beyond it
    front = opposite_turns(_arc(radius, 200.0, 2.0, facing_back=False), centre)
    rear = opposite_turns(_arc(radius, 200.0, 2.0, facing_back=True), centre)
    assert np.allclose(front[middle], expected, atol=0.5), front[middle]
    assert np.allclose(rear[middle], -expected, atol=0.5), rear[middle]
    straight = np.stack([np.arange(0.0, 100.0, 3.0), np.zeros(34), np.zeros(34)], axis=1)
    assert np.allclose(opposite_turns(straight, centre), 0.0, atol=1e-9)
    # Beyond the route's ends the road is taken to go on straight: a frame whose other end lies beyond is turned
    # by the bend between it and the end.
    step = np.degrees(2.0 / radius)
    assert np.allclose(front[-4:], [3 * step, 2 * step, step, 0.0], atol=0.01), front[-4:]
    assert np.allclose(rear[:4], [0.0, -step, -2 * step, -3 * step], atol=0.01), rear[:4]


def test_a_grid_gathered_from_a_camera_turned_about_its_centre_is_the_grid_turned_back(rng):
    """Gathering the same points about the grid's centre point turned by d degrees gives, cell for cell, the grid
    turned by -d: what a map stores for the other end of its stretch, with nothing resampled."""
    config = LayoutConfig(blur=0.0)
    xy = np.stack([rng.uniform(-5, 35, 40000), rng.uniform(-15, 15, 40000)], axis=1).astype(np.float32)
    kind = (np.abs(xy[:, 1] - 0.3 * (xy[:, 0] - 15.0)) > 4.0).astype(np.int8)  # a road crossing the grid askew
    z = np.zeros(0, np.float32)
    points = FramePoints(xy, kind, np.ones(len(xy), np.float32), np.zeros((0, 2), np.float32), np.zeros(0, np.int8), z)
    pose = np.array([3.0, -2.0, 0.4])
    as_seen = accumulate([points], pose[None], pose, config)
    for degrees in (-15.0, 15.0):
        gathered = accumulate([points], pose[None], turned_about_centre(pose, degrees, config.centre), config)
        right, wrong = as_seen.rotated(-degrees), as_seen.rotated(degrees)
        both = gathered.mask & right.mask & wrong.mask
        assert np.abs(gathered.values[0][both] - right.values[0][both]).mean() < 0.05
        assert np.abs(gathered.values[0][both] - wrong.values[0][both]).mean() > 0.2


def test_a_map_stores_both_ends_of_a_stretch_and_reads_a_single_grid_for_both(rng):
    grid, other = _grid(rng), _grid(rng)
    shape = grid.mask.shape
    values, bits = pack_both(grid, other)
    for other_end, expected in ((False, grid), (True, other)):
        back = unpack(*stored_half(values, bits, shape, other_end), shape)
        assert np.array_equal(back.mask, expected.mask)
        assert np.abs(back.values - expected.values).max() <= 0.5 * 4.0 / 255 + 1e-6
    single = pack(grid)  # a map built before the other end was stored
    for other_end in (False, True):
        assert np.array_equal(unpack(*stored_half(*single, shape, other_end), shape).values,
                              unpack(*single, shape).values)


def _point(x: float, y: float, kind: int = ROAD) -> FramePoints:
    z = np.zeros(0, np.float32)
    return FramePoints(np.array([[x, y]], np.float32), np.array([kind], np.int8), np.array([1.0], np.float32),
                       np.zeros((0, 2), np.float32), np.zeros(0, np.int8), z)


def test_frames_are_gathered_where_the_motion_puts_them():
    config = LayoutConfig(blur=0.0)
    # A camera 4 m further on sees the same road point 4 m nearer; gathered, both land in one cell.
    first, second = _point(20.0, 3.0), _point(16.0, 3.0, OBJECT)
    poses = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0]])
    grid = accumulate([first, second], poses, poses[1], config)
    assert grid.observed == 1
    road = grid.values[CHANNELS.index("road")]
    assert road[grid.mask][0] == pytest.approx(0.5)  # one ray of road, one of something standing there
    rows, cols = grid_shape(config)
    (a,), (x,) = np.nonzero(grid.mask)
    assert (a, x) == (int((16.0 - (config.centre - config.length / 2)) // config.cell),
                      int((config.width / 2 - 3.0) // config.cell))
    # From the other end of the stretch (a camera 30 m on, looking back: the grids share their centre), the
    # same point lies in the grid turned 180 degrees.
    ahead = accumulate([first], poses[:1], np.array([0.0, 0.0, 0.0]), config)
    back = accumulate([first], poses[:1], np.array([2 * config.centre, 0.0, np.pi]), config)
    assert np.array_equal(back.mask, ahead.turned().mask) and back.observed == 1
    assert rows == 20 and cols == 15


def test_frames_gathered_land_where_each_pose_puts_them(rng):
    """Each frame's points moved by its own pose and counted by kind and cell, the frames' counts summed in turn:
    the same sums, to the bit, as the rotation and binning written out by hand (an empty frame and a one-point
    frame among them)."""
    config = LayoutConfig()
    rows, cols = grid_shape(config)
    frames = [(rng.uniform([-10, -30], [70, 30], (n, 2)).astype(np.float32), rng.integers(0, 3, n).astype(np.int8),
               rng.uniform(0.5, 9.0, n).astype(np.float32)) for n in (500, 0, 800, 1)]
    here = np.column_stack([rng.uniform(-20, 5, 4), rng.uniform(-3, 3, 4), rng.uniform(-0.3, 0.3, 4)])
    expected = np.zeros(3 * rows * cols)
    for (xy, kind, weight), pose in zip(frames, here):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        p = xy.astype(np.float64)
        along, left = pose[0] + c * p[:, 0] - s * p[:, 1], pose[1] + s * p[:, 0] + c * p[:, 1]
        a = np.floor((along - (config.centre - config.length / 2.0)) / config.cell).astype(np.int64)
        x = np.floor((config.width / 2.0 - left) / config.cell).astype(np.int64)
        inside = (a >= 0) & (a < rows) & (x >= 0) & (x < cols)
        expected += np.bincount((kind[inside] * rows + a[inside]) * cols + x[inside], weight[inside], len(expected))
    assert np.array_equal(cell_weights(frames, here, 3, config), expected)


def test_class_roles_are_found_however_a_model_spells_its_names():
    """ADE20K's published names list synonyms, the class's own first ("streetlight;street;lamp" is a lamp, not the
    street); Mapillary Vistas' are paths, the last step the class (a marking's path ends in its shape)."""
    ade = ["wall", "building;edifice", "sky", "tree", "road;route", "sidewalk;pavement",
           "person;individual;someone;somebody;mortal;soul", "earth;ground", "car;auto;automobile;machine;motorcar",
           "streetlight;street;lamp"]
    vistas = ["construction--flat--road", "construction--flat--sidewalk", "marking--discrete--arrow--left",
              "object--vehicle--car", "nature--vegetation", "nature--sky", "construction--structure--building",
              "object--support--pole", "human--person"]
    contact = {name: i for i, name in enumerate(CONTACTS)}
    for names, expected in (
        (ade, [(OBJECT, "building", False), (OBJECT, "building", False), (-1, "other", False),
               (OBJECT, "vegetation", False), (ROAD, "other", False), (GROUND, "other", False),
               (OBJECT, "other", True), (GROUND, "other", False), (OBJECT, "vehicle", True),
               (OBJECT, "other", False)]),
        (vistas, [(ROAD, "other", False), (GROUND, "other", False), (ROAD, "other", False),
                  (OBJECT, "vehicle", True), (OBJECT, "vegetation", False), (-1, "other", False),
                  (OBJECT, "building", False), (OBJECT, "other", False), (OBJECT, "other", True)]),
    ):
        classes = LayoutClasses.of_model(names)
        assert classes is not None
        found = [(int(classes.ray[i]), CONTACTS[classes.contact[i]], bool(classes.is_mover[i]))
                 for i in range(len(names))]
        assert found == expected
        assert all(contact[kind] == classes.contact[i] for i, (_, kind, _) in enumerate(expected))
    assert LayoutClasses.of_model(["streetlight;street;lamp", "sky", "building"]) is None  # no road: no layout


def test_frames_are_chosen_evenly_over_the_distance():
    travelled = np.arange(0.0, 60.0, 1.0)
    chosen = spread(travelled, 10.0, 34.0, 5, keep=34)
    assert len(chosen) <= 6 and 34 in chosen and chosen.min() >= 10 and chosen.max() <= 34
    assert np.all(np.diff(travelled[chosen]) >= 4.0)
    assert len(spread(travelled, 10.0, 13.0, 12, keep=13)) == 4


@pytest.mark.parametrize("stream", ["a camera at 50 Hz", "a stop of 200 frames"])
def test_a_live_grid_gathers_its_distance_at_any_frame_rate(stream):
    """Each frame sees a road point 25 m ahead of it; the grid gathers the last 24 m, so its points spread over some
    twelve 2 m rows, whether the frames come 0.1 m apart or the car stood still for 200 of them (the newest 48
    frames kept spanned 4.8 m, and a stop none)."""
    config = LayoutConfig(blur=0.0)
    live = LiveLayout(config)
    if stream == "a stop of 200 frames":
        at = list(np.arange(0.0, 30.0, 2.0)) + [28.0] * 200
    else:
        at = list(np.arange(0.0, 30.0, 0.1))
    for x in at:
        grid = live.add(Placed(_point(25.0, 0.0), np.array([x, 0.0, 0.0]), float(x))).grid()
    rows = np.flatnonzero(grid.mask.any(axis=1))
    assert rows.max() - rows.min() + 1 >= 11, rows


@pytest.fixture(scope="module")
def scene():
    if not SCENE.is_dir():
        pytest.fail(f"test data missing: {SCENE}")
    return SCENE


def _placed(traverse, mosaic, config: Config) -> list[Placed]:
    classes = LayoutClasses.of_model(mosaic.info.class_names)
    placer = FramePlacer(classes, config.layout, config.motion)
    return [placer(frame, mosaic(frame.image).label_map) for frame in traverse]


def test_the_same_stretch_from_its_two_ends_agrees_better_turned(scene, mosaic):
    """Front frame i and rear frame i + 12 show one stretch of road from its two ends (the data's ground truth):
    their grids agree better with one of them turned 180 degrees than as they are, compared as the defaults compare
    them (shifted sideways up to ``across_shift``)."""
    config = Config()
    shifts = int(config.layout.across_shift / config.layout.cell)
    front = _placed(open_traverse(scene / "front").subset(range(20)), mosaic, config)
    rear = _placed(open_traverse(scene / "rear").subset(range(8, 34)), mosaic, config)
    live = LiveLayout(config.layout)
    queries = [live.add(p).grid() for p in front]
    pairs = [(i, i + 12 - 8) for i in range(6, 20, 2)]
    turned = as_is = 0
    margins = []
    for i, j in pairs:
        ref = GridStack.of([map_grid(rear, j, config.layout)])
        a, b = similarity(queries[i].turned(), ref, WEIGHTS, shifts)[0], similarity(queries[i], ref, WEIGHTS, shifts)[0]
        turned += a > b
        as_is += b > a
        margins.append(a - b)
    assert turned >= len(pairs) - 1, margins
    assert np.mean(margins) > 0.1


def _denser(frames: list[Placed], times: int) -> list[Placed]:
    """Each frame's evidence again at ``times - 1`` poses on the way to the next frame: a traverse recorded
    ``times`` as densely (the evidence itself is the frame's)."""
    out = []
    for placed, after in zip(frames, frames[1:]):
        turn = np.arctan2(np.sin(after.pose[2] - placed.pose[2]), np.cos(after.pose[2] - placed.pose[2]))
        for t in np.arange(times) / times:
            pose = np.array([*(placed.pose[:2] + t * (after.pose[:2] - placed.pose[:2])), placed.pose[2] + t * turn])
            out.append(dataclasses.replace(placed, pose=pose,
                                           travelled=placed.travelled + t * (after.travelled - placed.travelled)))
    return out + frames[-1:]


def test_a_densely_recorded_map_gives_its_frames_the_grids_a_sparse_one_does(scene, mosaic):
    """The front camera's frames 3 m apart, and recorded sixteen times as densely (0.2 m apart, a 30 Hz video at
    city speed): each frame's grids, as its camera and as the other end of its stretch views it, are the same
    places seen from the same frames' evidence, since what they gather and the route searched for the other end
    (45 m ahead) are set in metres. Holding the route by a count of frames cut both short at this density
    (the other end's grids then correlated 0.91 at the median, 0.5 at the worst, smoothed 2 m; measured now, smoothed
    1 m as by default, 0.94 at the median, 0.87 at the worst)."""
    config = Config().layout
    front = _placed(open_traverse(scene / "front"), mosaic, Config())
    times = 16
    sparse = [g for _, _, g in _with_grids(((i, None, p) for i, p in enumerate(front)), config)]
    dense = [g for _, _, g in _with_grids(((i, None, p) for i, p in enumerate(_denser(front, times))), config)]
    assert len(dense) == times * (len(front) - 1) + 1
    for heading in (0, 1):
        agree = [np.corrcoef(sparse[i][heading].values.ravel(), dense[times * i][heading].values.ravel())[0, 1]
                 for i in range(len(front))]
        assert np.median(agree) > 0.93 and min(agree) > 0.8, (heading, np.round(agree, 2))


def test_turned_and_shifted_comparisons_with_a_maps_stored_grids_equal_each_pair_compared_alone(scene, mosaic):
    """Front frames against the rear camera's grids as a map stores them (one-byte levels; classes absent from
    many grids, whose channels are all zero: no correlation there, not rounding noise): each heading's scores are
    the best of every turn and shift, each pair compared alone in float64."""
    from lostx.core.match import combined

    config = Config()
    rear = _placed(open_traverse(scene / "rear"), mosaic, config)
    front = _placed(open_traverse(scene / "front").subset(range(16)), mosaic, config)
    stored = [pack(map_grid(rear, j, config.layout)) for j in range(len(rear))]
    shape = grid_shape(config.layout)
    stack = _stored(stored, shape)
    maps = [unpack(v, b, shape) for v, b in stored]
    live = LiveLayout(config.layout)
    queries = [live.add(p).grid() for p in front][10::2]
    for query in queries:
        comparison = combined.LayoutComparison(query, stack, WEIGHTS, shifts=1, min_cells=25, turns=(-2.0, 0.0, 2.0))
        scores = comparison.every()
        for heading, view in enumerate((query, query.turned())):
            exact = _best_turned_and_shifted(view, maps, 25)
            # To the query's values rounded to whole levels (query_levels: 3.5e-4 at most here).
            assert np.allclose(scores[heading], exact, atol=1e-3)
            assert scores[heading].max() <= 1.0


def test_a_rear_camera_whose_file_leaves_its_boot_lid_in_still_finds_what_stands_by_the_road(scene, mosaic):
    """The rear camera's bottom rows show the car's boot lid. A camera file without ``body`` leaves them in; every
    column then starts with the lid, and the things standing by the road above it must still be found, as where
    the rows are cut."""
    traverse = open_traverse(scene / "rear")
    classes = LayoutClasses.of_model(mosaic.info.class_names)
    frames = list(traverse.subset([0, 10, 20, 30]))
    for frame in frames:
        labels = mosaic(frame.image).label_map
        metres = {}
        for body in (traverse.geometry.body, 0.0):
            project = GroundProjector(dataclasses.replace(traverse.geometry, body=body), labels.shape, classes, 60.0)
            metres[body] = float(project(labels).contact_weight.sum())
        assert traverse.geometry.body > 0.05 and metres[traverse.geometry.body] > 10.0
        assert metres[0.0] == pytest.approx(metres[traverse.geometry.body], rel=0.1), (frame.id, metres)


def test_a_map_of_frames_without_a_camera_has_no_layout_and_matches_as_before(day_map, robotcar, mosaic):
    assert day_map.layout_settings is None and day_map.progress is None
    on = PlaceMatcher(day_map, Config(), mosaic)
    off = PlaceMatcher(day_map, dataclasses.replace(Config(), layout=LayoutConfig(enabled="off")), mosaic)
    assert "no layout" in (on.layout_off or "")
    for frame in open_traverse(robotcar / "night").subset(range(4)):
        a, b = on.match(frame), off.match(frame)
        assert np.array_equal(a.same.candidates, b.same.candidates) and a.progress is None


def _route_costs(truth: np.ndarray, n_refs: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Scores of each frame over the map: low at its true map frame, noise elsewhere."""
    scores = []
    for true in truth:
        s = rng.normal(0.0, 1.0, n_refs)
        s[int(round(true))] -= 6.0
        scores.append(s)
    return scores


def test_the_sequence_follows_the_distance_through_a_stop_and_changes_of_speed(rng):
    n_refs = 120
    route = np.arange(n_refs) * 2.0  # a map frame every 2 m
    steps = np.concatenate([np.full(8, 3.0), np.zeros(6), np.full(8, 1.0), np.full(10, 4.0)])  # metres a frame
    progress = 10.0 + np.concatenate([[0.0], np.cumsum(steps)])
    truth = progress / 2.0  # the true map frame of each query frame
    scores = _route_costs(truth, n_refs, rng)

    def run(follow_distance: bool) -> np.ndarray:
        costs = EveryFrameCosts(n_refs, 8, 10, 100.0)
        speeds = signed((0.8, 1.0, 1.25), stopped=False) if follow_distance else signed((0.5, 1.0, 1.5, 2.0), True)
        seq = SequenceFilter(8, tuple(speeds), 0, 0.0, costs, anchors=5, neighbourhood=5,
                             route=route if follow_distance else None, reach=1e9)
        out = []
        for t, s in enumerate(scores):
            result = seq.update(MapScores.of_array(s), np.argsort(s)[:3], None, None,
                                float(progress[t]) if follow_distance else None)
            out.append(result.position)
        return np.array(out)

    after = slice(8, None)  # once the window is full
    along = run(True)
    assert np.all(np.abs(along[after] - truth[after]) <= 1.0), np.round(along - truth, 1)
    frames = run(False)
    assert np.abs(frames[after] - truth[after]).max() > 1.0  # straight in frames, the stop and the speeds break it


def test_at_a_high_frame_rate_or_stopped_the_window_keeps_its_reach_in_metres(rng):
    """Frames 0.5 m apart (four times a 2 Hz rate) and a stop: a frame nearer than reach / length to the frame
    before the newest takes the newest's place, so that the window still spans most of its reach in metres and
    sees ten places, not two."""
    n_refs, reach, length = 150, 30.0, 10
    route = np.arange(n_refs) * 2.0
    steps = np.concatenate([np.full(60, 0.5), np.zeros(20), np.full(60, 0.5)])
    progress = 10.0 + np.concatenate([[0.0], np.cumsum(steps)])
    truth = np.rint(progress / 2.0).astype(int)
    looks = rng.normal(0.0, 1.0, (n_refs, n_refs))  # frames at one place share its look-alikes
    scores = [looks[t] - 2.0 * (np.arange(n_refs) == t) for t in truth]

    def run(spacing: float) -> tuple[np.ndarray, np.ndarray]:
        seq = SequenceFilter(length, tuple(signed((0.8, 1.0, 1.25), stopped=False)), 0, 0.0,
                             EveryFrameCosts(n_refs, length, 10, 100.0), anchors=5, neighbourhood=5, route=route,
                             reach=reach, spacing=spacing)
        results = [seq.update(MapScores.of_array(s), np.argsort(s)[:3], None, None, float(q))
                   for s, q in zip(scores, progress)]
        span = np.array([2.0 * abs(r.trajectory[-1] - r.trajectory[0]) for r in results])
        return np.array([r.position for r in results]), span

    kept, kept_span = run(reach / length)
    recent, recent_span = run(0.0)
    later = slice(70, None)  # once 30 m are travelled, through the stop and after
    assert kept_span[later].min() >= 2 * reach / 3 and recent_span[later].max() <= 6.0
    kept_wrong = int((np.abs(kept - truth)[later] > 1).sum())
    recent_wrong = int((np.abs(recent - truth)[later] > 1).sum())
    assert kept_wrong <= 2 and recent_wrong >= 10 * max(kept_wrong, 1), (kept_wrong, recent_wrong)


def test_a_stack_of_grids_goes_to_another_process_as_its_grids_alone_and_compares_the_same(rng):
    """A map's grids are handed to the comparison process pickled: only the grids and their scale travel (not the
    stack's cell-major copies), and the stack made again from them holds the same arrays and compares the same."""
    n, a, x = 300, 20, 15
    levels = rng.integers(0, 256, size=(n, len(CHANNELS), a, x), dtype=np.uint8)
    masks = rng.random((n, a, x)) < 0.8
    stack = GridStack(levels, masks, np.full(len(CHANNELS), 255.0))
    sent = pickle.dumps(stack)
    assert len(sent) < 1.01 * stack.grids.nbytes
    again = pickle.loads(sent)
    for name in ("grids", "cells", "scale", "totals", "square_totals"):
        assert np.array_equal(getattr(again, name), getattr(stack, name)), name
    assert [b for b, _ in again.blocks] == [b for b, _ in stack.blocks]
    query = LayoutGrid(rng.random((len(CHANNELS), a, x)).astype(np.float32), rng.random((a, x)) < 0.9)
    weights = np.ones(len(CHANNELS))
    assert np.array_equal(similarities([query, query.turned()], again, weights, 1, 25),
                          similarities([query, query.turned()], stack, weights, 1, 25))

"""``lostx eval`` on the real RobotCar pair: every method and mode, the report, the plots, the cache."""

from __future__ import annotations

import json
import shutil

import pytest

from lostx.evaluation.report import REQUIRED_KEYS

from test_cli import assert_one_line_error, lostx


@pytest.fixture(scope="module")
def report(tmp_path_factory, robotcar):
    out = tmp_path_factory.mktemp("eval") / "report"
    proc = lostx("eval", "--reference", robotcar / "day", "--query", robotcar / "night", "--out", out,
                 "--window", "3", "--quiet")
    assert proc.returncode == 0, proc.stderr
    return out, proc.stdout


def entries(out) -> list[dict]:
    return json.loads((out / "report.json").read_text())


def find(rows, method, mode, tolerance):
    (row,) = [r for r in rows if (r["method"], r["mode"], r["tolerance"]) == (method, mode, tolerance)]
    return row


def test_every_method_mode_and_tolerance_is_reported(report):
    out, stdout = report
    rows = entries(out)
    assert len(rows) == 4 * 2 * 3
    for row in rows:
        assert set(REQUIRED_KEYS) <= set(row)
        assert row["tolerance_unit"] == "frames" and row["n_queries"] == 10
    assert "| lostx | single | 0 frames |" in (out / "report.md").read_text()
    assert "| lostx | single |" in stdout


def test_figures_match_the_single_frame_and_sequence_runs(report):
    rows = entries(report[0])
    # The same frames as tests/test_robotcar.py and test_localizer.py: 6 and 7 of 10 exact, all within one.
    assert find(rows, "lostx", "single", 0.0)["recall_at_1"] == pytest.approx(0.6)
    assert find(rows, "lostx", "single", 1.0)["recall_at_1"] == pytest.approx(1.0)
    assert find(rows, "lostx", "sequence", 0.0)["recall_at_1"] == pytest.approx(0.7)
    assert find(rows, "lostx", "single", 1.0)["recall_at_100p"] == pytest.approx(1.0)
    # The verification earns its keep over the descriptor alone (measured: 20 % vs 60 % exact), and over SeqSLAM's
    # thumbnails (none exact: a night thumbnail's mirrored match is as good as its own, so its heading is found the
    # wrong way in 3 of 10 frames).
    assert find(rows, "lost", "single", 0.0)["recall_at_1"] == pytest.approx(0.2)
    assert find(rows, "thumbnail", "single", 0.0)["recall_at_1"] == pytest.approx(0.0)


def test_recall_comes_with_its_interval_and_the_methods_are_compared_query_by_query(report):
    out = report[0]
    row = find(entries(out), "lostx", "single", 0.0)
    # 6 of 10 exact: Wilson's 95 % interval 31-83 %.
    assert (row["recall_at_1_low"], row["recall_at_1_high"]) == pytest.approx((0.312674, 0.831820), abs=1e-5)
    text = (out / "report.md").read_text()
    section = text[text.index("## Differences, query by query"):]
    rows = {tuple(c.strip() for c in line.strip("|").split("|")[:3]): line
            for line in section.splitlines() if line.startswith("| ")}
    # Each method against LoST-X in the same mode, and each sequence against its single frame: the splits
    # add up to the recalls' difference (LoST 2, LoST-X 6 of 10 single; the sequence 7).
    lost = rows[("LoST, single", "LoST-X, single", "0 frames")].split("|")
    assert int(lost[4]) - int(lost[5]) == 2 - 6
    seq = rows[("LoST-X, sequence", "LoST-X, single", "0 frames")].split("|")
    assert int(seq[4]) - int(seq[5]) == 7 - 6


def test_plots_are_written_and_shown_in_the_report(report, robotcar):
    out = report[0]
    text = (out / "report.md").read_text()
    for name in ("pr_0frames.png", "pr_1frames.png", "pr_2frames.png", "max_f1_vs_tolerance.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
        assert f"]({name})" in text
    # The settings that produced the numbers.
    assert f"| reference | `{(robotcar / 'day').resolve()}` (10 frames) |" in text
    assert f"| query | `{(robotcar / 'night').resolve()}` (10 frames) |" in text
    assert "| sequence window | 3 frames |" in text
    assert "| backbone | mosaic-ade20k (`mosaic-r4-ade20k31-uint8.tflite`) |" in text


def test_rerunning_reuses_the_network_outputs(report, robotcar, tmp_path):
    out = report[0]
    copy = tmp_path / "again"
    shutil.copytree(out / "cache", copy / "cache")
    before = {p.name: p.stat().st_mtime_ns for p in (copy / "cache").rglob("*") if p.is_file()}
    proc = lostx("eval", "--reference", robotcar / "day", "--query", robotcar / "night", "--out", copy,
                 "--window", "3", "--quiet")
    assert proc.returncode == 0, proc.stderr
    after = {p.name: p.stat().st_mtime_ns for p in (copy / "cache").rglob("*") if p.is_file()}
    assert after == before  # nothing rebuilt or rewritten
    assert any(name.startswith("queries-") for name in after)
    assert entries(copy) == entries(out)


def test_mismatched_pair_is_a_one_line_error(robotcar, tmp_path):
    short = tmp_path / "short"
    short.mkdir()
    for name in sorted(p.name for p in (robotcar / "night").iterdir())[:7]:
        shutil.copy(robotcar / "night" / name, short / name)
    proc = lostx("eval", "--reference", robotcar / "day", "--query", short, "--out", tmp_path / "r",
                 "--format", "pairs")
    assert_one_line_error(proc, "index-aligned")

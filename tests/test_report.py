"""report.json, the markdown table, the PNG figures, and reading back `lostx match` CSVs."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from lostx.evaluation import report
from lostx.core.errors import InputError
from lostx.evaluation.groundtruth import from_lists, index_aligned
from lostx.evaluation.metrics import evaluate, evaluate_tolerances
from lostx.replay.matches import read_matches_csv


def sample_evaluations():
    gts = index_aligned(6, 6, [0, 1, 2])
    pred = np.array([0, 2, 2, 4, 4, 1])
    score = np.array([0.1, 0.5, 0.2, 0.4, 0.3, 0.6])
    cands = np.array([[0, 1], [2, 1], [2, 3], [4, 3], [4, 5], [1, 0]])
    return evaluate_tolerances(pred, score, gts, cands)


def test_report_json_has_the_agreed_keys_and_null_for_undefined(tmp_path):
    evals = sample_evaluations()
    undefined = evaluate(np.array([0]), np.array([0.1]), from_lists([[]], 2))  # nothing to recall: NaN
    entries = [report.report_entry("thumbnail", "single", e) for e in evals]
    entries.append(report.report_entry("lost", "sequence", undefined, note="no matchable query"))
    path = report.write_report_json(tmp_path / "out" / "report.json", entries)
    data = json.loads(path.read_text())
    assert len(data) == 4
    for key in report.REQUIRED_KEYS:
        assert key in data[0]
    assert data[0]["tolerance"] == 0.0 and data[0]["tolerance_unit"] == "frames" and data[0]["n_queries"] == 6
    assert data[0]["max_f1"] == pytest.approx(evals[0].max_f1)
    assert data[3]["recall_at_100p"] is None and data[3]["note"] == "no matchable query"
    back = report.read_report_json(path)
    assert math.isnan(back[3]["max_f1"]) and back[1]["mode"] == "single"


def test_report_entry_refuses_unknown_mode_and_incomplete_entries(tmp_path):
    ev = sample_evaluations()[0]
    with pytest.raises(InputError, match="mode must be one of single, sequence"):
        report.report_entry("x", "batch", ev)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="report entry 0 .* lacks max_f1"):
        report.write_report_json(tmp_path / "r.json", [{k: 0 for k in report.REQUIRED_KEYS if k != "max_f1"}])


def test_markdown_table_rows_in_percent():
    evals = sample_evaluations()
    text = report.markdown_table([report.report_entry("thumbnail", "single", e) for e in evals])
    lines = text.strip().splitlines()
    assert lines[0].startswith("| method | mode | tolerance | R@100P oracle % | localized | localized prec. %")
    assert len(lines) == 2 + 3
    assert f"| thumbnail | single | 1 frame | {100 * evals[1].recall_at_100p:.1f} |" in lines[3]
    assert "| thumbnail | single | 2 frames |" in lines[4]


def test_plots_are_written_as_png(tmp_path):
    evals = sample_evaluations()
    pr = report.plot_pr_curves([(f"±{e.tolerance:g} frames", e.curve) for e in evals], tmp_path / "pr.png")
    f1 = report.plot_max_f1_vs_tolerance([("thumbnail", evals), ("again", evals)], tmp_path / "f1.png")
    for path in (pr, f1):
        image = cv2.imread(str(path))
        assert image is not None and image.shape[0] > 300 and image.shape[1] > 400
        assert image.std() > 10  # something drawn, not a blank canvas
    metric = evaluate(np.array([0]), np.array([0.1]), from_lists([[0]], 1, 5.0, "m"))
    with pytest.raises(InputError, match="mix tolerance units"):
        report.plot_max_f1_vs_tolerance([("a", evals), ("b", [metric])], tmp_path / "bad.png")


def test_read_matches_csv_of_lostx_match(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text(
        "query_index,query_file,match_index,match_file,score,confidence,candidates,distance,correspondences\n"
        "0,a.png,3,x.png,0.5,0.2,3 1 2,0.5,\n"
        "1,b.png,1,y.png,0.25,0.9,1 0,0.25,\n"
    )
    table = read_matches_csv(path)
    np.testing.assert_array_equal(table.predictions, [3, 1])
    np.testing.assert_allclose(table.scores, [0.5, 0.25])
    np.testing.assert_allclose(table.confidence, [0.2, 0.9])
    np.testing.assert_array_equal(table.candidates, [[3, 1, 2], [1, 0, -1]])


def test_read_matches_csv_bad_rows_name_the_line(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("query_index,match_index,score\n0,3,0.5\n1,x,0.2\n")
    with pytest.raises(InputError, match=r"m\.csv:3: malformed row"):
        read_matches_csv(path)
    path.write_text("query_index,match_index,score\n0,3,0.5\n2,1,0.2\n")
    with pytest.raises(InputError, match=r"m\.csv:3: query_index 2 where 1 was expected"):
        read_matches_csv(path)
    path.write_text("query,match_index\n")
    with pytest.raises(InputError, match=r"m\.csv:1: header lacks query_index, score"):
        read_matches_csv(path)


def test_a_method_keeps_its_colour_and_modes_differ_in_dashes():
    styles = report.method_styles([("lostx", "single"), ("lostx", "sequence"), ("thumbnail", "single"),
                                   ("thumbnail", "sequence")])
    lostx_single, lostx_sequence, thumb_single, thumb_sequence = styles
    assert lostx_single.colour != thumb_single.colour
    assert [s.dashes for s in styles] == ["-", "--", "-", "--"]
    # The sequence line is the method's hue, lighter, narrower and drawn on top, so a line lying on it shows.
    assert all(b >= a for a, b in zip(lostx_single.colour, lostx_sequence.colour))
    assert np.argmax(lostx_single.colour) == np.argmax(lostx_sequence.colour)
    assert lostx_sequence.width < lostx_single.width and lostx_sequence.layer > lostx_single.layer
    # Earlier methods are wider: two perfect methods on the same line both stay visible.
    assert lostx_single.width > thumb_single.width and lostx_sequence.width >= thumb_sequence.width


def test_pr_lines_leave_out_the_points_at_recall_zero():
    (gt,) = index_aligned(4, 4, [0])
    # The most confident answer is wrong: the curve's first point is (recall 0, precision 0).
    curve = evaluate(np.array([3, 1, 2, 0]), np.array([0.1, 0.2, 0.3, 0.4]), gt).curve
    assert curve.recall[0] == 0 and curve.precision[0] == 0
    recall, precision = report.pr_line(curve)
    np.testing.assert_allclose(recall, [25, 50, 50])
    np.testing.assert_allclose(precision, [50, 200 / 3, 50])


def test_report_md_records_the_settings_and_shows_the_figures(tmp_path):
    evals = sample_evaluations()
    path = report.write_markdown(
        tmp_path / "report.md", [report.report_entry("thumbnail", "single", e) for e in evals], "day vs night",
        settings={"sequence window": "3 frames", "backbone": "mosaic-ade20k"},
        figures=[("precision-recall at a tolerance of 0 frames", "pr_0frames.png"),
                 ("max F1", tmp_path / "max_f1_vs_tolerance.png")])
    text = path.read_text()
    assert text.startswith("# day vs night\n\n## Settings\n")
    assert "| sequence window | 3 frames |\n| backbone | mosaic-ade20k |" in text
    assert text.index("## Settings") < text.index("## Results") < text.index("## Figures")
    assert "![precision-recall at a tolerance of 0 frames](pr_0frames.png)" in text
    assert "![max F1](max_f1_vs_tolerance.png)" in text  # linked relative to the report


def test_table_gives_recall_at_1_as_a_count_with_its_interval():
    evals = sample_evaluations()
    lines = report.markdown_table([report.report_entry("thumbnail", "single", e) for e in evals]).strip().splitlines()
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    row = [cell.strip() for cell in lines[2].strip("|").split("|")]
    # At 0 frames queries 0, 2 and 4 of 6 are right: 3/6, Wilson's interval 19-81 %.
    assert row[header.index("R@1 right")] == "3/6"
    assert row[header.index("R@1 95 % interval")] == "19-81"


def test_report_md_compares_answers_query_by_query(tmp_path):
    from lostx.evaluation.significance import paired_comparison
    better = np.array([True] * 9 + [False])
    worse = np.array([True] + [False] * 9)
    table = report.paired_table([("lostx, sequence", "lostx, single", "7.5 m", paired_comparison(better, worse),
                                  paired_comparison(better, worse, stretches=True))])
    # 8 queries one way (2 / 2^8), all in one stretch (2 / 2).
    assert "| lostx, sequence | lostx, single | 7.5 m | 8 | 0 | 0.0078 | 1, 0, 1 |" in table
    path = report.write_markdown(tmp_path / "report.md", [report.report_entry("thumbnail", "single", e)
                                                          for e in sample_evaluations()], "t", settings={"backbone": "mosaic"},
                                 comparisons=table)
    text = path.read_text()
    assert text.index("## Results") < text.index("## Differences, query by query") and table in text
    assert "## Differences" not in report.write_markdown(tmp_path / "plain.md", [], "t", {"backbone": "mosaic"}).read_text()

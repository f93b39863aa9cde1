"""The positions CSV of a folder traverse: good files and every kind of bad row."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.replay.folder import folder_traverse
from lostx.replay.positions import read_positions


@pytest.fixture
def frames(tmp_path, robotcar):
    """Three real RobotCar day frames in a folder of their own."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for src in sorted((robotcar / "day").iterdir())[:3]:
        (folder / src.name).write_bytes(src.read_bytes())
    return folder


def write(path, text):
    path.write_text(text)
    return path


def test_positions_by_file_name_in_any_row_order(frames, tmp_path):
    names = sorted(p.name for p in frames.iterdir())
    csv = write(tmp_path / "pos.csv", "file,x,y,timestamp\n"
                f"{names[2]},20,1,3.5\n\n{names[0]},0,0,1.5\n{names[1]},10,0.5,2.5\n")
    traverse = folder_traverse(frames, csv)
    np.testing.assert_allclose(traverse.positions, [[0, 0], [10, 0.5], [20, 1]])
    np.testing.assert_allclose(traverse.timestamps, [1.5, 2.5, 3.5])
    frame = traverse.frame(1)
    assert frame.position == (10.0, 0.5) and frame.timestamp == 2.5 and frame.image.shape == (640, 1024, 3)


def test_latitude_longitude_become_local_metres(frames, tmp_path):
    # 0.001 degree of latitude is 111.2 m north; of longitude at 51.75 N, 68.8 m east.
    csv = write(tmp_path / "pos.csv", "\ufefflat,lon\n51.75,-1.25\n51.751,-1.25\n51.751,-1.249\n")
    traverse = folder_traverse(frames, csv)
    np.testing.assert_allclose(traverse.positions[1], [0.0, 111.19], atol=0.01)
    np.testing.assert_allclose(traverse.positions[2], [68.83, 111.19], atol=0.05)
    np.testing.assert_allclose(traverse.geo[2], [51.751, -1.249])


def test_malformed_number_names_file_and_line(tmp_path):
    csv = write(tmp_path / "pos.csv", "x,y\n0,0\n1,zero\n")
    with pytest.raises(InputError, match=r"pos\.csv:3: not a number"):
        read_positions(csv)


def test_missing_value_names_file_and_line(tmp_path):
    csv = write(tmp_path / "pos.csv", "file,x,y\na.png,0,0\nb.png,1\n")
    with pytest.raises(InputError, match=r"pos\.csv:3: expected 3 columns, got 2"):
        read_positions(csv)
    empty = write(tmp_path / "empty_cell.csv", "file,x,y\na.png,0,0\nb.png,,1\n")
    with pytest.raises(InputError, match=r"empty_cell\.csv:3: not a number"):
        read_positions(empty)


def test_missing_rows_are_an_error(frames, tmp_path):
    names = sorted(p.name for p in frames.iterdir())
    short = write(tmp_path / "short.csv", "x,y\n0,0\n1,0\n")
    with pytest.raises(InputError, match=r"short\.csv: 2 position rows for 3 images"):
        folder_traverse(frames, short)
    named = write(tmp_path / "named.csv", f"file,x,y\n{names[0]},0,0\n{names[2]},2,0\n")
    with pytest.raises(InputError, match=rf"named\.csv: no position for 1 image\(s\), e\.g\. {names[1]}"):
        folder_traverse(frames, named)


def test_duplicate_and_nameless_rows_name_their_lines(frames, tmp_path):
    names = sorted(p.name for p in frames.iterdir())
    dup = write(tmp_path / "dup.csv", f"file,x,y\n\n{names[0]},0,0\n{names[1]},1,1\n{names[0]},2,2\n")
    with pytest.raises(InputError, match=r"dup\.csv:5: file .* is listed twice \(first on line 3\)"):
        folder_traverse(frames, dup)
    nameless = write(tmp_path / "nameless.csv", "file,x,y\n,0,0\n")
    with pytest.raises(InputError, match=r"nameless\.csv:2: empty file name"):
        read_positions(nameless)


def test_header_without_positions_and_out_of_range_latitude(tmp_path):
    with pytest.raises(InputError, match=r"nohead\.csv:1: header .* has no position columns"):
        read_positions(write(tmp_path / "nohead.csv", "file,a,b\nx.png,1,2\n"))
    with pytest.raises(InputError, match=r"lat\.csv:2: latitude/longitude out of range"):
        read_positions(write(tmp_path / "lat.csv", "lat,lon\n95,0\n"))
    with pytest.raises(InputError, match=r"inf\.csv:2: non-finite"):
        read_positions(write(tmp_path / "inf.csv", "x,y\ninf,0\n"))
    with pytest.raises(InputError, match="positions file not found"):
        read_positions(tmp_path / "absent.csv")

"""The result journal on its own: order, durability across reopening, rotation, its bound, damage, one writer."""

from __future__ import annotations

import os

import pytest

from lostx.stream.journal import HEADER, Journal, JournalError


def payload(seq: int) -> bytes:
    return f"answer {seq} ".encode() * (1 + seq % 7)


def fill(journal: Journal, first: int, last: int) -> None:
    for seq in range(first, last + 1):
        journal.append(seq, payload(seq))
    journal.commit()


def test_answers_read_back_in_order_from_any_point_after_reopening(tmp_path):
    with Journal(tmp_path / "j") as journal:
        assert (journal.first, journal.last) == (0, 0) and journal.read(0, 10, 1 << 20) == []
        fill(journal, 1, 50)
        journal_id = journal.id
    with Journal(tmp_path / "j") as journal:
        assert journal.id == journal_id and (journal.first, journal.last) == (1, 50)
        assert journal.read(0, 1000, 1 << 20) == [payload(s) for s in range(1, 51)]
        assert journal.read(47, 1000, 1 << 20) == [payload(48), payload(49), payload(50)]
        assert journal.read(10, 3, 1 << 20) == [payload(11), payload(12), payload(13)]
        assert journal.read(50, 10, 1 << 20) == []
        # A byte budget stops early, but never returns nothing while there is something.
        assert journal.read(0, 1000, len(payload(1)) + len(payload(2))) == [payload(1), payload(2)]
        assert journal.read(0, 1000, 1) == [payload(1)]
        assert journal.tail(2) == [payload(49), payload(50)]
        fill(journal, 51, 52)  # numbers go on after a reopening
        with pytest.raises(JournalError, match="answer 54 does not follow answer 52"):
            journal.append(54, b"x")
    with Journal(tmp_path / "j") as journal:
        assert journal.last == 52 and journal.read(50, 10, 1 << 20) == [payload(51), payload(52)]


def test_readers_see_only_committed_answers(tmp_path):
    with Journal(tmp_path / "j") as journal:
        fill(journal, 1, 3)
        journal.append(4, payload(4))
        assert (journal.last, journal.committed) == (4, 3)
        assert journal.read(0, 10, 1 << 20) == [payload(1), payload(2), payload(3)]
        journal.commit()
        assert journal.read(2, 10, 1 << 20) == [payload(3), payload(4)]


def test_segments_rotate_and_the_oldest_go_to_keep_the_bound(tmp_path):
    record = HEADER.size + len(payload(6))  # the longest payload
    with Journal(tmp_path / "j", segment_bytes=20 * record, max_bytes=70 * record) as journal:
        fill(journal, 1, 400)
        files = sorted(p.name for p in (tmp_path / "j").glob("*.journal"))
        assert len(files) == journal.segments >= 3
        assert journal.nbytes <= 70 * record
        assert sum(p.stat().st_size for p in (tmp_path / "j").glob("*.journal")) == journal.nbytes
        first = journal.first
        assert files[0] == f"{first:020d}.journal" and 1 < first < 400 and journal.last == 400
        # Asking for what was deleted gives what is left, from the oldest held.
        got = journal.read(0, 1000, 1 << 30)
        assert got == [payload(s) for s in range(first, 401)]
    with Journal(tmp_path / "j", segment_bytes=20 * record, max_bytes=70 * record) as journal:
        assert (journal.first, journal.last) == (first, 400)


def test_a_torn_record_at_the_end_is_cut_off_and_writing_goes_on(tmp_path):
    with Journal(tmp_path / "j") as journal:
        fill(journal, 1, 10)
    segment = next((tmp_path / "j").glob("*.journal"))
    whole = segment.stat().st_size
    with open(segment, "ab") as handle:  # a crash of the machine in the middle of a write
        handle.write(HEADER.pack(100, 0, 11) + b"only part of the")
    with Journal(tmp_path / "j") as journal:
        assert journal.last == 10 and segment.stat().st_size == whole
        fill(journal, 11, 12)
        assert journal.read(9, 10, 1 << 20) == [payload(10), payload(11), payload(12)]


def test_damage_before_the_end_is_reported_not_skipped(tmp_path):
    record = HEADER.size + len(payload(6))
    with Journal(tmp_path / "j", segment_bytes=5 * record, max_bytes=100 * record) as journal:
        fill(journal, 1, 30)
    oldest = sorted((tmp_path / "j").glob("*.journal"))[0]
    data = bytearray(oldest.read_bytes())
    data[HEADER.size + 2] ^= 0xFF  # inside the first answer
    oldest.write_bytes(bytes(data))
    with pytest.raises(JournalError, match=rf"{oldest.name} is damaged at byte 0 \(answer 1\)"):
        Journal(tmp_path / "j", segment_bytes=5 * record, max_bytes=100 * record)


def test_one_service_writes_a_journal_at_a_time(tmp_path):
    with Journal(tmp_path / "j"):
        with pytest.raises(JournalError, match=rf"is in use by another service \(pid {os.getpid()}\)"):
            Journal(tmp_path / "j")
    with Journal(tmp_path / "j") as journal:  # the lock goes with the writer
        assert journal.last == 0


def test_a_folder_that_is_not_a_journal_is_refused(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.png").write_bytes(b"x")
    with pytest.raises(JournalError, match="is not a lostx journal"):
        Journal(tmp_path / "photos")
    (tmp_path / "j").mkdir()
    (tmp_path / "j" / "journal.json").write_text('{"format": "something-else"}')
    with pytest.raises(JournalError, match="not a lostx journal"):
        Journal(tmp_path / "j")
    with pytest.raises(JournalError, match="need max_bytes"):
        Journal(tmp_path / "k", segment_bytes=1000, max_bytes=10)

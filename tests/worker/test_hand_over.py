"""Hand-overs between a job's tasks (`worker.handover.array_records`): in a file, or kept in the process that wrote
it (a merge's own later chunk), read back record by record, the same either way."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.core.settings import Settings
from worker.context import JobContext
from worker.handover import array_records, has_hand_over, read_array_records


def _context(tmp_path, *, hold: bool) -> JobContext:
    settings = Settings(_env_file=None, data_dir=tmp_path)  # type: ignore[call-arg]
    return JobContext(job_id="job-1", spec={}, settings=settings, sessions=None, hold=hold)  # type: ignore[arg-type]


@pytest.mark.parametrize("hold", [False, True], ids=["file", "kept in the process"])
def test_records_come_back_as_written_and_a_kept_one_leaves_no_file(tmp_path, hold: bool) -> None:
    writer, reader = _context(tmp_path, hold=hold), _context(tmp_path, hold=False)
    rng = np.random.default_rng(3)
    written = [{"k": rng.integers(0, 100, 50).astype(np.int32), "z_mm": rng.normal(size=50)} for _ in range(3)]
    with array_records(writer, "chunks/frames-0000000.arrays") as write:
        for record in written:
            write(**record)
    assert has_hand_over(reader, "chunks/frames-0000000.arrays")
    assert (writer.directory / "chunks/frames-0000000.arrays").is_file() != hold
    back = list(read_array_records(reader, "chunks/frames-0000000.arrays"))
    assert len(back) == len(written)
    for got, want in zip(back, written, strict=True):
        assert got.keys() == want.keys()
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])
            assert got[name].dtype == want[name].dtype
    if hold:  # read once, then gone: what a merge keeps does not outlive its turn
        assert not has_hand_over(reader, "chunks/frames-0000000.arrays")


def test_a_hand_over_whose_writing_failed_is_not_kept(tmp_path) -> None:
    context = _context(tmp_path, hold=True)
    with pytest.raises(RuntimeError, match="measuring failed"), array_records(context, "chunks/x.arrays") as write:
        write(a=np.zeros(3))
        raise RuntimeError("measuring failed")
    assert not has_hand_over(context, "chunks/x.arrays")


def test_a_kept_hand_over_beyond_its_memory_budget_goes_on_in_a_temporary_file(tmp_path, monkeypatch) -> None:
    import worker.handover as runner

    monkeypatch.setattr(runner, "HELD_HAND_OVER_BYTES", 2 * 8 * 100)  # two records of 100 float64 in memory
    context = _context(tmp_path, hold=True)
    written = [{"z_mm": np.full(100, float(i)), "frame": np.int64(i)} for i in range(5)]
    with array_records(context, "chunks/frames-0000000.arrays") as write:
        for record in written:
            write(**record)
    kept = runner._held[(context.job_id, "chunks/frames-0000000.arrays")]
    assert len(kept.records) == 1 and kept.spill is not None  # the second did not fit beside the first's 8 bytes
    back = list(read_array_records(context, "chunks/frames-0000000.arrays"))
    assert [int(record["frame"]) for record in back] == [0, 1, 2, 3, 4]
    for got, want in zip(back, written, strict=True):
        np.testing.assert_array_equal(got["z_mm"], want["z_mm"])
    assert kept.spill.closed and not list(tmp_path.rglob("*.arrays"))

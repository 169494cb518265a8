"""How a job's frames are split into chunks: a job's own chunk size as given, else guided self-scheduling."""

from __future__ import annotations

import pytest

from fringelab.core.settings import Settings
from worker.chunks import GUIDED_PARTS, MIN_CHUNK_FRAMES, guided_frame_ranges, planned_frame_ranges


@pytest.mark.parametrize("count", [1, 4, 5, 7, 40, 160, 799, 2000])
@pytest.mark.parametrize("most", [1, 5, 20, 100])
def test_guided_chunks_cover_every_frame_once_and_shrink_towards_the_end(count: int, most: int) -> None:
    ranges = guided_frame_ranges(count, most=most)
    assert ranges[0][0] == 0 and ranges[-1][1] == count
    assert all(stop == next_first for (_, stop), (next_first, _) in zip(ranges, ranges[1:], strict=False))
    sizes = [stop - first for first, stop in ranges]
    assert max(sizes) <= most
    assert sizes == sorted(sizes, reverse=True), "a chunk is larger than one before it"
    # every chunk but the last takes 1/GUIDED_PARTS of what is left, clipped to [MIN_CHUNK_FRAMES, most]
    left = count
    for size in sizes[:-1]:
        assert size == min(most, max(MIN_CHUNK_FRAMES, -(-left // GUIDED_PARTS)))
        left -= size


def test_a_long_job_ends_in_small_chunks() -> None:
    sizes = [stop - first for first, stop in guided_frame_ranges(2000, most=100)]
    assert sizes[:13] == [100] * 13  # 1/8 of what is left is more than the most until 800 frames are left
    assert sizes[-8:-1] == [MIN_CHUNK_FRAMES] * 7 and sizes[-1] <= MIN_CHUNK_FRAMES


def test_a_jobs_own_chunk_size_is_kept() -> None:
    settings = Settings(_env_file=None, chunk_frames=100)  # type: ignore[call-arg]
    assert planned_frame_ranges(45, 20, settings) == [(0, 20), (20, 40), (40, 45)]
    assert planned_frame_ranges(45, None, settings) == guided_frame_ranges(45, most=100)


def test_an_empty_job_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one frame"):
        guided_frame_ranges(0, most=10)

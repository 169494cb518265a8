"""Workers keep the disk's reserve while they write (issue 26: a topography wrote until 45 MiB were free)."""

from __future__ import annotations

import pytest

from fringelab.core.storage import free_disk_bytes
from worker.reserve import BelowReserve, require_reserve


def test_a_job_stops_in_words_below_the_reserve(settings):
    settings.data_path.mkdir(parents=True, exist_ok=True)
    require_reserve(settings, what="writing frames 0 to 9")  # the tests' disk is above the default reserve
    full = settings.model_copy(update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40})
    with pytest.raises(BelowReserve, match="stopped before writing frames 0 to 9: not enough free space") as error:
        require_reserve(full, what="writing frames 0 to 9")
    assert "FRINGELAB_MIN_FREE_DISK_BYTES" in str(error.value) and isinstance(error.value, ValueError)

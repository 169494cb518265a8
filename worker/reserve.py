"""Workers keep the disk's reserve (FRINGELAB_MIN_FREE_DISK_BYTES) before and while they write a job's files.

A topography on a fine grid wrote until 45 MiB were free, then failed with an error naming the server's path
(issue 26). Checked before each chunk is written and as each one is merged, a job stops with a sentence a person
can act on; its result, written to a temporary file that only a finished job renames, is never left half-written.
"""

from __future__ import annotations

from fringelab.core.settings import Settings
from fringelab.core.storage import InsufficientStorage, check_room


class BelowReserve(ValueError):
    """The data volume has fallen below its reserve: the job stops (its error says so), nothing is kept."""


def require_reserve(settings: Settings, *, what: str) -> None:
    """Raise BelowReserve when the data volume has less than FRINGELAB_MIN_FREE_DISK_BYTES free."""
    try:
        check_room(settings.data_path, 0, reserve_bytes=settings.min_free_disk_bytes)
    except InsufficientStorage as error:
        raise BelowReserve(f"stopped before {what}: {error}; free some space and retry the job") from None

"""The cap on event streams per user and process (issue 26: one member held 965 streams, 40 % of a core)."""

from __future__ import annotations

import pytest

from backend.streams import StreamSlots
from fringelab.core.errors import RateLimited


def test_a_user_beyond_the_cap_is_refused_and_a_closed_stream_frees_its_slot():
    slots = StreamSlots(per_user=2)
    first = slots.take("ada", name="ada")
    with slots.held("ada", first):
        second = slots.take("ada", name="ada")
        with pytest.raises(RateLimited, match="FRINGELAB_EVENT_STREAMS_PER_USER"):
            slots.take("ada", name="ada")
        slots.give_back("bob", slots.take("bob", name="bob"))  # another user is not held back
        slots.give_back("ada", second)
    slots.take("ada", name="ada")
    slots.take("ada", name="ada")  # the first stream ended: two again

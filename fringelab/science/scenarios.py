"""The names of the virtual tests (`virtual_test.scenario` makes them), with no imports: the API offers
them for its demo without loading the renderer. Not here: the scenes and timelines themselves (`virtual_test.py`)."""

from __future__ import annotations

SCENARIOS = ("quasi-static", "fast", "petals", "highlight", "shadow", "hard", "dim")


def min_test_frames(scenario_name: str) -> int:
    """Fewest test frames a scenario's timeline can be made of: 4 for the quasi-static ones (`punch_timeline`:
    quasi-static, highlight, dim), 6 for those built on the fast test (`fast_timeline`: a ramp, then three
    perforated frames).

    >>> min_test_frames("fast")
    6
    """
    if scenario_name not in SCENARIOS:
        raise ValueError(f"scenario: expected one of {SCENARIOS}, got {scenario_name!r}")
    return 4 if scenario_name in ("quasi-static", "highlight", "dim") else 6

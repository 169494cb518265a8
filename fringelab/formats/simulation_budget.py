"""How much memory a simulation may take: the one rule every simulation reader applies to what a file declares (its
node, element and state counts, from its header, or its row count estimated from its size), before it allocates
an array.

A 16 KB Exodus file declaring 60 M nodes took a process to 2176 MiB before it was refused (issue 26): a reader
allocates what a header says. Here a reader first says what it will hold, in the units it knows, and
`check_declared` refuses the file, naming it, its counts and the budget, when that is more than `max_bytes`
(FRINGELAB_SIMULATION_MAX_BYTES). What a reader holds: node coordinates and ids (4 values a node), element corners
(one value each), the displacements of the states it keeps in memory at once (3 values a node per state: one for the
readers that read a state when it is asked for, all for those that read everything), the state times, and for the
text formats the table it parses (`n_values`) and the file's text where a library holds it whole (`file_bytes`).
Every value counts 8 bytes (float64, int64). Not here: reading any file (the `simulation_*` modules).
"""

from __future__ import annotations

from pathlib import Path

DEFAULT_MAX_BYTES = 2**30
VALUE_BYTES = 8
MIB = 2**20
SAMPLE_BYTES = 1 << 16  # what a text file's rows are measured on


def declared_bytes(
    *, n_nodes: int, n_corners: int = 0, n_states_held: int = 1, n_states: int = 0, n_values: int = 0,
    file_bytes: int = 0,
) -> int:  # fmt: skip
    """The bytes a reader holds for a model of these counts (see the module's docstring)."""
    values = 4 * n_nodes + n_corners + 3 * n_nodes * n_states_held + n_states + n_values
    return VALUE_BYTES * values + file_bytes


def check_declared(
    where: str, *, max_bytes: int, n_nodes: int, n_elements: int = 0, n_corners: int = 0, n_states_held: int = 1,
    n_states: int = 0, n_values: int = 0, file_bytes: int = 0, what: str = "",
) -> None:  # fmt: skip
    """ValueError naming the file (`where`), what it declares and the budget when a reader of it would hold more
    than `max_bytes`; `what` says where the counts came from (e.g. "its header")."""
    needed = declared_bytes(n_nodes=n_nodes, n_corners=n_corners, n_states_held=n_states_held, n_states=n_states,
                            n_values=n_values, file_bytes=file_bytes)  # fmt: skip
    if needed <= max_bytes:
        return
    counts = [f"{n} {name}{'s' if n != 1 else ''}" for n, name in ((n_nodes, "node"), (n_elements, "element"),
                                                                   (n_states, "state")) if n]  # fmt: skip
    declared = f"declares {', '.join(counts)}" + (f" ({what})" if what else "") if counts else f"holds {what}"
    raise ValueError(
        f"{where}: {declared}: reading it would take about {_size(needed)}, more than the {_size(max_bytes)} a "
        "simulation may take (FRINGELAB_SIMULATION_MAX_BYTES); refused before reading it"
    )


def _size(n_bytes: int) -> str:
    return f"{n_bytes / MIB:.0f} MiB" if n_bytes >= MIB else f"{n_bytes / 1024:.0f} KiB"


def estimated_rows(path: Path) -> int:
    """The lines of a text file, estimated from its size and the mean length of the lines in its first 64 KiB
    (at least 1)."""
    size = path.stat().st_size
    with open(path, "rb") as handle:
        sample = handle.read(SAMPLE_BYTES)
    lines = sample.count(b"\n") or 1
    return max(1, round(size * lines / max(len(sample), 1)))

"""LS-DYNA ASCII time histories: `nodout` (nodal displacements) and `rcforc` (contact resultant forces).

They give a simulation its punch: the travel of a punch node (nodout) and the punch force (rcforc), on their own
time bases. Each file is read once, in memory (they hold a few nodes and interfaces). The writers produce the
same layout, for tests and examples.

LS-DYNA writes these files with Fortran formats, so the columns, not the spaces, decide where a number ends:
numbers can touch, and a number whose exponent needs three digits loses its "E" (`-1.5000-345` is
−1.5 × 10⁻³⁴⁵; `1.2345+100` is 1.2345 × 10¹⁰⁰). A field too narrow for its value is printed as asterisks
(`************`): it is read as missing (NaN), never as a number, and its line is listed in `missing_lines`.
A value beyond the range of float64 is missing too.

nodout: blocks headed ` n o d a l   p r i n t   o u t   f o r   t i m e  s t e p  N  ( at time T )`, a column
line starting `nodal point  x-disp …`, then one line per node: the id in columns 1–10, then x/y/z-disp, -vel,
-accl, -coor in fields of 12 columns (Fortran `i10,12e12.4`; LS-DYNA's l2a writes `%9d%13.4E%12.4E…`, the same
columns). Rotation blocks (`x-rot …`) are skipped. Every block lists the same nodes in the same order; a block
that does not is refused naming its line.
rcforc: lines `  master|slave  ID time T  x FX  y FY  z FZ  mass M`; each number is the text between its label
and the next one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fringelab.formats.atomic import atomic_write
from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES, check_declared, estimated_rows

NODOUT_ID_COLUMNS = 10  # the node id ends at column 10
NODOUT_FIELD_COLUMNS = 12  # each value after it is 12 columns wide
_RCFORC_LABELS = ("time", "x", "y", "z")
# A parsed line is held as Python objects (an id, a tuple or list of floats, the list's slot) until the arrays are
# made: about 190 bytes, counted as this many 8-byte values against the budget (`simulation_budget`).
VALUES_PER_LINE = 24


def _check_lines(path: Path, max_bytes: int) -> None:
    """The lines of a file, estimated from its size, held as parsed against the budget, before it is parsed."""
    lines = estimated_rows(path)
    check_declared(path.name, max_bytes=max_bytes, n_nodes=0, n_values=VALUES_PER_LINE * lines,
                   what=f"about {lines} lines, from its size")  # fmt: skip


class FieldError(ValueError):
    """A fixed-width field that holds no number (the caller names the file and line)."""


def fortran_float(field: str) -> float:
    """The value of one Fortran E-format field: `1.2345E-01`, `1.2345D-01`, `-1.5000-345` (no "E": a
    three-digit exponent), `  0.0`; NaN for an overflow field of asterisks or a value beyond float64.

    >>> fortran_float(" -1.5000-345"), fortran_float("1.2345+100"), fortran_float("2.5000E-03")
    (-0.0, 1.2345e+100, 0.0025)
    >>> import math; math.isnan(fortran_float("************"))
    True
    """
    text = field.strip()
    if not text:
        raise FieldError("an empty field")
    if set(text) == {"*"}:
        return math.nan
    text = text.replace("D", "E").replace("d", "e")
    if "E" not in text and "e" not in text:
        # a sign after the first character (and not after an "E") starts an exponent that lost its "E"
        cut = max(text.rfind("+", 1), text.rfind("-", 1))
        if cut > 0:
            text = text[:cut] + "E" + text[cut:]
    try:
        value = float(text)
    except ValueError:
        raise FieldError(f"{field.strip()!r} is not a number") from None
    return value if math.isfinite(value) else math.nan


@dataclass(frozen=True, eq=False)
class NodeHistories:
    """nodout: time (T,), node ids (M,), displacement (T, M, 3) in the model's units; NaN where the file printed
    asterisks (its lines in missing_lines)."""

    time: np.ndarray
    node_ids: np.ndarray
    displacement: np.ndarray
    missing_lines: tuple[int, ...] = ()

    def punch_travel(self, node_id: int | None, *, where: str = "nodout") -> np.ndarray:
        """|u| (T,) of the punch node (the only node when node_id is None); NaN where a component is missing."""
        if node_id is None:
            if len(self.node_ids) != 1:
                raise ValueError(
                    f"{where}: {len(self.node_ids)} nodes ({', '.join(map(str, self.node_ids[:8]))}…); "
                    "set the punch node (--punch-node ID)"
                )
            column = 0
        else:
            hits = np.flatnonzero(self.node_ids == node_id)
            if len(hits) == 0:
                raise ValueError(f"{where}: no node {node_id}; it has {', '.join(map(str, self.node_ids[:8]))}")
            column = int(hits[0])
        return np.linalg.norm(self.displacement[:, column], axis=1)


def _time_of_header(line: str, where: str) -> float:
    start = line.find("at time")
    end = line.find(")", start)
    if start < 0 or end < 0:
        raise ValueError(f"{where}: a block header without '( at time … )'")
    try:
        value = fortran_float(line[start + len("at time") : end])
    except FieldError as error:
        raise ValueError(f"{where}: the block's time: {error}") from None
    if math.isnan(value):
        raise ValueError(f"{where}: the block's time is printed as asterisks; write nodout with more digits")
    return value


def _check_block_came(header_line: int, name: str) -> None:
    """A time step's header (line header_line; 0: none pending) must be followed by its column line and nodes; a
    header whose nodes never come is a file cut short."""
    if header_line:
        raise ValueError(
            f"{name}: line {header_line}: a time step's header without its nodes: the file is cut short; copy it "
            "again from the solver's folder"
        )


def read_nodout(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> NodeHistories:
    """Parse an ASCII nodout file (ValueError naming the file and line of anything not understood, or, before it
    is parsed, its size when its lines would take more than `max_bytes`)."""
    path = Path(path)
    _check_lines(path, max_bytes)
    times: list[float] = []
    blocks: list[tuple[int, list[int], list[tuple[float, float, float]]]] = []  # (header line, ids, disp)
    missing: list[int] = []
    in_block = False
    pending_time, pending_line = math.nan, 0
    width = NODOUT_FIELD_COLUMNS
    with open(path, encoding="latin-1") as handle:
        for number, line in enumerate(handle, start=1):
            line = line.rstrip("\r\n")
            where = f"{path.name}: line {number}"
            if "n o d a l   p r i n t   o u t" in line:
                _check_block_came(pending_line, path.name)
                in_block = False
                pending_time, pending_line = _time_of_header(line, where), number
                continue
            stripped = line.strip()
            if stripped.startswith("nodal point"):
                if not pending_line:
                    raise ValueError(
                        f"{where}: a column line without its time step's header ('n o d a l   p r i n t   o u t … "
                        "( at time … )') before it: the file is damaged; copy it again from the solver's folder"
                    )
                if "x-disp" not in stripped and "x-rot" not in stripped:
                    raise ValueError(
                        f"{where}: a column line neither 'nodal point  x-disp …' nor 'nodal point  x-rot …': "
                        f"{stripped[:40]!r}; is it an ASCII nodout as LS-DYNA writes it?"
                    )
                in_block = "x-disp" in stripped
                if in_block:
                    times.append(pending_time)
                    blocks.append((pending_line, [], []))
                pending_line = 0  # its nodes follow (displacements, or rotations: skipped)
                continue
            if not in_block or not stripped:
                continue
            head = line[:NODOUT_ID_COLUMNS].strip()
            if not head.isdigit():
                in_block = False
                continue
            if len(line.rstrip()) <= NODOUT_ID_COLUMNS + 2 * width:
                raise ValueError(
                    f"{where}: node {head}: the line ends before x-, y- and z-disp (columns 11–46); "
                    "is it an ASCII nodout as LS-DYNA writes it?"
                )
            values = []
            for k in range(3):
                field = line[NODOUT_ID_COLUMNS + k * width : NODOUT_ID_COLUMNS + (k + 1) * width]
                try:
                    values.append(fortran_float(field))
                except FieldError as error:
                    first = NODOUT_ID_COLUMNS + k * width + 1
                    raise ValueError(
                        f"{where}: node {head}, {'xyz'[k]}-disp (columns {first}–{first + width - 1}): {error}"
                    ) from None
            if any(math.isnan(v) for v in values):
                missing.append(number)
            blocks[-1][1].append(int(head))
            blocks[-1][2].append((values[0], values[1], values[2]))
    if not times:
        raise ValueError(f"{path.name}: no 'nodal print out' block with displacements; is it an ASCII nodout?")
    _check_block_came(pending_line, path.name)
    first_line, ids, _ = blocks[0]
    for header_line, block_ids, _ in blocks:
        if block_ids != ids:
            raise ValueError(
                f"{path.name}: line {header_line}: this time step lists {len(block_ids)} nodes "
                f"({', '.join(map(str, block_ids[:6]))}…), the first (line {first_line}) {len(ids)} "
                f"({', '.join(map(str, ids[:6]))}…); every block must list the same nodes: was the file cut or "
                "two runs written into one?"
            )
    displacement = np.array([block[2] for block in blocks], np.float64).reshape(len(times), len(ids), 3)
    return NodeHistories(
        time=np.array(times), node_ids=np.array(ids, np.int64), displacement=displacement,
        missing_lines=tuple(missing),
    )  # fmt: skip


def write_nodout(path: str | Path, *, time: np.ndarray, node_ids: np.ndarray, displacement: np.ndarray,
                 coordinates: np.ndarray) -> Path:  # fmt: skip
    """Write an ASCII nodout in LS-DYNA's layout (velocities and accelerations written as 0); displacement
    (T, M, 3), coordinates (M, 3) of the reference."""
    lines = [" ls-dyna  (written by fringelab)", ""]
    header = (" nodal point  x-disp     y-disp      z-disp      x-vel       y-vel       z-vel      x-accl"
              "      y-accl      z-accl      x-coor      y-coor      z-coor")  # fmt: skip
    for t, time_value in enumerate(time):
        lines.append(f" n o d a l   p r i n t   o u t   f o r   t i m e  s t e p{t + 1:8d}"
                     f"                              ( at time {time_value:.7E} )")  # fmt: skip
        lines += ["", header]
        for j, node in enumerate(node_ids):
            values = [*displacement[t, j], 0, 0, 0, 0, 0, 0, *(coordinates[j] + displacement[t, j])]
            lines.append(f"{int(node):9d}{values[0]:13.4E}" + "".join(f"{v:12.4E}" for v in values[1:]))
        lines.append("")
    return atomic_write(path, "\n".join(lines) + "\n")


@dataclass(frozen=True, eq=False)
class ContactForces:
    """rcforc: per interface id and side, time (T,) and force (T, 3) in the model's units; NaN where the file
    printed asterisks (its lines in missing_lines)."""

    series: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]]
    missing_lines: tuple[int, ...] = ()

    def punch_force(self, interface: int | None, *, where: str = "rcforc") -> tuple[np.ndarray, np.ndarray, int]:
        """time (T,), |F| (T,) of the master side of one interface (the largest-force one when None), and its id."""
        masters = {key[0]: value for key, value in self.series.items() if key[1] == "master"}
        if not masters:
            masters = {key[0]: value for key, value in self.series.items()}
        if interface is None:
            interface = max(masters, key=lambda i: float(np.nanmax(np.linalg.norm(masters[i][1], axis=1), initial=0)))
        if interface not in masters:
            raise ValueError(f"{where}: no interface {interface}; it has {sorted(masters)}")
        time, force = masters[interface]
        return time, np.linalg.norm(force, axis=1), interface


def _rcforc_fields(line: str, where: str) -> tuple[int, list[float]]:
    """The interface id and (time, fx, fy, fz) of one rcforc line: each number is the text between its label
    and the next label."""
    body = line.strip()
    side_end = body.find(" ")
    rest = body[side_end:]
    starts = []
    position = 0
    for label in _RCFORC_LABELS:
        found = rest.find(f" {label}", position)
        if found < 0:
            raise ValueError(f"{where}: no '{label}' field; expected 'master|slave ID time T x FX y FY z FZ'")
        starts.append((found, found + len(label) + 1))
        position = found + len(label) + 1
    end_of_z = rest.find(" mass", position)
    if end_of_z < 0:
        raise ValueError(f"{where}: no 'mass' field after z: the line is cut short; copy the file again")
    ident_text = rest[: starts[0][0]].strip()
    if not ident_text.isdigit():
        raise ValueError(f"{where}: interface id {ident_text!r} is not a number")
    values = []
    for k, label in enumerate(_RCFORC_LABELS):
        stop = starts[k + 1][0] if k + 1 < len(starts) else end_of_z
        try:
            values.append(fortran_float(rest[starts[k][1] : stop]))
        except FieldError as error:
            raise ValueError(f"{where}: '{label}': {error}") from None
    return int(ident_text), values


def read_rcforc(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> ContactForces:
    """Parse an ASCII rcforc file (ValueError naming the file and line of anything not understood, or, before it
    is parsed, its size when its lines would take more than `max_bytes`)."""
    path = Path(path)
    _check_lines(path, max_bytes)
    collected: dict[tuple[int, str], list[list[float]]] = {}
    missing: list[int] = []
    with open(path, encoding="latin-1") as handle:
        for number, line in enumerate(handle, start=1):
            side = line.strip().split(" ", 1)[0].lower()
            if side not in ("master", "slave") or " time" not in line:
                continue
            ident, values = _rcforc_fields(line, f"{path.name}: line {number}")
            if math.isnan(values[0]):
                raise ValueError(f"{path.name}: line {number}: the time is printed as asterisks")
            if any(math.isnan(v) for v in values):
                missing.append(number)
            collected.setdefault((ident, side), []).append(values)
    if not collected:
        raise ValueError(f"{path.name}: no 'master|slave ID time T x … y … z …' line; is it an ASCII rcforc?")
    for ident in {key[0] for key in collected}:
        sides = [len(collected.get((ident, side), [])) for side in ("master", "slave")]
        if all(sides) and sides[0] != sides[1]:
            raise ValueError(
                f"{path.name}: interface {ident} has {sides[0]} master and {sides[1]} slave lines: the file is cut "
                "short; copy it again from the solver's folder"
            )
    series = {}
    for key, rows in collected.items():
        array = np.array(rows)
        series[key] = (array[:, 0], array[:, 1:4])
    return ContactForces(series, missing_lines=tuple(missing))


def write_rcforc(path: str | Path, *, time: np.ndarray, force: np.ndarray, interface: int = 1) -> Path:
    """Write an ASCII rcforc for one interface in LS-DYNA's layout; force (T, 3) on the master side (the slave
    side the opposite)."""
    lines = [" r e s u l t a n t   i n t e r f a c e   f o r c e s", "", ""]
    for t, time_value in enumerate(time):
        for side, sign in (("master", 1.0), ("slave ", -1.0)):
            fx, fy, fz = sign * force[t]
            lines.append(f"  {side}{interface:11d} time{time_value:12.5E}  x {fx:12.5E}  y {fy:12.5E}"
                         f"  z {fz:12.5E} mass {0.0:12.5E}")  # fmt: skip
    return atomic_write(path, "\n".join(lines) + "\n")

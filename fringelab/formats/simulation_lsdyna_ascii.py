"""LS-DYNA ASCII time histories: `nodout` (nodal displacements) and `rcforc` (contact resultant forces).

They give a simulation its punch: the travel of a punch node (nodout) and the punch force (rcforc), on their own
time bases. Parsed here line by line (numbers in LS-DYNA's fixed-width E format may touch, so they are found
by pattern, not split on spaces); each file is read once, in memory (they hold a few nodes and interfaces).
The writers produce the same layout, for tests and examples.

nodout: blocks headed ` n o d a l   p r i n t   o u t   f o r   t i m e  s t e p  N  ( at time T )`, a column
line starting `nodal point  x-disp …`, then one line per node: id, x/y/z-disp, -vel, -accl, -coor. Rotation blocks
(`x-rot …`) are skipped.
rcforc: lines `  master|slave  ID time T  x FX  y FY  z FZ  mass …`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fringelab.formats.atomic import atomic_write

_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[EeDd][-+]?\d+)?")
_AT_TIME = re.compile(r"at time\s*([-+0-9.EeDd]+)")
_RCFORC = re.compile(r"^\s*(master|slave)\s+(\d+)\s+time\s*(\S+)\s+x\s*(\S+)\s+y\s*(\S+)\s+z\s*(\S+)", re.IGNORECASE)


def _float(text: str) -> float:
    return float(text.replace("D", "E").replace("d", "e"))


@dataclass(frozen=True, eq=False)
class NodeHistories:
    """nodout: time (T,), node ids (M,), displacement (T, M, 3) in the model's units."""

    time: np.ndarray
    node_ids: np.ndarray
    displacement: np.ndarray

    def punch_travel(self, node_id: int | None, *, where: str = "nodout") -> np.ndarray:
        """|u| (T,) of the punch node (the only node when node_id is None)."""
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


def read_nodout(path: str | Path) -> NodeHistories:
    """Parse an ASCII nodout file."""
    path = Path(path)
    times: list[float] = []
    rows: list[dict[int, tuple[float, float, float]]] = []
    in_block = False
    pending_time = float("nan")
    with open(path, encoding="latin-1") as handle:
        for number, line in enumerate(handle, start=1):
            if "n o d a l   p r i n t   o u t" in line:
                match = _AT_TIME.search(line)
                if match is None:
                    raise ValueError(f"{path.name}: line {number}: a block header without '( at time … )'")
                in_block = False
                pending_time = _float(match.group(1))
                continue
            stripped = line.strip()
            if stripped.startswith("nodal point"):
                in_block = "x-disp" in stripped
                if in_block:
                    times.append(pending_time)
                    rows.append({})
                continue
            if in_block and stripped:
                fields = stripped.split(None, 1)
                if not fields[0].isdigit():
                    in_block = False
                    continue
                numbers = _NUMBER.findall(fields[1]) if len(fields) > 1 else []
                if len(numbers) < 3:
                    raise ValueError(f"{path.name}: line {number}: expected x-, y-, z-disp after node {fields[0]}")
                rows[-1][int(fields[0])] = (_float(numbers[0]), _float(numbers[1]), _float(numbers[2]))
    if not times:
        raise ValueError(f"{path.name}: no 'nodal print out' block with displacements; is it an ASCII nodout?")
    ids = np.array(sorted(rows[0]), np.int64)
    displacement = np.full((len(times), len(ids), 3), np.nan)
    for t, block in enumerate(rows):
        for j, node in enumerate(ids):
            if node in block:
                displacement[t, j] = block[node]
    return NodeHistories(time=np.array(times), node_ids=ids, displacement=displacement)


def write_nodout(path: str | Path, *, time: np.ndarray, node_ids: np.ndarray, displacement: np.ndarray,
                 coordinates: np.ndarray) -> Path:  # fmt: skip
    """Write an ASCII nodout (velocities and accelerations written as 0); displacement (T, M, 3),
    coordinates (M, 3) of the reference."""
    lines = [" ls-dyna  (written by fringelab)", ""]
    header = (" nodal point  x-disp     y-disp      z-disp      x-vel       y-vel       z-vel       x-accl"
              "      y-accl      z-accl      x-coor      y-coor      z-coor")  # fmt: skip
    for t, time_value in enumerate(time):
        lines.append(f" n o d a l   p r i n t   o u t   f o r   t i m e  s t e p{t + 1:8d}"
                     f"                              ( at time {time_value:.7E} )")  # fmt: skip
        lines += ["", header]
        for j, node in enumerate(node_ids):
            values = [*displacement[t, j], 0, 0, 0, 0, 0, 0, *(coordinates[j] + displacement[t, j])]
            lines.append(f"{int(node):9d}" + "".join(f"{v:12.4E}" for v in values))
        lines.append("")
    return atomic_write(path, "\n".join(lines) + "\n")


@dataclass(frozen=True, eq=False)
class ContactForces:
    """rcforc: per interface id and side, time (T,) and force (T, 3) in the model's units."""

    series: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]]

    def punch_force(self, interface: int | None, *, where: str = "rcforc") -> tuple[np.ndarray, np.ndarray, int]:
        """time (T,), |F| (T,) of the master side of one interface (the largest-force one when None), and its id."""
        masters = {key[0]: value for key, value in self.series.items() if key[1] == "master"}
        if not masters:
            masters = {key[0]: value for key, value in self.series.items()}
        if interface is None:
            interface = max(masters, key=lambda i: float(np.max(np.linalg.norm(masters[i][1], axis=1))))
        if interface not in masters:
            raise ValueError(f"{where}: no interface {interface}; it has {sorted(masters)}")
        time, force = masters[interface]
        return time, np.linalg.norm(force, axis=1), interface


def read_rcforc(path: str | Path) -> ContactForces:
    """Parse an ASCII rcforc file."""
    path = Path(path)
    collected: dict[tuple[int, str], list[tuple[float, float, float, float]]] = {}
    with open(path, encoding="latin-1") as handle:
        for number, line in enumerate(handle, start=1):
            match = _RCFORC.match(line)
            if match is None:
                continue
            side, ident = match.group(1).lower(), int(match.group(2))
            try:
                values = tuple(_float(match.group(g)) for g in range(3, 7))
            except ValueError:
                raise ValueError(f"{path.name}: line {number}: a force value is not a number") from None
            collected.setdefault((ident, side), []).append(values)  # type: ignore[arg-type]
    if not collected:
        raise ValueError(f"{path.name}: no 'master|slave ID time T x … y … z …' line; is it an ASCII rcforc?")
    series = {}
    for key, rows in collected.items():
        array = np.array(rows)
        series[key] = (array[:, 0], array[:, 1:4])
    return ContactForces(series)


def write_rcforc(path: str | Path, *, time: np.ndarray, force: np.ndarray, interface: int = 1) -> Path:
    """Write an ASCII rcforc for one interface; force (T, 3) on the master side (the slave side the opposite)."""
    lines = [" r e s u l t a n t   i n t e r f a c e   f o r c e s", "", ""]
    for t, time_value in enumerate(time):
        for side, sign in (("master", 1.0), ("slave", -1.0)):
            fx, fy, fz = sign * force[t]
            lines.append(f"  {side:6s}{interface:8d} time{time_value:12.5E}  x{fx:12.5E}  y{fy:12.5E}"
                         f"  z{fz:12.5E}  mass {0.0:12.5E}")  # fmt: skip
    return atomic_write(path, "\n".join(lines) + "\n")

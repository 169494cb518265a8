"""What the simulation files call their elements and their displacements: one rule for the Exodus and VTU readers.

Belongs here: which element kinds fringelab reads and how (shells and solids, quadratic ones through their corner
nodes), which it leaves aside (points and lines beside a surface), which it refuses, each with its own sentence; and
the names solvers give the nodal displacement (`DISPLACEMENT_X`, `DISPX`, `DISPLX`, `disp_x`, `MODEL_DISPLACEMENT_X`,
`U_X`, … as three scalars; `displacement`, `DISP`, `U`, … as one vector). Not here: reading a file (the
`simulation_*` modules).

Element kinds are recognised by the family of their name (Exodus `elem_type` or meshio's cell type, case ignored)
and their node count: every quadratic or higher element lists its corner nodes first (Exodus and VTK alike), so a
`triangle6`, `quad8`, `quad9`, `TRISHELL6`, `SHELL8`, `tetra10`, `HEX20`, `hexahedron27`, `wedge15` … is read as its
linear element through its corners: the surface between corners is flat, the corner displacements are exact.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# family -> (kind, corners, node counts accepted); the family is the leading letters of the type name
_FAMILIES: dict[str, tuple[str, int, frozenset[int]]] = {
    "tri": ("shell", 3, frozenset({3, 4, 6, 7})),
    "triangle": ("shell", 3, frozenset({3, 4, 6, 7})),
    "trishell": ("shell", 3, frozenset({3, 4, 6, 7})),
    "quad": ("shell", 4, frozenset({4, 5, 8, 9})),
    "shell": ("shell", 4, frozenset({4, 5, 8, 9})),  # SHELL3/SHELL6 are triangles: see _classify
    "tet": ("solid", 4, frozenset({4, 8, 10, 11, 14, 15})),
    "tetra": ("solid", 4, frozenset({4, 8, 10, 11, 14, 15})),
    "hex": ("solid", 8, frozenset({8, 9, 20, 27})),
    "hexahedron": ("solid", 8, frozenset({8, 9, 20, 27})),
    "wedge": ("solid", 6, frozenset({6, 15, 16, 18, 20, 21, 24, 52})),
    "sphere": ("point", 1, frozenset({1})),
    "vertex": ("point", 1, frozenset({1})),
    "circle": ("point", 1, frozenset({1})),
    "beam": ("line", 2, frozenset({2, 3, 4})),
    "bar": ("line", 2, frozenset({2, 3})),
    "truss": ("line", 2, frozenset({2, 3})),
    "line": ("line", 2, frozenset({2, 3, 4})),
}
READ_KINDS = (
    "shells (triangles, quadrilaterals, also quadratic ones: triangle6, quad8, quad9, …) and solids (tetrahedra, "
    "wedges, hexahedra, also quadratic ones: tetra10, hex20, …)"
)


@dataclass(frozen=True)
class CellBlock:
    """One block of elements as a file holds it: its type name, connectivity (E, k) of 0-based node positions, and
    where it is (for messages, e.g. "element block 2")."""

    type_name: str
    connectivity: np.ndarray
    where: str


def _classify(type_name: str, n_nodes: int) -> tuple[str, int] | None:
    """(kind, corners) of an element type with n_nodes per element, or None when fringelab does not read it."""
    family = re.match(r"[a-z]*", type_name.lower())
    name = family.group(0) if family else ""
    if name == "shell" and n_nodes in (3, 6):
        return "shell", 3
    rule = _FAMILIES.get(name)
    if rule is None or n_nodes not in rule[2]:
        return None
    return rule[0], rule[1]


def shells_and_solids(blocks: Sequence[CellBlock], where: str) -> tuple[np.ndarray, np.ndarray]:
    """Shells (E, 4) and solids (F, 8|6|4) of a mesh's element blocks, each element through its corner nodes
    (triangles repeat their last corner). Points and lines beside shells or solids are left aside (point masses,
    springs, beams are no part of a surface). ValueError with its own sentence for: a block of a kind fringelab
    does not read, a mesh of points only, of lines only, or without elements, and solids of mixed kinds."""
    shells, solids = [], []
    aside: dict[str, int] = {}
    for block in blocks:
        data = np.asarray(block.connectivity, np.int64)
        if data.ndim != 2:
            raise ValueError(f"{where}: {block.where} ({block.type_name}): connectivity of shape {data.shape}")
        if len(data) == 0:
            continue
        kind = _classify(block.type_name, data.shape[1])
        if kind is None:
            raise ValueError(
                f"{where}: {block.where} holds {len(data)} {block.type_name} elements ({data.shape[1]} nodes each), "
                f"a kind fringelab does not read; it reads {READ_KINDS}: export the plate part with those"
            )
        corners = data[:, : kind[1]]
        if kind[0] == "shell":
            shells.append(corners if kind[1] == 4 else np.column_stack([corners, corners[:, 2]]))
        elif kind[0] == "solid":
            solids.append(corners)
        else:
            aside[kind[0]] = aside.get(kind[0], 0) + len(data)
    if not shells and not solids:
        if aside.get("point") and not aside.get("line"):
            raise ValueError(
                f"{where}: a point-only mesh ({aside['point']} point elements such as SPHERE, no shells or solids): "
                "it has no surface to compare with the measurement (SPH or discrete particles?); export the plate "
                "as shells or solids"
            )
        if aside:
            raise ValueError(
                f"{where}: only line and point elements ({', '.join(f'{n} {k}s' for k, n in aside.items())}), no "
                f"shells or solids: no surface to compare; fringelab reads {READ_KINDS}"
            )
        raise ValueError(f"{where}: no elements: fringelab needs the plate's {READ_KINDS}")
    if len({s.shape[1] for s in solids}) > 1:
        raise ValueError(f"{where}: mixed solid element kinds; export the plate part with one kind")
    return (
        np.concatenate(shells) if shells else np.zeros((0, 4), np.int64),
        np.concatenate(solids) if solids else np.zeros((0, 8), np.int64),
    )


_COMPONENT = re.compile(r"^(model_)?(displacements?|displ?|u)[_ ]?([xyz])$", re.IGNORECASE)
VECTOR_NAMES = ("displacement", "displacements", "disp", "displ", "u", "model_displacement")
COMPONENT_HINT = "DISPLACEMENT_X/Y/Z, DISPX/Y/Z, DISPL_X/…, disp_x/…, MODEL_DISPLACEMENT_X/…, U_X/… or UX/…"


def displacement_components(names: Sequence[str], where: str) -> tuple[int, int, int]:
    """Positions of the x, y and z displacement among nodal variable names (plain names before MODEL_ ones).

    ValueError: "2-D result" when only x and y are there; else the names found and the names expected.

    >>> displacement_components(["TEMP", "MODEL_DISPLACEMENT_X", "MODEL_DISPLACEMENT_Y", "MODEL_DISPLACEMENT_Z"], "")
    (1, 2, 3)
    """
    families: dict[tuple[str, str], dict[str, int]] = {}
    for index, name in enumerate(names):
        match = _COMPONENT.match(name.strip())
        if match:
            key = ((match.group(1) or "").lower(), match.group(2).lower())
            families.setdefault(key, {}).setdefault(match.group(3).lower(), index)
    ranked = sorted(families.items(), key=lambda item: item[0][0] != "")  # plain names first
    for _, axes in ranked:
        if {"x", "y", "z"} <= axes.keys():
            return axes["x"], axes["y"], axes["z"]
    if any({"x", "y"} <= axes.keys() for _, axes in ranked):
        raise ValueError(two_d_message(where, f"displacement components x and y only among {list(names)}"))
    raise ValueError(
        f"{where}: no displacement among the nodal variables {list(names)} (expected {COMPONENT_HINT}, as three "
        "variables)"
    )


def two_d_message(where: str, detail: str) -> str:
    return (
        f"{where}: 2-D result: no out-of-plane displacement ({detail}); fringelab compares the plate's "
        "out-of-plane deflection: export a 3-D model (shells or solids)"
    )


def displacement_vector(point_data: dict[str, np.ndarray], where: str) -> np.ndarray:
    """The displacement (N, 3) among a mesh's point data: one vector named as in VECTOR_NAMES (case ignored), or
    three scalars named as `displacement_components` knows. ValueError naming what was found, or "2-D result"."""
    by_lower = {name.lower(): name for name in point_data}
    for wanted in VECTOR_NAMES:
        if wanted in by_lower:
            values = np.asarray(point_data[by_lower[wanted]], np.float64)
            if values.ndim == 2 and values.shape[1] == 3:
                return values
            if values.ndim == 2 and values.shape[1] == 2:
                raise ValueError(two_d_message(where, f"point data {by_lower[wanted]!r} has 2 components"))
    scalars = [name for name, values in point_data.items() if np.ndim(values) == 1]
    try:
        x, y, z = displacement_components(scalars, where)
    except ValueError as error:
        if "2-D result" in str(error):
            raise
        raise ValueError(
            f"{where}: no displacement vector in the point data (found {sorted(point_data) or 'none'}; expected a "
            f"vector named {', '.join(VECTOR_NAMES)} (case ignored), or three scalars {COMPONENT_HINT})"
        ) from None
    return np.column_stack([np.asarray(point_data[scalars[k]], np.float64) for k in (x, y, z)])

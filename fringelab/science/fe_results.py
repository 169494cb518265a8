"""Finite-element results as fringelab holds them in memory, whatever file they came from.

Belongs here: the one type every simulation reader returns (`FEResults`: the mesh in the model's own frame and
length unit, and its states, read one at a time) and pure helpers on it (element faces, the boundary of a solid
mesh). Not here: reading files (`fringelab.formats.simulation_*`), putting the model into the plate frame and
comparing it with a measurement (`compare.py`).

Conventions: node arrays are indexed by node position 0..N−1 (`node_ids` holds the model's own ids);
`displacement(i)` is the displacement (N, 3) of state i from the reference coordinates, in the model's length
unit; times are in the model's time unit (`time_unit_s` seconds each, None where the file does not say).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .arrays import checked_array

# Faces of the solid elements fringelab reads, as corner positions in the element's node list (VTK/Exodus/LS-DYNA
# order): hexahedron (8 nodes), tetrahedron (4), wedge (6). Each face's corners run counter-clockwise seen from
# outside the element.
SOLID_FACES: dict[int, tuple[tuple[int, ...], ...]] = {
    8: ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)),
    4: ((0, 2, 1), (0, 1, 3), (1, 2, 3), (2, 0, 3)),
    6: ((0, 2, 1), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)),
}


@dataclass(frozen=True, eq=False)
class FEResults:
    """A simulation's nodal results: its mesh and its states (displacements read one state at a time).

    node_ids (N,) int64; node_xyz (N, 3) reference coordinates in the model's length unit; shells (E, 3|4) and
    solids (F, 4|6|8) node positions of the elements (empty (0, 4) arrays where there are none);
    shell_thickness (N,) nodal shell thickness in the model's length unit, or None (no shells, or not in the
    file); time (S,) of each state in the model's time unit; displacement(i) → (N, 3), NaN rows for the nodes
    that state does not have (the nodes of eroded elements: node sets that change between states are read, and a
    node missing from a state is missing there, a hole in its surface).
    punch_time, punch_displacement (P,): the punch's travel (positive along its motion) when the file has it, in
    the model's length unit (in mm where punch_in_mm: a punch CSV);
    force_time, force (Q,): the punch force, in kN times `force_unit_kN`.
    length_unit: "mm" or "m" where the file declares it, None where it must be detected; time_unit_s and
    force_unit_kN likewise (None: not declared).
    """

    source: str
    kind: str
    node_ids: np.ndarray
    node_xyz: np.ndarray
    shells: np.ndarray
    solids: np.ndarray
    shell_thickness: np.ndarray | None
    time: np.ndarray
    displacement: Callable[[int], np.ndarray]
    length_unit: str | None = None
    time_unit_s: float | None = None
    punch_time: np.ndarray | None = None
    punch_displacement: np.ndarray | None = None
    force_time: np.ndarray | None = None
    force: np.ndarray | None = None
    force_unit_kN: float | None = None
    punch_in_mm: bool = False

    def __post_init__(self) -> None:
        n = len(checked_array(self.node_xyz, shape=(None, 3), name="node_xyz"))
        checked_array(self.node_ids, shape=(n,), name="node_ids")
        if len(self.time) == 0:
            raise ValueError(f"{self.source}: the simulation has no states")
        for name in ("shells", "solids"):
            cells = getattr(self, name)
            if cells.ndim != 2 or (cells.size and (cells.min() < 0 or cells.max() >= n)):
                raise ValueError(f"{self.source}: {name} refer to nodes outside 0..{n - 1}")

    @property
    def n_states(self) -> int:
        return len(self.time)

    @property
    def n_nodes(self) -> int:
        return len(self.node_xyz)

    def node_index(self, node_id: int) -> int:
        """Position of the node with the model's id `node_id` (ValueError naming the id if absent)."""
        hits = np.flatnonzero(self.node_ids == node_id)
        if len(hits) == 0:
            raise ValueError(
                f"{self.source}: no node with id {node_id} (ids {self.node_ids.min()}…{self.node_ids.max()})"
            )
        return int(hits[0])


def with_updates(results: FEResults, **changes: object) -> FEResults:
    """A copy of `results` with some fields replaced (a punch curve or force read from a second file)."""
    from dataclasses import replace

    return replace(results, **changes)  # type: ignore[arg-type]


def triangles_of_faces(faces: np.ndarray) -> np.ndarray:
    """Triangles (T, 3) of faces (F, 3) or (F, 4); a quad (a, b, c, d) gives (a, b, c) and (a, c, d); a quad
    with d == c (a degenerate shell, as LS-DYNA writes triangles) gives one triangle."""
    if faces.size == 0:
        return np.zeros((0, 3), np.int64)
    if faces.shape[1] == 3:
        return faces.astype(np.int64)
    first = faces[:, [0, 1, 2]]
    second = faces[:, [0, 2, 3]]
    keep = faces[:, 3] != faces[:, 2]
    return np.concatenate([first, second[keep]]).astype(np.int64)


def solid_boundary_faces(solids: np.ndarray) -> np.ndarray:
    """Faces (F, 4) of a solid mesh that belong to one element only (triangles repeat their last corner).

    solids: (E, k) with k in SOLID_FACES; degenerate hexahedra (LS-DYNA writes wedges and tetrahedra as hexahedra
    with repeated nodes) give degenerate faces, which are dropped.
    """
    if solids.size == 0:
        return np.zeros((0, 4), np.int64)
    k = solids.shape[1]
    if k not in SOLID_FACES:
        raise ValueError(f"solids: expected 4, 6 or 8 nodes per element, got {k}")
    faces = []
    for corners in SOLID_FACES[k]:
        face = solids[:, list(corners)]
        if face.shape[1] == 3:
            face = np.column_stack([face, face[:, 2]])
        faces.append(face)
    all_faces = np.concatenate(faces).astype(np.int64)
    n_distinct = np.array([len(set(row)) for row in all_faces.tolist()])
    all_faces = all_faces[n_distinct >= 3]
    key = np.sort(all_faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return all_faces[counts[inverse.ravel()] == 1]

"""Exodus and VTU results as solvers write them: displacement under the names they use, quadratic elements read
through their corners, and 2-D results, point-only meshes and element kinds fringelab does not read refused, each
with its own sentence.

Files are written with meshio (the mesh, in the Exodus II / VTK layout) and netCDF4 (Exodus's time steps and nodal
variables, as the solvers lay them out); Exodus states are compared with a plain netCDF4 read of the file's own
variables, state by state.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import netCDF4
import numpy as np
import pytest

from fringelab.formats.simulation_exodus import write_exodus
from fringelab.formats.simulation_vtu import write_vtu_series
from fringelab.formats.simulations import open_simulation
from tests.formats.test_simulations import DISP, IDS, N_STATES, QUADS, TIME, XYZ, check

TRIANGLES = np.concatenate([QUADS[:, [0, 1, 2]], QUADS[:, [0, 2, 3]]])


def triangle6_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The plate as quadratic triangles: corners first, then a node at the middle of each edge (VTK and Exodus
    order: edges 0-1, 1-2, 2-0)."""
    edges: dict[tuple[int, int], int] = {}
    points = [*XYZ]
    cells = []
    for a, b, c in TRIANGLES.tolist():
        middles = []
        for p, q in ((a, b), (b, c), (c, a)):
            key = (min(p, q), max(p, q))
            if key not in edges:
                edges[key] = len(points)
                points.append((XYZ[p] + XYZ[q]) / 2)
            middles.append(edges[key])
        cells.append([a, b, c, *middles])
    return np.array(points), np.array(cells)


def reference_states(path: Path, names: tuple[str, ...]) -> list[np.ndarray]:
    """Each time step's displacement read straight from the file's variables with netCDF4 (the reference)."""
    with netCDF4.Dataset(path) as nc:
        stored = [b"".join(row).decode().strip("\x00 ") for row in nc.variables["name_nod_var"][:].data]
        columns = [stored.index(name) + 1 for name in names]
        return [np.column_stack([nc.variables[f"vals_nod_var{k}"][s].data for k in columns])
                for s in range(len(nc.variables["time_whole"]))]  # fmt: skip


def test_exodus_model_displacement_names(tmp_path: Path) -> None:
    """MODEL_DISPLACEMENT_X/Y/Z beside other nodal variables (the old reader refused it while listing them)."""
    names = ("TEMPERATURE", "MODEL_DISPLACEMENT_X", "MODEL_DISPLACEMENT_Y", "MODEL_DISPLACEMENT_Z")
    values = np.concatenate([np.full((N_STATES, len(XYZ), 1), 300.0), DISP], axis=2)
    write_exodus(tmp_path / "m.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=values,
                 node_ids=IDS, names=names)  # fmt: skip
    results = open_simulation(tmp_path / "m.exo")
    check(results, atol=1e-12)
    for state, expected in enumerate(reference_states(tmp_path / "m.exo", names[1:])):
        np.testing.assert_array_equal(results.displacement(state), expected)


NAMES = [("DISPLACEMENT_X", "DISPLACEMENT_Y", "DISPLACEMENT_Z"), ("displ_x", "displ_y", "displ_z"),
         ("U_X", "U_Y", "U_Z"), ("DISPX", "DISPY", "DISPZ")]  # fmt: skip


@pytest.mark.parametrize("names", NAMES)
def test_exodus_displacement_names_solvers_use(tmp_path: Path, names: tuple[str, ...]) -> None:
    write_exodus(tmp_path / "m.e", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=DISP,
                 node_ids=IDS, names=names)  # fmt: skip
    check(open_simulation(tmp_path / "m.e"), atol=1e-12)


def test_exodus_2d_results_are_refused_as_2d(tmp_path: Path) -> None:
    write_exodus(tmp_path / "plane.exo", node_xyz=XYZ[:, :2], cells=[("quad", QUADS)], time=TIME,
                 displacement=DISP[..., :2], names=("DISPX", "DISPY"))  # fmt: skip
    with pytest.raises(ValueError, match=r"plane.exo: 2-D result: no out-of-plane displacement \(num_dim is 2\)"):
        open_simulation(tmp_path / "plane.exo")
    write_exodus(tmp_path / "xy.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=DISP[..., :2],
                 names=("DISPLACEMENT_X", "DISPLACEMENT_Y"))  # fmt: skip
    with pytest.raises(ValueError, match=r"xy.exo: 2-D result: no out-of-plane displacement \(displacement "
                                         r"components x and y only"):  # fmt: skip
        open_simulation(tmp_path / "xy.exo")


def test_exodus_quadratic_triangles_read_through_their_corners(tmp_path: Path) -> None:
    points, tri6 = triangle6_mesh()
    moved = np.random.default_rng(2).normal(0.0, 1.0, (N_STATES, len(points), 3))
    write_exodus(tmp_path / "tri6.exo", node_xyz=points, cells=[("triangle6", tri6)], time=TIME, displacement=moved)
    results = open_simulation(tmp_path / "tri6.exo")
    np.testing.assert_array_equal(results.shells, np.column_stack([TRIANGLES, TRIANGLES[:, 2]]))
    with netCDF4.Dataset(tmp_path / "tri6.exo") as nc:
        assert nc.variables["connect1"].elem_type.upper().startswith("TRI6")
    for state, expected in enumerate(reference_states(tmp_path / "tri6.exo", ("DISPX", "DISPY", "DISPZ"))):
        np.testing.assert_array_equal(results.displacement(state), expected)


def test_exodus_point_only_and_unknown_elements_are_refused_each_in_words(tmp_path: Path) -> None:
    write_exodus(tmp_path / "sph.exo", node_xyz=XYZ, cells=[("vertex", np.arange(len(XYZ))[:, None])], time=TIME,
                 displacement=DISP)  # fmt: skip
    with netCDF4.Dataset(tmp_path / "sph.exo") as nc:
        assert nc.variables["connect1"].elem_type == "SPHERE"
    with pytest.raises(ValueError, match=r"sph.exo: a point-only mesh \(30 point elements such as SPHERE"):
        open_simulation(tmp_path / "sph.exo")
    write_exodus(tmp_path / "nsided.exo", node_xyz=XYZ, cells=[("quad", QUADS), ("quad", QUADS[:2])], time=TIME,
                 displacement=DISP)  # fmt: skip
    with netCDF4.Dataset(tmp_path / "nsided.exo", "a") as nc:
        nc.variables["connect2"].elem_type = "NSIDED"  # meshio's own reader fails with KeyError: 'NSIDED'
    with pytest.raises(ValueError, match=r"nsided.exo: element block \d+ holds 2 NSIDED elements \(4 nodes each\), a "
                                         r"kind fringelab does not read; it reads shells"):  # fmt: skip
        open_simulation(tmp_path / "nsided.exo")


def test_vtu_quadratic_quads_and_displacement_names(tmp_path: Path) -> None:
    """quad9 cells (corners first, then edge and centre nodes) with a vector `U`; then three DISPLACEMENT_*
    scalars; a 2-component vector is a 2-D result."""
    extra = len(XYZ) + np.arange(5 * len(QUADS)).reshape(len(QUADS), 5)
    points = np.concatenate([XYZ, np.repeat(XYZ[QUADS].mean(axis=1), 5, axis=0)])
    quad9 = np.column_stack([QUADS, extra])
    moved = np.random.default_rng(4).normal(0.0, 1.0, (len(points), 3))
    mesh = meshio.Mesh(points, [("quad9", quad9)], point_data={"U": moved})
    mesh.write(tmp_path / "q9.vtu")
    results = open_simulation(tmp_path / "q9.vtu")
    np.testing.assert_array_equal(results.shells, QUADS)
    np.testing.assert_array_equal(results.displacement(0), meshio.read(tmp_path / "q9.vtu").point_data["U"])
    scalars = {f"DISPLACEMENT_{axis}": moved[:, k] for k, axis in enumerate("XYZ")}
    meshio.Mesh(points, [("quad9", quad9)], point_data=scalars).write(tmp_path / "s.vtu")
    np.testing.assert_array_equal(open_simulation(tmp_path / "s.vtu").displacement(0), moved)
    meshio.Mesh(points, [("quad9", quad9)], point_data={"displacement": moved[:, :2]}).write(tmp_path / "p.vtu")
    with pytest.raises(ValueError, match=r"p.vtu: 2-D result: no out-of-plane displacement \(point data "):
        open_simulation(tmp_path / "p.vtu")
    meshio.Mesh(points, [("pyramid", np.array([[0, 1, 7, 6, 40]]))], point_data={"U": moved}).write(tmp_path / "y.vtu")
    with pytest.raises(ValueError, match=r"y.vtu: cell block 1 holds 1 pyramid elements"):
        open_simulation(tmp_path / "y.vtu")


def test_vtu_series_writer_still_round_trips(tmp_path: Path) -> None:
    pvd = write_vtu_series(tmp_path / "v", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=DISP,
                           node_ids=IDS)  # fmt: skip
    check(open_simulation(pvd), atol=1e-12)


def test_exodus_element_death_leaves_the_nodes_of_dead_elements_out(tmp_path: Path) -> None:
    """Eroded elements as Sierra/SM writes them (element variable death_status, 1 alive, 0 dead), over two blocks:
    a node all of whose elements are dead is missing (NaN) in that state, a node with one live element is not;
    a status variable with other values (Abaqus-style STATUS of 2) is refused rather than guessed."""
    status = np.ones((N_STATES, len(QUADS)))
    status[2:, [6, 7, 11, 12]] = 0.0  # the four quads around node 14, across blocks 1 (0..9) and 2 (10..19)
    status[3, 0] = 0.0  # the corner quad: node 0 is its alone
    write_exodus(tmp_path / "m.exo", node_xyz=XYZ, cells=[("quad", QUADS[:10]), ("quad", QUADS[10:])], time=TIME,
                 displacement=DISP, node_ids=IDS, element_status=status)  # fmt: skip
    results = open_simulation(tmp_path / "m.exo")
    for state, missing in enumerate([[], [], [14], [0, 14]]):
        u = results.displacement(state)
        expected = DISP[state].copy()
        expected[missing] = np.nan
        np.testing.assert_array_equal(np.flatnonzero(np.isnan(u[:, 0])), missing)
        np.testing.assert_allclose(u, expected)  # NaN where expected NaN, the file's numbers elsewhere
    status[3, 0] = 2.0
    write_exodus(tmp_path / "odd.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=DISP,
                 element_status=status, status_name="STATUS")  # fmt: skip
    odd = open_simulation(tmp_path / "odd.exo")
    refusal = r"odd.exo: element variable 'STATUS', element block 0, step 3: values outside 0..1 \(from 0 to 2\)"
    with pytest.raises(ValueError, match=refusal + "; fringelab reads element death as 1 alive, 0 dead"):
        odd.displacement(3)

"""Simulation files: each writer read back by its reader (and by `open_simulation`), and bad files named.

The mesh is a small quad shell grid with known displacements; what is read back must equal what was written to
the precision of the file (float64, float32 in d3plot and Exodus' time, 5 significant digits in LS-DYNA's ASCII).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats import simulation_csv, simulation_exodus, simulation_lsdyna_ascii, simulation_vtu
from fringelab.formats.simulations import open_simulation

NX, NY, N_STATES = 6, 5, 4
GX, GY = np.meshgrid(np.linspace(-50.0, 50.0, NX), np.linspace(-40.0, 40.0, NY))
XYZ = np.column_stack([GX.ravel(), GY.ravel(), np.zeros(GX.size)])
QUADS = np.array([[j * NX + i, j * NX + i + 1, (j + 1) * NX + i + 1, (j + 1) * NX + i]
                  for j in range(NY - 1) for i in range(NX - 1)])  # fmt: skip
TIME = np.array([0.0, 0.001, 0.0025, 0.004])
DISP = np.random.default_rng(1).normal(0.0, 2.0, (N_STATES, len(XYZ), 3))
IDS = np.arange(101, 101 + len(XYZ))


def check(results, *, atol: float) -> None:  # type: ignore[no-untyped-def]
    assert results.n_states == N_STATES and results.n_nodes == len(XYZ)
    np.testing.assert_allclose(results.node_xyz, XYZ, atol=atol)
    np.testing.assert_allclose(results.time, TIME, atol=1e-7)
    np.testing.assert_array_equal(results.node_ids, IDS)
    for state in (0, N_STATES - 1, 1):
        np.testing.assert_allclose(results.displacement(state), DISP[state], atol=atol)


def test_nodes_csv_and_punch_csv(tmp_path: Path) -> None:
    simulation_csv.write_nodes_csv(tmp_path / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME, displacement_mm=DISP)
    simulation_csv.write_punch_csv(tmp_path / "p.csv", time_s=TIME, force_kN=np.arange(4.0),
                                   punch_displacement_mm=np.arange(4.0) * 2)  # fmt: skip
    results = open_simulation(tmp_path)
    check(results, atol=1e-6)
    assert results.length_unit == "mm" and results.time_unit_s == 1.0 and len(results.shells) == 0
    np.testing.assert_allclose(results.force, np.arange(4.0))
    assert results.force_unit_kN == 1.0 and results.punch_in_mm
    np.testing.assert_allclose(results.punch_displacement, np.arange(4.0) * 2)


def test_vtu_series(tmp_path: Path) -> None:
    thickness = np.full(len(XYZ), 1.5)
    pvd = simulation_vtu.write_vtu_series(tmp_path / "vtu", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                          displacement=DISP, node_ids=IDS, thickness=thickness)  # fmt: skip
    for path in (pvd, tmp_path / "vtu"):
        results = open_simulation(path)
        check(results, atol=1e-12)
        np.testing.assert_array_equal(results.shells, QUADS)
        np.testing.assert_allclose(results.shell_thickness, 1.5)


def test_exodus(tmp_path: Path) -> None:
    simulation_exodus.write_exodus(tmp_path / "m.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                   displacement=DISP, node_ids=IDS)  # fmt: skip
    results = open_simulation(tmp_path / "m.exo")
    check(results, atol=1e-12)
    np.testing.assert_array_equal(results.shells, QUADS)


def test_nodout_and_rcforc_give_the_punch(tmp_path: Path) -> None:
    simulation_csv.write_nodes_csv(tmp_path / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME, displacement_mm=DISP)
    travel = np.zeros((N_STATES, 2, 3))
    travel[:, 0, 2] = [0.0, 1.5, -3.25, 7.0]  # the punch node; |u| is its travel
    travel[:, 1, 0] = 1.0
    simulation_lsdyna_ascii.write_nodout(tmp_path / "nodout", time=TIME, node_ids=np.array([7, 9]),
                                         displacement=travel, coordinates=np.zeros((2, 3)))  # fmt: skip
    force = np.zeros((N_STATES, 3))
    force[:, 1] = [0.0, -2.0, 5.0, 1.0]
    simulation_lsdyna_ascii.write_rcforc(tmp_path / "rcforc", time=TIME, force=force, interface=3)
    with pytest.raises(ValueError, match=r"nodout: 2 nodes .*set the punch node \(--punch-node ID\)"):
        open_simulation(tmp_path)
    results = open_simulation(tmp_path, punch_node=7)
    np.testing.assert_allclose(results.punch_displacement, [0.0, 1.5, 3.25, 7.0], rtol=1e-4)
    np.testing.assert_allclose(results.force, [0.0, 2.0, 5.0, 1.0], rtol=1e-4)
    assert results.force_unit_kN is None  # rcforc says nothing about units
    with pytest.raises(ValueError, match=r"no interface 4; it has \[3\]"):
        open_simulation(tmp_path, punch_node=7, contact_interface=4)


def test_punch_node_of_the_mesh(tmp_path: Path) -> None:
    simulation_csv.write_nodes_csv(tmp_path / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME, displacement_mm=DISP)
    results = open_simulation(tmp_path / "m.csv", punch_node=int(IDS[4]))
    np.testing.assert_allclose(results.punch_displacement, np.linalg.norm(DISP[:, 4], axis=1), atol=1e-6)
    with pytest.raises(ValueError, match="no node with id 5 "):
        open_simulation(tmp_path / "m.csv", punch_node=5)


def test_bad_files_are_named(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match=r"no simulation model found \(notes.txt\).*state,time_s,node"):
        open_simulation(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text("state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n0,0,1,0,0,0,0,0,0\n0,0,2,1,0,0,x,0,0\n")
    with pytest.raises(ValueError, match=r"bad.csv: line 3: 'x' is not a number"):
        open_simulation(bad)
    bad.write_text("state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm\n0,0,1,0,0,0,0,0\n")
    with pytest.raises(ValueError, match=r"line 1: missing column\(s\) uz_mm"):
        open_simulation(bad)
    bad.write_text("state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n0,0,1,0,0,0,0,0,0\n0,0,1,0,0,0,0,0,0\n")
    with pytest.raises(ValueError, match=r"bad.csv: line 3: node 1 appears twice in state 0"):
        open_simulation(bad)
    (tmp_path / "x.vtu").write_text("not xml")
    with pytest.raises(ValueError, match=r"x.vtu: not a readable mesh file"):
        open_simulation(tmp_path / "x.vtu")
    (tmp_path / "nodout").write_text("nothing here\n")
    with pytest.raises(ValueError, match=r"nodout: no 'nodal print out' block"):
        simulation_lsdyna_ascii.read_nodout(tmp_path / "nodout")
    with pytest.raises(ValueError, match=r"no such file or folder"):
        open_simulation(tmp_path / "missing")


def test_a_node_missing_from_a_state_is_missing_there(tmp_path: Path) -> None:
    """Node sets that change between states (eroded elements after a perforation): each state keeps its own."""
    table = tmp_path / "eroded.csv"
    table.write_text("state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n"
                     "0,0,1,0,0,0,0,0,0\n0,0,2,10,0,0,0,0,0\n0,0,3,0,10,0,0,0,0\n"
                     "1,1,2,10,0,0,0,0,2\n1,1,3,0,10,0,0,0,3\n")  # fmt: skip
    results = open_simulation(table)
    assert results.n_states == 2 and list(results.node_ids) == [1, 2, 3]
    np.testing.assert_array_equal(results.displacement(0)[:, 2], [0.0, 0.0, 0.0])
    assert np.all(np.isnan(results.displacement(1)[0])) and list(results.displacement(1)[1:, 2]) == [2.0, 3.0]


def test_a_vtu_series_whose_later_state_leaves_eroded_nodes_out(tmp_path: Path) -> None:
    """.vtu files of one series with a smaller node set after a perforation: matched by node_id, the nodes a state
    lacks are missing there (NaN), never a refusal."""
    import meshio

    points = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]])
    cells = [("triangle", np.array([[0, 1, 2], [1, 3, 2]]))]
    ids = np.array([11, 12, 13, 14])
    u0 = np.zeros((4, 3))
    meshio.write(tmp_path / "s0.vtu", meshio.Mesh(points, cells, point_data={"displacement": u0, "node_id": ids}))
    kept = np.array([1, 2, 3])  # node 11 eroded
    u1 = np.column_stack([np.zeros(3), np.zeros(3), [2.0, 3.0, 4.0]])
    meshio.write(tmp_path / "s1.vtu", meshio.Mesh(points[kept], [("triangle", np.array([[0, 2, 1]]))],
                                                  point_data={"displacement": u1, "node_id": ids[kept]}))  # fmt: skip
    results = open_simulation(tmp_path)
    assert results.n_states == 2
    later = results.displacement(1)
    assert np.all(np.isnan(later[0])) and list(later[1:, 2]) == [2.0, 3.0, 4.0]

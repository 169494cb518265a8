"""The checked simulation (`fringelab.formats.simulation_store`): what a check read, stored and read back, makes the
same `FEResults` as the uploaded files (`assemble` of the same parts): exact, as it is float64 throughout, whatever
the punch node and contact interface chosen afterwards."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats import simulation_csv, simulation_lsdyna_ascii, simulation_vtu
from fringelab.formats.simulation_store import read_checked, write_checked
from fringelab.formats.simulations import assemble, open_simulation, read_parts
from tests.formats.test_simulations import DISP, IDS, QUADS, TIME, XYZ


def same(a, b) -> None:  # type: ignore[no-untyped-def]
    for name in ("node_ids", "node_xyz", "shells", "solids", "time", "punch_time", "punch_displacement",
                 "force_time", "force"):  # fmt: skip
        left, right = getattr(a, name), getattr(b, name)
        assert (left is None) == (right is None), name
        if left is not None:
            np.testing.assert_array_equal(left, right, err_msg=name)
    assert (a.kind, a.length_unit, a.time_unit_s, a.force_unit_kN, a.punch_in_mm) == (
        b.kind, b.length_unit, b.time_unit_s, b.force_unit_kN, b.punch_in_mm,
    )  # fmt: skip
    for state in range(a.n_states):
        np.testing.assert_array_equal(a.displacement(state), b.displacement(state))


def test_a_csv_with_its_punch_csv_reads_back_the_same(tmp_path: Path) -> None:
    folder = tmp_path / "fe"
    folder.mkdir()
    simulation_csv.write_nodes_csv(folder / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME, displacement_mm=DISP)
    simulation_csv.write_punch_csv(folder / "p.csv", time_s=TIME, force_kN=np.arange(4.0),
                                   punch_displacement_mm=np.arange(4.0) * 2)  # fmt: skip
    store = write_checked(tmp_path / "checked.h5", read_parts(folder))
    same(assemble(read_checked(store)), open_simulation(folder))


def test_a_vtu_series_with_a_nodout_of_two_nodes_and_an_rcforc_reads_back_the_same_for_each_choice(
    tmp_path: Path,
) -> None:
    folder = tmp_path / "fe"
    simulation_vtu.write_vtu_series(folder, node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME, displacement=DISP,
                                    node_ids=IDS, thickness=np.full(len(XYZ), 1.5))  # fmt: skip
    simulation_lsdyna_ascii.write_nodout(folder / "nodout", time=TIME, node_ids=np.array([9001, 9002]),
                                         displacement=DISP[:, :2], coordinates=XYZ[:2])  # fmt: skip
    simulation_lsdyna_ascii.write_rcforc(folder / "rcforc", time=TIME, force=np.ones((len(TIME), 3)))
    stored = read_checked(write_checked(tmp_path / "checked.h5", read_parts(folder)))
    np.testing.assert_array_equal(stored.model.shell_thickness, 1.5)
    for node in (9001, 9002):
        same(assemble(stored, punch_node=node), open_simulation(folder, punch_node=node))
    with pytest.raises(ValueError, match="nodout: 2 nodes"):
        assemble(stored)  # the punch node must be chosen, as with the files
    same(assemble(stored, punch_needed=False), open_simulation(folder, punch_needed=False))


def test_a_file_that_is_no_checked_simulation_is_named(tmp_path: Path) -> None:
    (tmp_path / "checked.h5").write_bytes(b"nothing")
    with pytest.raises(ValueError, match=r"checked.h5: not a readable HDF5 file"):
        read_checked(tmp_path / "checked.h5")

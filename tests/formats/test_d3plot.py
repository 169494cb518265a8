"""LS-DYNA d3plot families, written with lasso-python's writer (the layout LS-DYNA writes: a geometry file, state
files d3plot01, d3plot02, … each closed by the end mark and padded to whole blocks), read by fringelab and
compared state by state with lasso-python's own full read, and broken as copies and runs break them.

Marked `lsdyna`: they need lasso-python, which pins plotly 5; `make test` runs them in `.venv-lsdyna` (the
project with the `lsdyna` extra), the rest of the suite in `.venv`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.simulations import open_simulation
from tests.formats.test_simulations import DISP, IDS, N_STATES, QUADS, TIME, XYZ, check

pytestmark = pytest.mark.lsdyna
lasso_dyna = pytest.importorskip("lasso.dyna", reason="d3plot needs lasso-python: `make test` runs it in .venv-lsdyna")
from fringelab.formats.simulation_d3plot import write_d3plot  # noqa: E402

A = lasso_dyna.ArrayType


def lasso_geometry() -> object:
    d3plot = lasso_dyna.D3plot()
    d3plot.arrays[A.node_coordinates] = XYZ
    d3plot.arrays[A.node_ids] = IDS
    d3plot.arrays[A.element_shell_node_indexes] = QUADS
    d3plot.arrays[A.element_shell_part_indexes] = np.zeros(len(QUADS), np.int64)
    return d3plot


@pytest.mark.parametrize("one_state_per_file", [False, True])
def test_d3plot_family_read_state_by_state(tmp_path: Path, one_state_per_file: bool) -> None:
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP, node_ids=IDS,
                 shell_thickness=2.0, one_state_per_file=one_state_per_file)  # fmt: skip
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == (["d3plot", "d3plot01", "d3plot02", "d3plot03", "d3plot04"] if one_state_per_file
                     else ["d3plot", "d3plot01"])  # fmt: skip
    results = open_simulation(tmp_path)
    check(results, atol=1e-4)  # positions are float32 in the file: 1e-4 mm at 100 mm
    np.testing.assert_array_equal(results.shells, QUADS)
    np.testing.assert_allclose(results.shell_thickness, 2.0)
    reference = lasso_dyna.D3plot(str(tmp_path / "d3plot"))  # lasso reads every state at once
    np.testing.assert_array_equal(results.time, reference.arrays[A.global_timesteps])
    for state in range(N_STATES):  # the same float32 numbers: equal to float32 round-off of the subtraction
        expected = reference.arrays[A.node_displacement][state] - reference.arrays[A.node_coordinates]
        np.testing.assert_allclose(results.displacement(state), expected, atol=1e-5)


def test_d3plot_with_nodout_keeps_the_punch_travel_of_its_last_state(tmp_path: Path) -> None:
    """d3plot holds its times as float32, nodout prints them with 8 digits: the last state's time lies a hair
    after nodout's last, and its punch travel (with it the state, in an alignment by displacement) must not be
    lost. A nodout of several nodes still uploads (punch_needed=False) and then has no punch travel."""
    from fringelab.formats import simulation_lsdyna_ascii
    from fringelab.science.compare import PlateFrame, map_model, state_punch_mm

    time = np.array([0.0, 0.0033333333, 0.0066666667, 0.0123456789])  # the last: float32 rounds it up
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=time, displacement=0.01 * DISP, node_ids=IDS)
    travel = np.zeros((N_STATES, 1, 3))
    travel[:, 0, 2] = 1000.0 * time
    simulation_lsdyna_ascii.write_nodout(tmp_path / "nodout", time=time, node_ids=np.array([9]), displacement=travel,
                                         coordinates=np.zeros((1, 3)))  # fmt: skip
    results = open_simulation(tmp_path)
    assert results.time[-1] > results.punch_time[-1]  # as LS-DYNA's files have it
    model = map_model(results, PlateFrame(axis_xy_mm=(0.0, 0.0), data_box_mm=(-50.0, 50.0, -40.0, 40.0)))
    np.testing.assert_allclose(state_punch_mm(model), 1000.0 * time, rtol=1e-4)  # type: ignore[arg-type]  # 5 digits
    both = np.concatenate([travel, travel], axis=1)
    simulation_lsdyna_ascii.write_nodout(tmp_path / "nodout", time=time, node_ids=np.array([9, 10]),
                                         displacement=both, coordinates=np.zeros((2, 3)))  # fmt: skip
    assert open_simulation(tmp_path, punch_needed=False).punch_displacement is None


def test_a_family_with_a_gap_is_refused_naming_the_missing_file(tmp_path: Path) -> None:
    """lasso reads d3plot01, 02, 04 as three states without a word; the missing file is named instead."""
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP,
                 one_state_per_file=True)  # fmt: skip
    (tmp_path / "d3plot03").unlink()
    assert len(lasso_dyna.D3plot(str(tmp_path / "d3plot")).arrays[A.global_timesteps]) == N_STATES - 1
    with pytest.raises(ValueError, match=r"d3plot: the family has a gap: d3plot03 missing .*up to d3plot04"):
        open_simulation(tmp_path)


@pytest.mark.parametrize("one_state_per_file", [False, True])
def test_a_file_cut_inside_a_state_is_refused_naming_it(tmp_path: Path, one_state_per_file: bool) -> None:
    """A copy cut short: the last file ends inside a state (lasso drops that state without a word)."""
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP,
                 one_state_per_file=one_state_per_file)  # fmt: skip
    last = sorted(tmp_path.glob("d3plot0*"))[-1]
    state_bytes = int(lasso_dyna.D3plot(str(tmp_path / "d3plot"))._compute_n_bytes_per_state())
    keep = (0 if one_state_per_file else 2 * state_bytes) + state_bytes // 2
    last.write_bytes(last.read_bytes()[:keep])
    name = last.name
    match = rf"{name}: (ends inside a state|holds no whole state).*shorter than the header says"
    with pytest.raises(ValueError, match=match):
        open_simulation(tmp_path)


def test_a_thermal_result_is_refused_at_upload_with_a_sentence(tmp_path: Path) -> None:
    """Node temperatures and no positions: refused when it is opened (the upload's check), not with a KeyError
    when a comparison asks for a displacement."""
    from fringelab.core.errors import Invalid
    from fringelab.core.simulation_check import read_simulation_summary

    d3plot = lasso_geometry()
    d3plot.arrays[A.global_timesteps] = TIME  # type: ignore[attr-defined]
    d3plot.arrays[A.node_temperature] = np.full((N_STATES, len(XYZ)), 293.0)  # type: ignore[attr-defined]
    d3plot.write_d3plot(str(tmp_path / "d3plot"))  # type: ignore[attr-defined]
    refusal = r"d3plot: no nodal displacements or coordinates per state \(its states hold node temperatures\): was it"
    with pytest.raises(ValueError, match=refusal + " written by a thermal-only run"):
        open_simulation(tmp_path)
    with pytest.raises(Invalid, match=r"thermal.zip: not a simulation fringelab reads: d3plot: no nodal displacements"):
        read_simulation_summary(tmp_path, filename="thermal.zip", max_bytes=2**30)


def test_geometry_only_says_so(tmp_path: Path) -> None:
    """A geometry file without its state files (lasso: "State '0' exceeds the maximum number of states of '0'"),
    and one written with no state at all."""
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP)
    (tmp_path / "d3plot01").unlink()
    with pytest.raises(ValueError, match=r"d3plot: geometry only, no states \(30 nodes, 20 shells, 0 solids; 0 state "):
        open_simulation(tmp_path)
    lasso_geometry().write_d3plot(str(tmp_path / "d3plot"))  # type: ignore[attr-defined]
    assert [p.name for p in tmp_path.iterdir()] == ["d3plot"]
    with pytest.raises(ValueError, match=r"d3plot: geometry only, no states"):
        open_simulation(tmp_path)


def test_not_a_d3plot_is_named(tmp_path: Path) -> None:
    (tmp_path / "d3plot").write_bytes(b"\x01" * 300)
    with pytest.raises(ValueError, match=r"d3plot: not a readable d3plot \("):
        open_simulation(tmp_path)


def test_a_header_declaring_60_m_nodes_is_refused_before_the_geometry_is_read(tmp_path: Path) -> None:
    """Issue 26, finding 4: the control header's NUMNP (word 16) says 60 M nodes in a file of a few KB; refused by
    the budget (`simulation_budget`) from the header alone, before lasso reads a geometry that size (tracemalloc's
    peak: numpy's buffers are traced)."""
    import tracemalloc

    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP, node_ids=IDS)
    data = bytearray((tmp_path / "d3plot").read_bytes())
    assert np.frombuffer(bytes(data[64:68]), np.int32)[0] == len(XYZ)  # lasso writes 4-byte words
    data[64:68] = np.array([60_000_000], np.int32).tobytes()
    (tmp_path / "d3plot").write_bytes(bytes(data))
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"d3plot: declares 60000000 nodes, 20 elements \(its control header\): "
                                             r"reading it would take about 3204 MiB"):  # fmt: skip
            open_simulation(tmp_path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, peak
    (tmp_path / "sound").mkdir()
    write_d3plot(tmp_path / "sound" / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP)
    assert open_simulation(tmp_path / "sound", max_bytes=2**20).n_nodes == len(XYZ)
    with pytest.raises(ValueError, match="FRINGELAB_SIMULATION_MAX_BYTES"):
        open_simulation(tmp_path / "sound", max_bytes=1024)


def test_a_damaged_geometry_file_is_a_value_error_naming_it(tmp_path: Path) -> None:
    """Cut or overwritten anywhere in its geometry file: refused in words (lasso raises many kinds: here each becomes
    a ValueError naming the d3plot), or read whole. Overwritten numbers a reader cannot tell from real ones."""
    (tmp_path / "sound").mkdir()
    write_d3plot(tmp_path / "sound" / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP)
    data = (tmp_path / "sound" / "d3plot").read_bytes()
    for n, fraction in enumerate((0.0, 0.05, 0.2, 0.5, 0.8, 0.99, 0.1, 0.3, 0.6)):
        folder = tmp_path / f"d{n}"
        folder.mkdir()
        write_d3plot(folder / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP)
        at = int(len(data) * fraction)
        damaged = data[:at] if n < 6 else data[:at] + b"\xff\x7f\x00\x80" * 8 + data[at + 32 :]
        (folder / "d3plot").write_bytes(damaged)
        try:
            results = open_simulation(folder)
            assert results.n_states == N_STATES
            for state in range(N_STATES):
                results.displacement(state)
        except ValueError as error:
            assert "d3plot" in str(error), str(error)


def test_eroded_shells_leave_their_nodes_out_of_the_states_they_are_deleted_in(tmp_path: Path) -> None:
    """Element deletion flags (MDLOPT 2) as LS-DYNA writes them after a perforation: the four quads around node
    14 deleted from state 2 on, the corner quad (node 0 is its alone) in state 3. Compared with lasso's own full
    read: a node all of whose shells are deleted is NaN in that state, every other node as lasso reads it."""
    alive = np.ones((N_STATES, len(QUADS)))
    alive[2:, [6, 7, 11, 12]] = 0.0
    alive[3, 0] = 0.0
    write_d3plot(tmp_path / "d3plot", node_xyz=XYZ, shells=QUADS, time=TIME, displacement=DISP, node_ids=IDS,
                 shell_is_alive=alive)  # fmt: skip
    results = open_simulation(tmp_path)
    reference = lasso_dyna.D3plot(str(tmp_path / "d3plot"))
    np.testing.assert_array_equal(reference.arrays[A.element_shell_is_alive], alive)
    for state, missing in enumerate([[], [], [14], [0, 14]]):
        u = results.displacement(state)
        np.testing.assert_array_equal(np.flatnonzero(np.isnan(u).any(axis=1)), missing)
        expected = reference.arrays[A.node_displacement][state] - reference.arrays[A.node_coordinates]
        expected[missing] = np.nan
        np.testing.assert_allclose(u, expected, atol=1e-5)  # float32 round-off of the subtraction, as above


def test_eroded_solids_leave_their_nodes_out(tmp_path: Path) -> None:
    """The plate as one layer of hexahedra with element_solid_is_alive: the four hexes around the column of node
    14 deleted in the last state, its two nodes (bottom and top) NaN there, the rest as lasso reads it."""
    n = len(XYZ)
    xyz = np.concatenate([XYZ, XYZ + [0.0, 0.0, 1.0]])
    d3plot = lasso_dyna.D3plot()
    d3plot.arrays[A.node_coordinates] = xyz
    d3plot.arrays[A.element_solid_node_indexes] = np.concatenate([QUADS, QUADS + n], axis=1)
    d3plot.arrays[A.element_solid_part_indexes] = np.zeros(len(QUADS), np.int64)
    d3plot.arrays[A.global_timesteps] = TIME
    d3plot.arrays[A.node_displacement] = xyz[None] + np.concatenate([DISP, DISP], axis=1)
    alive = np.ones((N_STATES, len(QUADS)))
    alive[3, [6, 7, 11, 12]] = 0.0
    d3plot.arrays[A.element_solid_is_alive] = alive
    d3plot.write_d3plot(str(tmp_path / "d3plot"))
    results = open_simulation(tmp_path)
    reference = lasso_dyna.D3plot(str(tmp_path / "d3plot"))
    for state, missing in enumerate([[], [], [], [14, 14 + n]]):
        u = results.displacement(state)
        np.testing.assert_array_equal(np.flatnonzero(np.isnan(u).any(axis=1)), missing)
        expected = reference.arrays[A.node_displacement][state] - reference.arrays[A.node_coordinates]
        expected[missing] = np.nan
        np.testing.assert_allclose(u, expected, atol=1e-5)  # float32 round-off of the subtraction

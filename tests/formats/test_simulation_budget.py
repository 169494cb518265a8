"""Declared sizes before arrays (issue 26, finding 4): every simulation reader refuses what a file declares beyond
its budget (`fringelab.formats.simulation_budget`, FRINGELAB_SIMULATION_MAX_BYTES) before it allocates it, naming
the file, what it declares and the setting. "Before it allocates": the reading's peak of traced allocations
(tracemalloc sees numpy's buffers) stays far below what the declared arrays would take. The d3plot header's case is
in tests/formats/test_d3plot.py (lasso's venv)."""

from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats import simulation_csv, simulation_exodus, simulation_lsdyna_ascii, simulation_vtu
from fringelab.formats.simulation_budget import declared_bytes
from fringelab.formats.simulations import open_simulation
from tests.formats.test_simulations import DISP, IDS, QUADS, TIME, XYZ

MIB = 2**20
REFUSED = r"refused before reading it"


def refused_within(read: Callable[[], object], *, match: str, peak_below_bytes: int) -> None:
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=match):
            read()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < peak_below_bytes, peak / MIB


def test_the_rule_counts_nodes_elements_and_the_states_held() -> None:
    # coordinates and ids (4), one state's displacement (3), 4 corners per quad: 8 bytes each
    assert declared_bytes(n_nodes=1000, n_corners=4 * 900) == 8 * (7 * 1000 + 3600)
    assert declared_bytes(n_nodes=10, n_states_held=5, n_states=5) == 8 * (40 + 150 + 5)


def test_an_exodus_header_declaring_60_m_nodes_is_refused_before_its_coordinates_are_read(tmp_path: Path) -> None:
    import netCDF4

    path = tmp_path / "huge.exo"
    with netCDF4.Dataset(path, "w") as nc:  # 16 KB: the dimensions declare, nothing is stored
        for name, size in (("num_nodes", 60_000_000), ("num_dim", 3), ("num_el_blk", 1), ("num_el_in_blk1", 1),
                           ("num_nod_per_el1", 4)):  # fmt: skip
            nc.createDimension(name, size)
        nc.createDimension("time_step", None)
        for axis in "xyz":
            nc.createVariable(f"coord{axis}", "f8", ("num_nodes",), fill_value=0.0, chunksizes=(1_000_000,))
        nc.createVariable("connect1", "i4", ("num_el_in_blk1", "num_nod_per_el1"))[:] = [[1, 2, 3, 4]]
    assert path.stat().st_size < 64_000
    message = r"huge.exo: declares 60000000 nodes, 1 element \(its header's dimensions\): reading it would take about"
    # 60 M nodes × 7 values × 8 bytes = 3204 MiB; reading the coordinates alone would allocate 1373 MiB
    refused_within(lambda: simulation_exodus.read_exodus(path), match=message + r" 3204 MiB, more than the 1024 MiB",
                   peak_below_bytes=16 * MIB)  # fmt: skip
    with pytest.raises(ValueError, match="FRINGELAB_SIMULATION_MAX_BYTES"):
        open_simulation(path)
    # a sound model under a budget it fits reads; under one it does not, it is refused
    sound = simulation_exodus.write_exodus(tmp_path / "m.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                           displacement=DISP, node_ids=IDS)  # fmt: skip
    assert open_simulation(sound, max_bytes=MIB).n_nodes == len(XYZ)
    with pytest.raises(ValueError, match="m.exo: declares 30 nodes, 20 elements, 4 states"):
        open_simulation(sound, max_bytes=1024)


def test_a_vtu_piece_declaring_60_m_points_is_refused_before_meshio_reads_it(tmp_path: Path) -> None:
    pvd = simulation_vtu.write_vtu_series(tmp_path / "vtu", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                          displacement=DISP, node_ids=IDS)  # fmt: skip
    first = sorted(pvd.parent.glob("*.vtu"))[0]
    text = first.read_text()
    assert f'NumberOfPoints="{len(XYZ)}"' in text
    first.write_text(text.replace(f'NumberOfPoints="{len(XYZ)}"', 'NumberOfPoints="60000000"'))
    message = rf"{first.name}: declares 60000000 nodes, 20 elements .*{REFUSED}"
    refused_within(lambda: open_simulation(pvd), match=message, peak_below_bytes=4 * MIB)


def test_a_csv_is_refused_by_its_rows_estimated_from_its_size_and_by_its_state_and_node_numbers(
    tmp_path: Path,
) -> None:
    path = simulation_csv.write_nodes_csv(tmp_path / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME,
                                          displacement_mm=DISP)  # fmt: skip
    # 120 rows (and the header) of 9 columns, three times over while parsed: 25920 bytes
    message = r"m.csv: holds about 12\d rows of 9 columns, from its size: reading it would take about 2\d KiB"
    refused_within(lambda: simulation_csv.read_nodes_csv(path, max_bytes=20_000), match=message, peak_below_bytes=MIB)
    assert simulation_csv.read_nodes_csv(path, max_bytes=MIB).n_nodes == len(XYZ)
    # 3000 rows, each a state of its own and a node of its own: every state holds every node, 3000 × 3000 × 3
    # values (206 MiB) from a 100 KB file
    sparse = tmp_path / "sparse.csv"
    sparse.write_text(",".join(simulation_csv.NODES_COLUMNS) + "\n"
                      + "".join(f"{i},{i * 1e-3},{i + 1},{i},0,0,0,0,1\n" for i in range(3000)))  # fmt: skip
    assert sparse.stat().st_size < 100_000
    refused_within(lambda: simulation_csv.read_nodes_csv(sparse, max_bytes=64 * MIB),
                   match=r"sparse.csv: declares 3000 nodes, 3000 states \(its state and node numbers\)",
                   peak_below_bytes=8 * MIB)  # fmt: skip


def test_nodout_and_rcforc_are_refused_by_their_lines_estimated_from_their_size(tmp_path: Path) -> None:
    nodout = simulation_lsdyna_ascii.write_nodout(tmp_path / "nodout", time=TIME, node_ids=IDS,
                                                  displacement=DISP, coordinates=XYZ)  # fmt: skip
    rcforc = simulation_lsdyna_ascii.write_rcforc(tmp_path / "rcforc", time=TIME, force=np.ones((len(TIME), 3)))
    for path, read in ((nodout, simulation_lsdyna_ascii.read_nodout), (rcforc, simulation_lsdyna_ascii.read_rcforc)):
        refused_within(lambda p=path, r=read: r(p, max_bytes=1000),  # type: ignore[misc]
                       match=rf"{path.name}: holds about \d+ lines, from its size", peak_below_bytes=MIB)  # fmt: skip
        read(path, max_bytes=MIB)

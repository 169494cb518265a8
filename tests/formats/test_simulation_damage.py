"""Damaged simulation files: every reader, given a file cut short or with bytes overwritten, either reads it whole
or refuses it with a ValueError naming the file, never a KeyError, IndexError or another exception from deep in a
library, and never a model with fewer states or nodes than the file says. An LS-DYNA history (nodout, rcforc) has
no count of its time steps: cut between two of them it cannot be told from a shorter run, so there the samples read
must be the sound file's first ones, exactly. (d3plot: tests/formats/test_d3plot.py.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fringelab.formats import simulation_csv, simulation_exodus, simulation_lsdyna_ascii, simulation_vtu
from fringelab.formats.simulations import open_simulation
from tests.formats.test_simulations import DISP, IDS, N_STATES, QUADS, TIME, XYZ


def write(kind: str, folder: Path) -> Path:
    """One simulation file of `kind` in `folder`; returns the file to damage."""
    folder.mkdir()
    if kind == "csv":
        return simulation_csv.write_nodes_csv(folder / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME,
                                              displacement_mm=DISP)  # fmt: skip
    if kind == "vtu":
        pvd = simulation_vtu.write_vtu_series(folder, node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                              displacement=DISP)  # fmt: skip
        return sorted(pvd.parent.glob("*.vtu"))[1]
    if kind == "exodus":
        return simulation_exodus.write_exodus(folder / "m.exo", node_xyz=XYZ, cells=[("quad", QUADS)], time=TIME,
                                              displacement=DISP)  # fmt: skip
    simulation_csv.write_nodes_csv(folder / "m.csv", node_ids=IDS, node_xyz_mm=XYZ, time_s=TIME, displacement_mm=DISP)
    travel = np.zeros((N_STATES, 2, 3))
    travel[:, 0, 2] = [0.0, 1.5, 3.25, 7.0]
    if kind == "nodout":
        return simulation_lsdyna_ascii.write_nodout(folder / "nodout", time=TIME, node_ids=np.array([7, 9]),
                                                    displacement=travel, coordinates=np.zeros((2, 3)))  # fmt: skip
    return simulation_lsdyna_ascii.write_rcforc(folder / "rcforc", time=TIME, force=travel[:, 0], interface=3)


def read_all(folder: Path, sound: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    results = open_simulation(folder, punch_node=7 if (folder / "nodout").exists() else None)
    assert results.n_states == N_STATES and results.n_nodes == len(XYZ)  # whole, or refused: never fewer
    for state in range(results.n_states):
        assert results.displacement(state).shape == (len(XYZ), 3)
    histories = {name: np.asarray(getattr(results, name)) for name in ("punch_displacement", "force")
                 if getattr(results, name) is not None}  # fmt: skip
    for name, values in histories.items():
        if sound is not None:  # a history cut between time steps: the first samples, exactly
            np.testing.assert_array_equal(values, sound[name][: len(values)])
    return histories


@pytest.mark.parametrize("kind", ["csv", "vtu", "exodus", "nodout", "rcforc"])
def test_damaged_files_are_read_whole_or_refused_naming_the_file(tmp_path: Path, kind: str) -> None:
    original = write(kind, tmp_path / "sound")
    sound = read_all(original.parent)
    data = original.read_bytes()
    rng = np.random.default_rng(7)
    # A nodal CSV states no count of nodes or states: cut at a line end it is a smaller table, and cut inside a
    # number it still parses; it is damaged here by overwriting only.
    damages = [] if kind == "csv" else [("cut", f) for f in (0.0, 0.1, 0.37, 0.5, 0.83, 0.97)]
    damages += [("overwrite", float(f)) for f in rng.uniform(0.05, 0.95, 8)]
    for n, (how, fraction) in enumerate(damages):
        folder = tmp_path / f"{how}{n}"
        target = write(kind, folder)
        at = int(len(data) * fraction)
        target.write_bytes(data[:at] if how == "cut" else data[:at] + b"\xff#\x00q" * 8 + data[at + 32 :])
        try:
            read_all(folder, sound)
        except ValueError as error:
            assert target.name in str(error) or folder.name in str(error), (how, fraction, str(error))

"""LS-DYNA d3plot families (d3plot, d3plot01, d3plot02, …) through lasso-python (the optional extra
`fringelab[lsdyna]`).

The geometry (node ids and coordinates, shell and solid connectivity) and the state times are read once; the
nodal positions of a state are read when that state is asked for (lasso's `state_filter`), so a family of many
gigabytes is never in memory at once. A d3plot stores the current coordinates of every node in each state
(lasso's `node_displacement`); the displacement is that minus the reference coordinates. Shell thickness, when the
file has it, is taken from the first state and averaged onto the nodes. (`buffered_reading=True` is passed
with every `state_filter`: lasso 2.0 takes a filter of state 0 alone, `{0}`, as no filter and reads all states.)

Eroded elements: a d3plot written with deletion flags (MDLOPT 2 in the header: lasso's `element_shell_is_alive`,
`element_solid_is_alive` per state, 0 deleted, otherwise alive) is read state by state; a node all of whose shells
and solids are deleted in a state is missing there (NaN displacement: `FEResults`' rule), a hole in that state's
surface. LS-DYNA still writes positions for those nodes, frozen where the element died: they are no plate surface.
Node deletion flags (MDLOPT 1, lasso's `node_is_alive`, 0 deleted) mark the nodes themselves.

Checked before anything is read, because lasso reads what it finds without a word: the family's numbering has no
gap (d3plot01, d3plot02, … each there), every file holds whole states (a file that ends inside a state, shorter
than the header's state size says, is a copy cut short), the states carry nodal positions (a thermal-only result
does not), there is at least one state, and the times do not go back. Each refusal names the file.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES, check_declared
from fringelab.science.fe_results import FEResults

INSTALL_HINT = "reading d3plot files needs lasso-python: pip install 'fringelab[lsdyna]'"
END_MARK = -999999.0  # LS-DYNA's end-of-data word after the last state of a file


def _lasso() -> tuple[Any, Any]:
    try:
        from lasso.dyna import ArrayType, D3plot
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    return D3plot, ArrayType


def is_d3plot(path: Path) -> bool:
    """Whether a file is the first file of a d3plot family, by name (d3plot, *.d3plot)."""
    return path.is_file() and (path.name.lower() == "d3plot" or path.suffix.lower() == ".d3plot")


def family_files(path: Path) -> list[Path]:
    """The state files of the family whose first file is `path` (path01, path02, … in order); ValueError naming
    the first missing one when the numbering has a gap."""
    pattern = re.compile(re.escape(path.name) + r"([0-9]+)$")
    numbered: dict[int, Path] = {}
    for entry in path.parent.iterdir():
        match = pattern.match(entry.name)
        if match and entry.is_file():
            numbered[int(match.group(1))] = entry
    if not numbered:
        return []
    missing = [n for n in range(1, max(numbered) + 1) if n not in numbered]
    if missing:
        names = ", ".join(f"{path.name}{n:02d}" for n in missing[:5]) + ("…" if len(missing) > 5 else "")
        raise ValueError(
            f"{path.name}: the family has a gap: {names} missing (there are {len(numbered)} files up to "
            f"{numbered[max(numbered)].name}); the states in the missing file would be lost: copy the whole family "
            "from the solver's folder"
        )
    return [numbered[n] for n in sorted(numbered)]


def _data_end(file: Path, word_bytes: int) -> int:
    """The byte offset after the last non-zero byte of `file`, rounded up to a whole word (LS-DYNA pads its
    files with zeros to whole blocks)."""
    size = file.stat().st_size
    chunk = 1 << 16
    with open(file, "rb") as handle:
        stop = size
        while stop > 0:
            start = max(0, stop - chunk)
            handle.seek(start)
            block = np.frombuffer(handle.read(stop - start), np.uint8)
            nonzero = np.flatnonzero(block)
            if len(nonzero):
                end = start + int(nonzero[-1]) + 1
                return -(-end // word_bytes) * word_bytes
            stop = start
    return 0


def _check_whole_states(files: list[Path], *, first_offset: int, state_bytes: int, word_bytes: int) -> None:
    """ValueError naming the first file that ends inside a state (a copy cut short), or a state file that holds
    no state. files[0] is the geometry file, whose states (if any) start at first_offset."""
    end_mark = np.array([END_MARK], np.float32 if word_bytes == 4 else np.float64).tobytes()
    for index, file in enumerate(files):
        start = first_offset if index == 0 else 0
        end = _data_end(file, word_bytes)
        n_states, rest = divmod(max(end - start, 0), state_bytes)
        if index > 0 and n_states == 0:
            raise ValueError(
                f"{file.name}: holds no whole state ({file.stat().st_size} bytes, a state is {state_bytes}): the "
                "file is shorter than the header says; copy the family again from the solver's folder"
            )
        if rest == 0 or (rest == word_bytes and _word_at(file, end - word_bytes, word_bytes) == end_mark):
            continue
        if file.stat().st_size >= start + (n_states + 1) * state_bytes:
            continue  # the state in progress is whole, its last words zero
        raise ValueError(
            f"{file.name}: ends inside a state (byte {end}: {n_states} whole states of {state_bytes} bytes from byte "
            f"{start}, then {rest} bytes): the file is shorter than the header says; copy the family again from "
            "the solver's folder"
        )


def _word_at(file: Path, offset: int, word_bytes: int) -> bytes:
    with open(file, "rb") as handle:
        handle.seek(offset)
        return handle.read(word_bytes)


def _open(D3plot: Any, path: Path, **options: Any) -> Any:
    try:
        return D3plot(str(path), **options)
    except Exception as error:  # lasso raises many kinds for a file it cannot parse
        raise ValueError(f"{path.name}: not a readable d3plot ({type(error).__name__}: {error})") from None


def _check_header(path: Path, max_bytes: int) -> None:
    """The sizes the control header declares (nodes; shells, solids, thick shells and beams with their nodes and
    part) against the budget (`simulation_budget`), before lasso reads the geometry they size. Only the header is
    read (lasso's `D3plotHeader`); the states are read one at a time."""
    from lasso.dyna import D3plotHeader

    try:
        header = D3plotHeader().load_file(str(path))
    except Exception as error:  # lasso raises many kinds for a file it cannot parse
        raise ValueError(f"{path.name}: not a readable d3plot ({type(error).__name__}: {error})") from None
    counts = {"shells": 4, "solids": 8, "thick_shells": 8, "beams": 5}  # nodes (and a beam's orientation) each
    n_elements = sum(max(0, int(getattr(header, f"n_{name}", 0))) for name in counts)
    n_corners = sum(max(0, int(getattr(header, f"n_{name}", 0))) * (k + 1) for name, k in counts.items())
    check_declared(path.name, max_bytes=max_bytes, n_nodes=max(0, int(header.n_nodes)), n_elements=n_elements,
                   n_corners=n_corners, what="its control header")  # fmt: skip


def read_d3plot(path: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> FEResults:
    """The first file of a d3plot family as `FEResults` (length and time units not declared); ValueError before
    its geometry is read when its header declares more than `max_bytes` (`simulation_budget`)."""
    D3plot, ArrayType = _lasso()
    path = Path(path)
    files = family_files(path)
    _check_header(path, max_bytes)
    timeline = _open(D3plot, path, state_array_filter=[ArrayType.global_timesteps], buffered_reading=True)
    header = timeline.header
    try:  # lasso's own sizes (private, pinned below lasso 3): the bytes of one state and of the geometry
        state_bytes = int(timeline._compute_n_bytes_per_state())
        first_offset = int(timeline.geometry_section_size)
    except Exception as error:
        raise ValueError(f"{path.name}: not a readable d3plot ({type(error).__name__}: {error})") from None
    _check_whole_states([path, *files], first_offset=first_offset, state_bytes=state_bytes,
                        word_bytes=int(header.wordsize))  # fmt: skip
    times = np.asarray(timeline.arrays.get(ArrayType.global_timesteps, np.zeros(0)), np.float64)
    arrays = timeline.arrays
    if ArrayType.node_coordinates not in arrays:
        raise ValueError(f"{path.name}: a d3plot without node coordinates in its geometry: is it damaged?")
    xyz = np.asarray(arrays[ArrayType.node_coordinates], np.float64)
    n_nodes = len(xyz)
    shells = np.asarray(arrays.get(ArrayType.element_shell_node_indexes, np.zeros((0, 4))), np.int64)
    solids = np.asarray(arrays.get(ArrayType.element_solid_node_indexes, np.zeros((0, 8))), np.int64)
    if len(times) == 0:
        raise ValueError(
            f"{path.name}: geometry only, no states ({n_nodes} nodes, {len(shells)} shells, {len(solids)} solids; "
            f"{len(files)} state files): the run wrote no output time, or only its geometry file was copied; "
            "upload the family with its state files (d3plot01, …)"
        )
    if not header.has_node_displacement:
        held = "node temperatures" if header.has_node_temperatures else "no nodal result"
        raise ValueError(
            f"{path.name}: no nodal displacements or coordinates per state (its states hold {held}): was it "
            "written by a thermal-only run, or with the nodal coordinates switched off in *DATABASE_EXTENT_BINARY? "
            "Upload the structural run's d3plot"
        )
    backwards = np.flatnonzero(np.diff(times) < 0)
    if len(backwards):
        k = int(backwards[0]) + 1
        raise ValueError(
            f"{path.name}: state {k} (t = {times[k]:.6g}) comes before state {k - 1} (t = {times[k - 1]:.6g}): "
            "files of two runs mixed in one family? copy the family again from the solver's folder"
        )
    thickness = None
    if len(shells):
        first = _open(D3plot, path, state_filter={0}, state_array_filter=[ArrayType.element_shell_thickness],
                      buffered_reading=True)  # fmt: skip
        if ArrayType.element_shell_thickness in first.arrays:
            per_shell = np.asarray(first.arrays[ArrayType.element_shell_thickness], np.float64)[0]
            total = np.bincount(shells.ravel(), weights=np.repeat(per_shell, shells.shape[1]), minlength=n_nodes)
            count = np.bincount(shells.ravel(), minlength=n_nodes)
            with np.errstate(invalid="ignore", divide="ignore"):
                thickness = np.where(count > 0, total / count, np.nan)
    ids = arrays.get(ArrayType.node_ids)
    cache: dict[int, np.ndarray] = {}
    # node_is_alive is left out of the filter: lasso 2.0 refuses it there ("not a state array") and reads it anyway
    alive_arrays = [ArrayType.element_shell_is_alive, ArrayType.element_solid_is_alive]
    has_deletion = bool(header.has_node_deletion_data or header.has_element_deletion_data)

    def displacement(i: int) -> np.ndarray:
        if i not in cache:
            if not 0 <= i < len(times):
                raise ValueError(f"{path.name}: no state {i}; it has {len(times)}")
            wanted = [ArrayType.node_displacement, *(alive_arrays if has_deletion else [])]
            state = _open(D3plot, path, state_filter={i}, state_array_filter=wanted, buffered_reading=True)
            current = np.asarray(state.arrays.get(ArrayType.node_displacement, np.zeros(0)), np.float64)
            if current.shape != (1, n_nodes, 3):
                raise ValueError(f"{path.name}: state {i}: expected positions (1, {n_nodes}, 3), got {current.shape}")
            u = current[0] - xyz
            if has_deletion:  # eroded elements: their nodes are a hole in this state
                u[_deleted_nodes(state.arrays, ArrayType, shells=shells, solids=solids, n_nodes=n_nodes,
                                 where=f"{path.name}: state {i}")] = np.nan  # fmt: skip
            cache.clear()
            cache[i] = u
        return cache[i]

    return FEResults(
        source=str(path), kind="d3plot",
        node_ids=np.asarray(ids, np.int64) if ids is not None else np.arange(1, n_nodes + 1), node_xyz=xyz,
        shells=shells, solids=solids, shell_thickness=thickness, time=times, displacement=displacement,
    )  # fmt: skip


def _deleted_nodes(arrays: dict[Any, Any], ArrayType: Any, *, shells: np.ndarray, solids: np.ndarray,
                   n_nodes: int, where: str) -> np.ndarray:  # fmt: skip
    """(N,) bool for the one state in `arrays`: the nodes marked deleted, and the nodes all of whose shells and
    solids are deleted (a node of no shell or solid is not)."""

    def flags_of(name: Any, n: int, what: str) -> np.ndarray:
        flags = np.asarray(arrays[name]) if name in arrays else np.ones((1, n))
        if flags.shape != (1, n):
            raise ValueError(f"{where}: {what} deletion flags of shape {flags.shape}, expected (1, {n})")
        return flags[0]

    # MDLOPT 1 (untested here: lasso 2.0's writer cannot write node deletion flags)
    deleted = flags_of(ArrayType.node_is_alive, n_nodes, "node") == 0
    in_element = np.zeros(n_nodes, bool)
    alive = np.zeros(n_nodes, bool)
    for cells, name in ((shells, ArrayType.element_shell_is_alive), (solids, ArrayType.element_solid_is_alive)):
        if len(cells):
            in_element[cells.ravel()] = True
            alive[cells[flags_of(name, len(cells), "element") != 0].ravel()] = True
    return deleted | (in_element & ~alive)


def write_d3plot(
    path: str | Path,
    *,
    node_xyz: np.ndarray,
    shells: np.ndarray,
    time: np.ndarray,
    displacement: np.ndarray,
    node_ids: np.ndarray | None = None,
    shell_thickness: float | None = None,
    one_state_per_file: bool = False,
    shell_is_alive: np.ndarray | None = None,
) -> Path:
    """Write a d3plot family with lasso-python's writer: shells (E, 4) (triangles repeat their last corner),
    states (S, N, 3) of displacement at times (S,); the geometry in `path`, the states in `path`01 (or one state
    per file, `path`01, `path`02, …, as LS-DYNA splits a long run). For tests and examples; the state files are
    moved into place before the geometry, so a reader never sees a family without its states. shell_is_alive
    (S, E), 1 alive and 0 deleted, writes element deletion flags (MDLOPT 2), as a run with eroded shells has them."""
    from fringelab.formats.atomic import commit_partial, partial_path

    D3plot, ArrayType = _lasso()
    d3plot = D3plot()
    d3plot.arrays[ArrayType.node_coordinates] = np.asarray(node_xyz, np.float64)
    d3plot.arrays[ArrayType.node_ids] = (
        np.arange(1, len(node_xyz) + 1) if node_ids is None else np.asarray(node_ids, np.int64)
    )
    d3plot.arrays[ArrayType.element_shell_node_indexes] = np.asarray(shells, np.int64)
    d3plot.arrays[ArrayType.element_shell_part_indexes] = np.zeros(len(shells), np.int64)
    d3plot.arrays[ArrayType.global_timesteps] = np.asarray(time, np.float64)
    d3plot.arrays[ArrayType.node_displacement] = np.asarray(node_xyz, np.float64)[None] + np.asarray(displacement)
    if shell_is_alive is not None:
        d3plot.arrays[ArrayType.element_shell_is_alive] = np.asarray(shell_is_alive, np.float64)
    if shell_thickness is not None:
        d3plot.arrays[ArrayType.element_shell_thickness] = np.full((len(time), len(shells)), float(shell_thickness))
    path = Path(path)
    # lasso 2.0 writes a wrong file to an open handle, and to a path it writes the geometry there and the states
    # to path01: the family is written in a hidden folder beside the target, then each file moved into place.
    folder = partial_path(path)
    folder.mkdir()
    try:
        d3plot.write_d3plot(str(folder / path.name), single_file=not one_state_per_file)
        for file in sorted(folder.iterdir(), key=lambda f: (len(f.name), f.name), reverse=True):
            commit_partial(file, path.parent / file.name)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return path

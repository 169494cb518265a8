"""A whole virtual test written to disk in the recording formats, with its ground truth beside it.

The rendering is `fringelab.science.virtual_test`; this module only writes what it renders (`fringelab.formats`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.atomic import write_json
from fringelab.formats.camera import write_camera_json
from fringelab.formats.recordings import write_recording
from fringelab.formats.sidecars import FrameTable, frames_csv_text, z_csv_text
from fringelab.science.chessboard import Board
from fringelab.science.synthetic import ChessboardRenderer, board_pose_at_z, zstack_board
from fringelab.science.virtual_test import FringeRenderer, Imaging, preset, true_camera_calibration
from fringelab.science.virtual_test import scenario as scenario_of


@dataclass(frozen=True)
class VirtualTest:
    """Paths of a written virtual test."""

    root: Path
    camera_calibration: Path
    projector_calibration: Path
    test: Path
    camera_json: Path
    truth_json: Path


def write_virtual_test(
    out_dir: str | Path,
    preset_name: str,
    *,
    n_test_frames: int = 40,
    calibration_z_mm: Sequence[float] | np.ndarray | None = None,
    camera_z_mm: Sequence[float] = tuple(np.linspace(-20.0, 100.0, 13)),
    as_zip: bool = False,
    seed: int = 0,
    imaging: Imaging | None = None,
    scenario: str = "quasi-static",
    progress: Callable[[int, int, str], None] | None = None,
) -> VirtualTest:
    """Write a whole virtual test for one camera in the recording formats, with ground truth beside it.

    out_dir/camera_calibration  chessboard Z-stack (frames, z.csv, board.json)
    out_dir/projector_calibration  flat plate at calibration_z_mm (default −4 … 80 mm in 2 mm steps,
        `virtual_test.calibration_heights_mm`; z.csv)
    out_dir/test  the punch test in n_test_frames (frames.csv: frame,time_s,punch_displacement_mm,force_kN)
    out_dir/truth/camera.json  the exact camera as a camera-calibration file
    out_dir/truth/experiment.json  camera, projector, scene, imaging, calibration heights and per-frame states
    (folders, or .zip files with as_zip). Frames are rendered and written one at a time. scenario: one of
    `virtual_test.SCENARIOS` (the paper's quasi-static test by default; "fast", "petals", "highlight", "shadow",
    "hard" are harder tests, see `virtual_test.scenario`).
    """

    setup, timeline = scenario_of(scenario, preset(preset_name, imaging=imaging), n_test_frames)
    z_cal = np.asarray(setup.calibration_z_mm if calibration_z_mm is None else calibration_z_mm, np.float64)
    root = Path(out_dir)
    root.mkdir(parents=True, exist_ok=True)
    suffix = ".zip" if as_zip else ""
    rng = np.random.default_rng(seed)
    total = len(camera_z_mm) + len(z_cal) + n_test_frames
    done = 0

    def counted(frames: Iterator[np.ndarray], stage: str) -> Iterator[np.ndarray]:
        nonlocal done
        for frame in frames:
            yield frame
            done += 1
            if progress is not None:
                progress(done, total, stage)

    board: Board = zstack_board(setup.camera)
    chessboard = ChessboardRenderer(setup.camera, board)
    board_json = json.dumps({"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm}) + "\n"
    camera_path = write_recording(
        root / f"camera_calibration{suffix}",
        counted((chessboard.render(board_pose_at_z(z), rng=rng) for z in camera_z_mm), "camera calibration"),
        sidecars={"z.csv": z_csv_text(list(camera_z_mm)), "board.json": board_json},
        as_zip=as_zip,
    )
    renderer = FringeRenderer(setup)
    projector_path = write_recording(
        root / f"projector_calibration{suffix}",
        counted((renderer.render_flat(z, rng=rng) for z in z_cal), "projector calibration"),
        sidecars={"z.csv": z_csv_text(z_cal.tolist())},
        as_zip=as_zip,
    )
    table = FrameTable(
        frame=np.arange(n_test_frames), time_s=timeline.time_s,
        punch_displacement_mm=timeline.punch_displacement_mm, force_kN=timeline.force_kN,
    )  # fmt: skip
    test_path = write_recording(
        root / f"test{suffix}",
        counted((renderer.render_test(state, rng=rng) for state in timeline.states), "test"),
        sidecars={"frames.csv": frames_csv_text(table)},
        as_zip=as_zip,
    )

    camera_json = write_camera_json(true_camera_calibration(setup.camera), root / "truth" / "camera.json")
    truth = {
        "preset": setup.name,
        "camera": asdict(setup.camera),
        "projector": asdict(setup.projector),
        "scene": asdict(setup.scene),
        "imaging": asdict(setup.imaging),
        "board": {"cols": board.cols, "rows": board.rows, "square_mm": board.square_mm},
        "camera_calibration_z_mm": list(map(float, camera_z_mm)),
        "projector_calibration_z_mm": z_cal.tolist(),
        "perforation_frame": timeline.perforation_frame,
        "frames": [{"frame": i, **asdict(s)} for i, s in enumerate(timeline.states)],
        "deflection": "w(r) = w0 ln(rho_R/rho)/ln(rho_R/b), rho = sqrt(r^2 + b^2), rho_R = sqrt(R^2 + b^2), "
        "b = punch_radius_mm, R = clamp_radius_mm, r from scene.centre_xy_mm; no surface for r < hole_radius_mm; "
        "petals and cracks as in fringelab.science.virtual_test.PlateScene.surface_mm",
        "scenario": scenario,
        "seed": seed,
    }
    truth_json = write_json(root / "truth" / "experiment.json", truth)
    return VirtualTest(root, camera_path, projector_path, test_path, camera_json, truth_json)


SIMULATION_WRITERS = ("csv", "vtu", "exodus", "d3plot")


def write_true_simulation(
    truth_json: str | Path,
    out: str | Path,
    *,
    kind: str,
    state_punch_mm: Sequence[float] | np.ndarray | None = None,
    quarter: bool = False,
    length_unit: str = "mm",
    resolution: float = 0.04,
) -> Path:
    """The virtual test's true surface written as a finite-element simulation (a folder, returned).

    kind: "csv" (nodal table + punch CSV with force and punch travel), "vtu" (.pvd series), "exodus" or "d3plot"
    (the last three with an LS-DYNA nodout of the punch node and an rcforc of the punch force). The states are
    the test's frames, or the punch displacements state_punch_mm. quarter: a quarter model about the plate
    centre (origin there). length_unit "m" writes metres (and N in rcforc); the CSV is always mm.
    """
    from fringelab.formats.simulation_csv import write_nodes_csv, write_punch_csv
    from fringelab.formats.simulation_lsdyna_ascii import write_nodout, write_rcforc
    from fringelab.science.virtual_test import PlateScene, true_plate_model

    if kind not in SIMULATION_WRITERS:
        raise ValueError(f"kind: expected one of {SIMULATION_WRITERS}, got {kind!r}")
    truth = json.loads(Path(truth_json).read_text())
    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in truth["scene"].items()}
    scene = PlateScene(**fields)
    _, timeline = scenario_of(truth.get("scenario", "quasi-static"), preset(truth["preset"]), len(truth["frames"]))
    punch = None if state_punch_mm is None else np.asarray(state_punch_mm, np.float64)
    model = true_plate_model(scene, timeline, state_punch_mm=punch, quarter=quarter, resolution=resolution)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    n_nodes = len(model.node_xyz_mm)
    ids = np.arange(1, n_nodes + 1)
    if kind == "csv":
        write_nodes_csv(folder / "plate.csv", node_ids=ids, node_xyz_mm=model.node_xyz_mm, time_s=model.time_s,
                        displacement_mm=model.displacement_mm)  # fmt: skip
        write_punch_csv(folder / "punch.csv", time_s=model.time_s, force_kN=model.force_kN,
                        punch_displacement_mm=model.punch_displacement_mm)  # fmt: skip
        return folder
    scale = {"mm": 1.0, "m": 1e-3}[length_unit]
    xyz, displacement = scale * model.node_xyz_mm, scale * model.displacement_mm
    if kind == "vtu":
        from fringelab.formats.simulation_vtu import write_vtu_series

        write_vtu_series(folder, node_xyz=xyz, cells=[("triangle", model.triangles)], time=model.time_s,
                         displacement=displacement, node_ids=ids)  # fmt: skip
    elif kind == "exodus":
        from fringelab.formats.simulation_exodus import write_exodus

        write_exodus(folder / "plate.e", node_xyz=xyz, cells=[("triangle", model.triangles)], time=model.time_s,
                     displacement=displacement, node_ids=ids)  # fmt: skip
    else:
        from fringelab.formats.simulation_d3plot import write_d3plot

        shells = np.column_stack([model.triangles, model.triangles[:, 2]])
        write_d3plot(folder / "d3plot", node_xyz=xyz, shells=shells, time=model.time_s, displacement=displacement,
                     node_ids=ids)  # fmt: skip
    punch = np.zeros((len(model.time_s), 1, 3))
    punch[:, 0, 2] = scale * model.punch_displacement_mm
    write_nodout(folder / "nodout", time=model.time_s, node_ids=np.array([n_nodes + 1]), displacement=punch,
                 coordinates=np.zeros((1, 3)))  # fmt: skip
    force = np.zeros((len(model.time_s), 3))
    force[:, 2] = model.force_kN * (1.0 if length_unit == "mm" else 1000.0)
    write_rcforc(folder / "rcforc", time=model.time_s, force=force)
    return folder

"""A topography result against a finite-element simulation, file to file (what `fringelab compare` and the
worker's comparison job call).

Reads the result (`formats.topography`) and the simulation (`formats.simulations`, state by state), maps the
model and pairs frames with states (`science.compare`), adds the camera calibration's term to σ_w
(`science.uncertainty`), and streams the comparison file (`formats.comparison`) frame by frame.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.comparison import ComparisonWriter, pair_result, plate_frame_of
from fringelab.formats.hdf5 import json_text
from fringelab.formats.simulation_budget import DEFAULT_MAX_BYTES
from fringelab.formats.simulations import open_simulation
from fringelab.formats.topography import TopographyResult
from fringelab.science import compare
from fringelab.science.calibration import CAMERA_PARAMETERS
from fringelab.science.fields import Grid, line_profile
from fringelab.science.uncertainty import camera_sigma_xy_mm, with_camera_term


@dataclass(frozen=True)
class ComparisonSummary:
    """What a comparison produced: the file, the mapping used and the per-frame differences."""

    path: Path
    mapping: dict[str, Any]
    alignment: str
    frames: list[dict[str, Any]]

    def as_json(self) -> dict[str, Any]:
        """`{"frames": [{"frame", "rms_diff_mm", "max_diff_mm"}, …]}` plus the mapping (NaN → null)."""
        return json.loads(json_text({"frames": self.frames, "mapping": self.mapping, "alignment": self.alignment}))


def camera_covariance_field(result: TopographyResult, grid: Grid, has: np.ndarray) -> np.ndarray | None:
    """Covariance (ny, nx, 2, 2) of X, Y at the grid nodes from the result's camera calibration, or None when
    the result records no parameter uncertainty (an exact camera)."""
    from fringelab.formats.camera import calibration_from_dict

    text = result.file["calibration"].attrs.get("camera_json") if "calibration" in result.file else None
    if text is None:
        return None
    document = json.loads(text)
    if "parameters" not in document or "correlation" not in document:
        return None
    calibration = calibration_from_dict(document)
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    points = np.column_stack([gx[has], gy[has], np.full(int(has.sum()), result.z_flat_mm)])
    covariance = np.zeros((*grid.shape, 2, 2))
    covariance[has] = camera_sigma_xy_mm(
        calibration.camera, points, standard_errors=calibration.standard_errors,
        correlation=np.nan_to_num(calibration.correlation), parameters=CAMERA_PARAMETERS,
    )  # fmt: skip
    return covariance


def _slopes(w: np.ndarray, step_mm: float) -> np.ndarray:
    dw_dy, dw_dx = np.gradient(w, step_mm)
    return np.stack([dw_dx, dw_dy], axis=-1)


def compare_result(
    result_path: str | Path,
    simulation_path: str | Path,
    out_path: str | Path,
    *,
    align: str = "displacement",
    mapping: compare.MappingSettings | None = None,
    punch_node: int | None = None,
    contact_interface: int | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    max_simulation_bytes: int = DEFAULT_MAX_BYTES,
) -> ComparisonSummary:
    """Compare a topography result with a simulation into a comparison file (layout in `formats.comparison`).

    Raises ValueError for unreadable input and `compare.ComparisonError` (naming the setting) when the model
    cannot be mapped or aligned or does not overlap the measurement; nothing is written then. The model's
    declared arrays may take `max_simulation_bytes` (`formats.simulation_budget`).
    """
    if align not in compare.ALIGNMENTS:
        raise ValueError(f"align: expected one of {compare.ALIGNMENTS}, got {align!r}")
    simulation = open_simulation(simulation_path, punch_node=punch_node, contact_interface=contact_interface,
                                 max_bytes=max_simulation_bytes)  # fmt: skip
    with TopographyResult(result_path) as result:
        grid = result.grid
        plate = plate_frame_of(result)
        if progress is not None:
            progress(0, result.n_frames, "aligning")
        pairing = pair_result(result, simulation, mapping=mapping, align=align)
        model, alignment, sampler, state_peak = pairing.model, pairing.alignment, pairing.sampler, pairing.state_peak_mm
        n_states = simulation.n_states
        frame_time = result.column("frames/time_s")
        frame_punch = result.column("frames/punch_displacement_mm")
        frame_force = result.column("frames/force_kN")
        frame_peak = result.measured_peaks()  # a peak not measured is no peak to compare (docs/method.md §8)
        frame_peak_measured = result.peak_measured()
        covariance = camera_covariance_field(result, grid, np.isfinite(result.w_grid(0)))
        state_time = simulation.time * model.mapping.time_unit_s
        state_punch = compare.state_punch_mm(model)
        state_force = compare.state_force_kN(model)
        nan_states = np.full(n_states, np.nan)
        curves = {"time_s": state_time, "punch_displacement_mm": nan_states if state_punch is None else state_punch,
                  "force_kN": nan_states if state_force is None else state_force, "peak_w_mm": state_peak}  # fmt: skip
        axis_x, axis_y = plate.axis_xy_mm
        lines = {"x": ((float(grid.x_mm[0]), axis_y), (float(grid.x_mm[-1]), axis_y)),
                 "y": ((axis_x, float(grid.y_mm[0])), (axis_x, float(grid.y_mm[-1])))}  # fmt: skip
        empty = {axis: line_profile(np.zeros(grid.shape), grid, *line) for axis, line in lines.items()}
        attrs = {
            "result": str(result_path), "simulation": str(simulation_path), "simulation_kind": simulation.kind,
            "alignment": align, "mapping_json": json_text(model.mapping.as_dict()),
        }  # fmt: skip
        rows: list[dict[str, Any]] = []
        profile_s = {a: p.s_mm for a, p in empty.items()}
        profile_xy = {a: (p.x_mm, p.y_mm) for a, p in empty.items()}
        writer = ComparisonWriter(out_path, grid=grid, profile_s_mm=profile_s, profile_xy_mm=profile_xy, attrs=attrs)
        with writer:
            for i, frame in enumerate(result.frames):
                w_meas = result.w_grid(i)
                sigma = result.sigma_grid(i)
                if sigma is not None and covariance is not None:
                    sigma = with_camera_term(sigma, _slopes(w_meas, grid.step_mm), covariance)
                lo, fraction = int(alignment.state_lo[i]), float(alignment.fraction[i])
                nan = float("nan")
                if lo >= 0:
                    w_sim = sampler.at(lo, fraction)
                    diff, stats = compare.frame_difference(w_meas, w_sim, sigma_w_mm=sigma)
                    hi = min(lo + 1, n_states - 1)

                    def blend(values: np.ndarray, lo: int = lo, hi: int = hi, fraction: float = fraction) -> float:
                        return float((1.0 - fraction) * values[lo] + fraction * values[hi])

                    sim = {"sim_time_s": blend(state_time),
                           "sim_punch_displacement_mm": blend(curves["punch_displacement_mm"]),
                           "sim_force_kN": blend(curves["force_kN"]),
                           "sim_peak_w_mm": float(np.nanmax(w_sim)) if np.any(np.isfinite(w_sim)) else nan}  # fmt: skip
                else:
                    w_sim = np.full(grid.shape, np.nan)
                    diff, stats = compare.frame_difference(w_meas, w_sim)
                    sim = dict.fromkeys(
                        ("sim_time_s", "sim_punch_displacement_mm", "sim_force_kN", "sim_peak_w_mm"), nan
                    )
                sigma_field = sigma if sigma is not None else np.full(grid.shape, np.nan)
                columns = {
                    "time_s": frame_time[i], "punch_displacement_mm": frame_punch[i], "force_kN": frame_force[i],
                    "peak_w_mm": frame_peak[i], "peak_measured": frame_peak_measured[i],
                    "state_fraction": fraction if lo >= 0 else nan, **sim,
                    "rms_diff_mm": stats.rms_diff_mm, "max_diff_mm": stats.max_diff_mm,
                    "mean_diff_mm": stats.mean_diff_mm, "fraction_beyond_2sigma": stats.fraction_beyond_2sigma,
                }  # fmt: skip
                profiles = {}
                for axis, line in lines.items():
                    stack = line_profile(np.stack([w_meas, w_sim, sigma_field]), grid, *line).values
                    profiles[axis] = {"measured_mm": stack[0], "simulated_mm": stack[1], "sigma_mm": stack[2]}
                fields = {"w_meas_mm": w_meas, "w_sim_mm": w_sim, "diff_mm": diff, "sigma_w_mm": sigma_field}
                writer.append(frame=int(frame), state_lo=lo, n_nodes=stats.n_nodes, reason=alignment.reason[i],
                              columns=columns, profiles=profiles, fields=fields)  # fmt: skip
                rows.append({"frame": int(frame), "rms_diff_mm": stats.rms_diff_mm, "max_diff_mm": stats.max_diff_mm})
                if progress is not None:
                    progress(i + 1, result.n_frames, "frames")
            path = writer.close(curves)
    return ComparisonSummary(path=path, mapping=model.mapping.as_dict(), alignment=align, frames=rows)

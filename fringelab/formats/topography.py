"""The topography result file (HDF5): its writer, which streams frames in, and its reader, which the API and the
exports go through.

Belongs here: the result's layout (`topography_layout`, every dataset declared once, as data), the streaming
writer (`TopographyWriter`, points and grids compressed in threads), its XDMF sidecar for ParaView (`write_xdmf`),
and the reader (`TopographyResult`: columns, points, grids, profiles and cuts of a frame). Not here: exports for
other tools (`exports`), the projector calibration (`projector`), a chunk's stored edges (`edges`), recordings
(`recordings`). Every file is written to a temporary name beside its target and renamed when complete.

Topography result (schema "fringelab.topography", version 1); lengths in mm in the object frame (docs/method.md §2:
+Z toward the camera), frames are recording frame indices; every dataset has `unit` and `description` attrs:
  /                 attrs: schema, schema_version, created_utc, n_frames, z_flat_mm (median Z of the first frame:
                    w = z − z_flat), grid_step_mm, grid_max_edge_mm, axis, settings_json, edge_settings_json,
                    provenance_json (code versions, input checksums)
  /calibration      attrs: camera_json (the camera calibration document or the camera's parameters),
                    camera_fingerprint, projector_json (its settings, QA, provenance, table size)
  /frames           index (n,) int64; camera_frame (n,) int64 (the camera's numbering, e.g. from a .cine's
                    trigger; absent in older files: the index); time_s, punch_displacement_mm, force_kN (n,)
                    float64, NaN if not logged; time_s from frames.csv, else the recording's own time stamps
                    (root attr time_source says which)
  /points           offsets (n + 1,) int64: frame i's points are rows offsets[i]:offsets[i+1] of
                    x_mm, y_mm, z_mm (P,) float32, edge (P,) int32 (edge index k), line (P,) int32 (scan line),
                    sigma_w_mm (P,) float32: σ of each point's height (`science.uncertainty`), NaN where unknown
  /grid             x_mm (nx,), y_mm (ny,); z_mm (n, ny, nx) float32, chunked one frame per chunk, NaN outside
                    the data; sigma_w_mm (n, ny, nx) float32, σ of the gridded height (interpolated like z)
Files written before σ existed have no sigma_w_mm datasets; the reader then returns None for σ.
  /peak             w_mm, x_mm, y_mm (n,): the largest deflection of the grid and where; centre_x_mm,
                    centre_y_mm (n,): centroid of the area above half the peak (the punch axis), NaN early on;
                    measured (n,) int8: 1 where the peak was measured, 0 where w_mm is only a lower bound (the rule
                    of `science.peaks`, attr radius_mm), missing_nodes (n,) int32: plate nodes within that radius
                    of the maximum without data (−1: no data at all). Absent in older files: unknown.
  /qa               n_points, n_tracks, n_ended, n_out_of_range, n_unmatched (n,) int64; edge_noise_px,
                    grid_coverage (n,) float64 (fraction of the first frame's grid area still with data);
                    since the per-frame order (absent in older files, read as NaN): measured_fraction,
                    visible_area_mm2, measured_area_mm2 and missing_<reason>_mm2 for every reason in
                    MISSING_REASONS (n,) float64 (what of the plate the reference frame sees was measured, and
                    what not, by reason); n_order_conflicts, n_order_unresolved (n,) int64; peak_region_coverage
                    (n,) float64 (share of the grid nodes within PEAK_REGION_RADIUS_MM of the plate centre with
                    data; QA only: whether a frame's peak was measured is peak/measured)
  /xdmf             nodes_xy_mm (ny·nx, 2), quads (M, 4), z_mm/<i> (ny, nx) virtual views of grid/z_mm[i]: what
                    the XDMF sidecar (`write_xdmf`, ParaView) points at; absent in older files
  grid/z_mm has HDF5 dimension scales: frames/index, grid/y_mm, grid/x_mm
  grid/* (but x_mm, y_mm) and points/* (but offsets) are compressed: byte shuffle, then a zlib stream (level 1)
  /summary          attrs: flat_rms_mm (RMS of w over the first frame), n_tracks_first_frame, clamp_centre_x_mm,
                    clamp_centre_y_mm, clamp_radius_mm (circle through the outermost first-frame points),
                    punch_axis_x_mm, punch_axis_y_mm (median of the per-frame centres), n_out_of_range_total;
                    reference_order_from ("projector table" or "gray code at rest"), reference_code_points,
                    reference_code_compared, reference_code_agreement (the code's check against the table's match,
                    docs/procam.md §5; 0, 0, NaN without a code; absent in older files)
"""

from __future__ import annotations

import contextlib
import math
from collections import defaultdict, deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import h5py
import numpy as np

from fringelab.formats.atomic import FlushBehind, atomic_path, commit_partial, partial_path

try:  # ISA-L's deflate makes the zlib streams that HDF5's deflate filter reads about 7 times faster than zlib
    from isal.isal_zlib import compress as deflate
except ImportError:  # a platform without its wheels: the same streams, slower
    from zlib import compress as deflate
from fringelab.formats.hdf5 import (
    SCHEMA_VERSION,
    FrameCache,
    ResultReader,
    file_key,
    open_read_only,
    path_key,
    require_schema,
    unit_dataset,
)

# MISSING_REASONS is re-exported for the API (it reads results through this module only).
from fringelab.science.coverage import MISSING_DESCRIPTIONS
from fringelab.science.coverage import MISSING_REASONS as MISSING_REASONS
from fringelab.science.fields import Grid, Peak
from fringelab.science.peaks import PUNCH_RADIUS_MM, PeakMeasurement, peak_measurement

if TYPE_CHECKING:
    from fringelab.science.topography import FrameMeasurement

TOPOGRAPHY_SCHEMA = "fringelab.topography"
# The region around the plate centre whose measured share qa/peak_region_coverage records (QA; the rule of a
# measured peak is `science.peaks`, stored as peak/measured).
PEAK_REGION_RADIUS_MM = 40.0
# Storage of the result: the compressed datasets' zlib level (with the byte shuffle), the points' chunk (rows), how
# many frames of the per-frame columns are buffered before they are written, and the writer's compression threads.
GZIP_LEVEL = 1
POINTS_CHUNK_ROWS = 65536
COLUMN_FLUSH_FRAMES = 1024
WRITER_THREADS = 2
MAX_WRITES_IN_FLIGHT = 16
# The XDMF views are made XDMF_VIEW_FRAMES frames at a time (made one by one while the file grows, they cost ~4
# times more; all at the close, they would wait for the last frame).
XDMF_VIEW_FRAMES = 32


# --------------------------------------------------------------------------------------------------------------
# The topography result


Growth = Literal["column", "points", "grid", "axis"]


@dataclass(frozen=True)
class DatasetLayout:
    """One dataset of the topography result, declared: where it is, what it holds and how it grows.

    grows: "column", one value a frame (chunks of 1024); "points", one row an edge point (chunks of
    POINTS_CHUNK_ROWS, compressed); "grid", one (ny, nx) slice a frame (one chunk a frame, compressed, NaN where
    not written); "axis", not at all (the grid's own coordinates, `Grid.<name>`, stored as they are: dtype
    None). initial_rows: rows it starts with (points/offsets starts with its 0).
    """

    path: str
    dtype: Any
    unit: str
    description: str
    grows: Growth = "column"
    initial_rows: int = 0

    @property
    def name(self) -> str:
        return self.path.rsplit("/", 1)[1]


def topography_layout() -> tuple[DatasetLayout, ...]:
    """Every dataset of a topography result in the order they are made (the module docstring describes them)."""
    column: Growth = "column"
    points: Growth = "points"
    grid: Growth = "grid"
    f64, i64, f32, i32 = np.float64, np.int64, np.float32, np.int32
    return (
        DatasetLayout("frames/index", i64, "1", "frame index in the recording"),
        DatasetLayout("frames/camera_frame", i64, "1",
                      "frame number as the camera counts it (a .cine counts from its trigger frame 0)"),
        DatasetLayout("frames/time_s", f64, "s",
                      "time of the frame (frames.csv, else the recording's time stamps; see time_source)"),
        DatasetLayout("frames/punch_displacement_mm", f64, "mm", "punch displacement (frames.csv)"),
        DatasetLayout("frames/force_kN", f64, "kN", "punch force (frames.csv)"),
        DatasetLayout("points/offsets", i64, "1", "frame i's points are rows offsets[i]:offsets[i+1]", column, 1),
        DatasetLayout("points/x_mm", f32, "mm", "X of each edge point", points),
        DatasetLayout("points/y_mm", f32, "mm", "Y of each edge point", points),
        DatasetLayout("points/z_mm", f32, "mm", "Z of each edge point (the deflection is z − z_flat_mm)", points),
        DatasetLayout("points/edge", i32, "1", "edge index k in the projector table", points),
        DatasetLayout("points/line", i32, "1", "scan line (image row for axis 'rows', column for 'cols')", points),
        DatasetLayout("points/sigma_w_mm", f32, "mm",
                      "standard deviation of the point's height (edge noise, projector table)", points),
        DatasetLayout("grid/x_mm", None, "mm", "X of the grid nodes", "axis"),
        DatasetLayout("grid/y_mm", None, "mm", "Y of the grid nodes", "axis"),
        DatasetLayout("grid/z_mm", f32, "mm", "gridded Z per frame [frame, iy, ix], NaN outside the data", grid),
        DatasetLayout("grid/sigma_w_mm", f32, "mm",
                      "standard deviation of the gridded height [frame, iy, ix] (its corners' σ interpolated)", grid),
        DatasetLayout("peak/w_mm", f64, "mm", "largest deflection w = z − z_flat of the grid"),
        DatasetLayout("peak/x_mm", f64, "mm", "X of the largest deflection"),
        DatasetLayout("peak/y_mm", f64, "mm", "Y of the largest deflection"),
        DatasetLayout("peak/centre_x_mm", f64, "mm", "X of the centroid of the area above half the peak"),
        DatasetLayout("peak/centre_y_mm", f64, "mm", "Y of the centroid of the area above half the peak"),
        DatasetLayout("peak/measured", np.int8, "1",
                      "1: the peak was measured (data on all sides of the maximum within radius_mm), 0: w_mm is only "
                      "a lower bound"),
        DatasetLayout("peak/missing_nodes", i32, "1",
                      "plate grid nodes within radius_mm of the maximum without data (−1: none at all)"),
        DatasetLayout("qa/n_points", i64, "1", "3-D points of the frame"),
        DatasetLayout("qa/n_tracks", i64, "1", "tracked (edge, line) points, with or without Z"),
        DatasetLayout("qa/n_ended", i64, "1", "tracks that ended at this frame"),
        DatasetLayout("qa/n_out_of_range", i64, "1", "tracked points beyond the calibrated Z range (masked)"),
        DatasetLayout("qa/n_unmatched", i64, "1", "edge points that belong to no track"),
        DatasetLayout("qa/edge_noise_px", f64, "px", "edge-location noise estimate"),
        DatasetLayout("qa/measured_fraction", f64, "1", "measured area / area of the plate the reference frame sees"),
        DatasetLayout("qa/visible_area_mm2", f64, "mm2", "area of the plate the reference frame sees"),
        DatasetLayout("qa/measured_area_mm2", f64, "mm2", "area of that plate measured in this frame"),
        *(DatasetLayout(f"qa/missing_{name}_mm2", f64, "mm2", f"area not measured: {MISSING_DESCRIPTIONS[name]}")
          for name in MISSING_REASONS),
        DatasetLayout("qa/n_order_conflicts", i64, "1",
                      "conflicts between the sources of the fringe order (masked, never guessed)"),
        DatasetLayout("qa/n_order_unresolved", i64, "1", "edge points whose order no anchor reaches (masked)"),
        DatasetLayout("qa/n_temporal_jumps", i64, "1",
                      "points whose change of height from the frame before departs from their neighbouring edges' "
                      "by more than 3/4 of a stripe step (a cross-check of the order); -1: not checked (the first "
                      "frame, a frame after a gap)"),
        DatasetLayout("qa/peak_region_coverage", f64, "1",
                      "share of the grid nodes around the punch (attrs x_mm, y_mm, radius_mm) with data; NaN where "
                      "the region is unknown"),
        DatasetLayout("qa/grid_coverage", f64, "1", "grid nodes with data / those of the first frame"),
    )  # fmt: skip


def _create_dataset(file: h5py.File, spec: DatasetLayout, grid: Grid) -> h5py.Dataset:
    """Make one declared dataset (empty, or the grid's coordinates) with its unit and description."""
    group_name, name = spec.path.rsplit("/", 1)
    group = file.require_group(group_name)
    described = {"unit": spec.unit, "description": spec.description}
    if spec.grows == "axis":
        return unit_dataset(group, name, getattr(grid, name), **described)
    if spec.grows == "column":
        rows = np.zeros(spec.initial_rows, spec.dtype)
        return unit_dataset(group, name, rows, maxshape=(None,), chunks=(1024,), **described)
    compressed: dict[str, Any] = {"compression": "gzip", "compression_opts": GZIP_LEVEL, "shuffle": True}
    if spec.grows == "points":
        rows = np.zeros(0, spec.dtype)
        return unit_dataset(group, name, rows, maxshape=(None,), chunks=(POINTS_CHUNK_ROWS,), **compressed, **described)
    ny, nx = grid.shape
    return unit_dataset(group, name, np.zeros((0, ny, nx), spec.dtype), maxshape=(None, ny, nx), chunks=(1, ny, nx),
                        fillvalue=np.nan, **compressed, **described)  # fmt: skip


# The points' columns and what each is stored as (the writer buffers them by these names).
_POINT_DTYPES = {spec.name: spec.dtype for spec in topography_layout() if spec.grows == "points"}


class TopographyWriter:
    """Streams a topography result into HDF5, one frame at a time (memory does not grow with the frame count).

    Use as a context manager: the file is written under a temporary name and renamed into place by `close()`
    after the summary; on an exception it is removed. threads: how many threads compress what comes unpacked
    (0: the calling thread does).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        grid: Grid,
        max_edge_mm: float,
        z_flat_mm: float,
        axis: str,
        attrs: dict[str, Any],
        calibration_attrs: dict[str, Any],
        peak_region_mm: tuple[float, float, float] | None = None,
        plate_nodes: np.ndarray | None = None,
        punch_radius_mm: float = PUNCH_RADIUS_MM,
        threads: int = WRITER_THREADS,
    ) -> None:
        self.path = Path(path)
        # The plate as the reference frame measured it (None: as the first frame written does), for the rule of a
        # measured peak (`science.peaks`).
        self._plate_nodes = plate_nodes
        self._punch_radius_mm = punch_radius_mm
        # The largest peak of the frames whose peak was measured (NaN: none): the run's headline peak.
        self.max_measured_peak_w_mm = float("nan")
        # Grid nodes of the region around the punch (X, Y, radius), where the peak is: whether a frame measured it.
        self._peak_nodes: np.ndarray | None = None
        if peak_region_mm is not None and all(np.isfinite(peak_region_mm)):
            px, py, radius = peak_region_mm
            gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
            self._peak_nodes = np.hypot(gx - px, gy - py) <= radius
            if not np.any(self._peak_nodes):
                self._peak_nodes = None
        self._temp = partial_path(self.path)
        self.grid = grid
        self.z_flat_mm = z_flat_mm
        self._n = 0
        self._n_points = 0
        self._first_coverage_nodes: int | None = None
        # Buffered until whole chunks (points) or COLUMN_FLUSH_FRAMES frames (the per-frame columns) can be written;
        # compression runs in threads, the writes on this thread in order, at most MAX_WRITES_IN_FLIGHT behind.
        self._points: dict[str, list[np.ndarray]] = {name: [] for name in _POINT_DTYPES}
        self._points_buffered = 0
        self._columns: dict[str, list[Any]] = defaultdict(list)
        self._columns_written = 0
        self._writes: deque[tuple[Any, tuple[Any, ...]]] = deque()
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="topography-writer") if threads > 0 else None
        self._datasets: dict[str, h5py.Dataset] = {}
        self._rows_reserved: dict[str, int] = {}  # rows each growing dataset has room for (`_reserved`)
        file = self._file = h5py.File(self._temp, "w")
        self._flush_behind = FlushBehind(self._temp)
        file.attrs["schema"] = TOPOGRAPHY_SCHEMA
        file.attrs["schema_version"] = SCHEMA_VERSION
        file.attrs["created_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        file.attrs["length_unit"] = "mm"
        file.attrs["object_frame"] = "X, Y in the plate plane, +Z toward the camera (docs/method.md §2)"
        file.attrs["z_flat_mm"] = z_flat_mm
        file.attrs["grid_step_mm"] = grid.step_mm
        file.attrs["grid_max_edge_mm"] = max_edge_mm
        file.attrs["axis"] = axis
        for key, value in attrs.items():
            file.attrs[key] = value
        calibration = file.create_group("calibration")
        for key, value in calibration_attrs.items():
            calibration.attrs[key] = value
        for spec in topography_layout():
            _create_dataset(file, spec, grid)
        self._xdmf_views = _start_xdmf_views(file, grid)
        self._views_made = 0
        self.max_edge_mm = max_edge_mm
        # Dimension scales: tools that read HDF5 generically (h5py, HDFView, xarray/h5netcdf) see z_mm's axes.
        grid_group = file["grid"]
        for dim, scale, label in ((0, file["frames/index"], "frame"), (1, grid_group["y_mm"], "y_mm"),
                                  (2, grid_group["x_mm"], "x_mm")):  # fmt: skip
            scale.make_scale(label)
            for gridded in (grid_group["z_mm"], grid_group["sigma_w_mm"]):
                gridded.dims[dim].attach_scale(scale)
                gridded.dims[dim].label = label
        for name in ("peak/measured", "peak/missing_nodes"):
            file[name].attrs["radius_mm"] = punch_radius_mm
        if peak_region_mm is not None:
            for key, value in zip(("x_mm", "y_mm", "radius_mm"), peak_region_mm, strict=True):
                file["qa/peak_region_coverage"].attrs[key] = float(value)

    def __enter__(self) -> TopographyWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self.abort()

    def append(
        self,
        measurement: FrameMeasurement,
        z_grid_mm: np.ndarray | None,
        peak: Peak,
        *,
        log: tuple[float, float, float],
        camera_frame: int | None = None,
        sigma_grid_mm: np.ndarray | None = None,
        packed: PackedGrids | None = None,
    ) -> None:
        """Add one frame: its points, grid and σ grid (NaN: not known), peak, test-log row (time_s,
        punch_displacement_mm, force_kN), QA, and its number as the camera counts it (default: its index).
        packed: the two grids already as stored (`pack_grids` of them, e.g. by the worker that measured the frame;
        the grids are then not needed); otherwise they are packed here, in the writer's threads."""
        if packed is None:
            if z_grid_mm is None:
                raise ValueError("z_grid_mm: a grid is needed unless the grids come packed")
            sigma = np.full(self.grid.shape, np.nan) if sigma_grid_mm is None else sigma_grid_mm
            grids: PackedGrids | Future[PackedGrids] = self._submit(pack_grids, z_grid_mm, sigma)
        else:
            grids = packed
        self._queue_write(self._write_grids, self._n, grids)
        self._flush_behind.poke()
        points = measurement.points_obj_mm
        sigma_points = measurement.sigma_z_mm if measurement.sigma_z_mm is not None else np.full(len(points), np.nan)
        for name, values in (
            ("x_mm", points[:, 0]), ("y_mm", points[:, 1]), ("z_mm", points[:, 2]), ("edge", measurement.k),
            ("line", measurement.line), ("sigma_w_mm", sigma_points),
        ):  # fmt: skip
            self._points[name].append(np.asarray(values, _POINT_DTYPES[name]))
        self._n_points += len(points)
        self._points_buffered += len(points)
        while self._points_buffered >= POINTS_CHUNK_ROWS:
            self._flush_points(POINTS_CHUNK_ROWS)
        finite = packed.z_finite if packed is not None else np.isfinite(np.asarray(z_grid_mm))
        nodes = int(np.count_nonzero(finite))
        if self._first_coverage_nodes is None:
            self._first_coverage_nodes = max(nodes, 1)
        if self._plate_nodes is None:
            self._plate_nodes = np.array(finite, bool)
        peak_measured = peak_measurement(
            finite, self.grid, (peak.x_mm, peak.y_mm), plate_nodes=self._plate_nodes, radius_mm=self._punch_radius_mm
        )
        if peak_measured.measured and not peak.w_mm <= self.max_measured_peak_w_mm:
            self.max_measured_peak_w_mm = float(peak.w_mm)
        coverage = measurement.coverage
        peak_nodes = self._peak_nodes
        row: dict[str, Any] = {
            "frames/index": measurement.frame,
            "frames/camera_frame": measurement.frame if camera_frame is None else camera_frame,
            "frames/time_s": log[0],
            "frames/punch_displacement_mm": log[1],
            "frames/force_kN": log[2],
            "points/offsets": self._n_points,
            **{f"peak/{name}": getattr(peak, name) for name in ("w_mm", "x_mm", "y_mm", "centre_x_mm", "centre_y_mm")},
            "peak/measured": int(peak_measured.measured),
            "peak/missing_nodes": peak_measured.missing_nodes,
            "qa/n_points": len(points),
            "qa/n_tracks": measurement.n_tracks,
            "qa/n_ended": measurement.n_ended,
            "qa/n_out_of_range": measurement.n_out_of_range,
            "qa/n_unmatched": measurement.n_unmatched,
            "qa/edge_noise_px": measurement.edge_noise_px,
            "qa/grid_coverage": nodes / self._first_coverage_nodes,
            "qa/peak_region_coverage": np.mean(finite[peak_nodes]) if peak_nodes is not None else np.nan,
            "qa/n_order_conflicts": measurement.n_order_conflicts,
            "qa/n_order_unresolved": measurement.n_order_unresolved,
            "qa/n_temporal_jumps": measurement.temporal.n_jumps if measurement.temporal is not None else -1,
            "qa/measured_fraction": coverage.measured_fraction if coverage else np.nan,
            "qa/visible_area_mm2": coverage.visible_area_mm2 if coverage else np.nan,
            "qa/measured_area_mm2": coverage.measured_area_mm2 if coverage else np.nan,
        }
        for name in MISSING_REASONS:
            row[f"qa/missing_{name}_mm2"] = coverage.missing_mm2[name] if coverage else np.nan
        for name, value in row.items():
            self._columns[name].append(value)
        self._n += 1
        if self._n - self._columns_written >= COLUMN_FLUSH_FRAMES:
            self._flush_columns()
        if self._n - self._views_made >= XDMF_VIEW_FRAMES:
            self._make_views()

    def _make_views(self) -> None:
        _add_xdmf_views(self._xdmf_views, range(self._views_made, self._n), self.grid.shape)
        self._views_made = self._n

    def _dataset(self, name: str) -> h5py.Dataset:
        """The open dataset `name` (looking one up by name costs more than writing a frame's grid)."""
        dataset = self._datasets.get(name)
        if dataset is None:
            dataset = self._datasets[name] = self._file[name]
        return dataset

    def _submit(self, compress: Any, *args: Any) -> Any:
        return self._pool.submit(compress, *args) if self._pool is not None else compress(*args)

    # Writes happen on the calling thread, in the order they were queued; the threads only compress.
    def _queue_write(self, write: Any, *args: Any) -> None:
        self._writes.append((write, args))
        while len(self._writes) > MAX_WRITES_IN_FLIGHT:
            self._write_next()

    def _write_next(self) -> None:
        write, args = self._writes.popleft()
        write(*(arg.result() if isinstance(arg, Future) else arg for arg in args))

    def _reserved(self, name: str, rows: int) -> h5py.Dataset:
        """The dataset `name` with room for `rows` rows: it grows by doubling (asking h5py for a dataset's shape,
        or resizing it, costs more than writing a frame's chunk); `_finish_writes` cuts it to the rows written."""
        dataset = self._dataset(name)
        room = self._rows_reserved.get(name, 0)
        if room < rows:
            self._rows_reserved[name] = max(rows, 2 * room)
            dataset.resize(self._rows_reserved[name], axis=0)
        return dataset

    def _write_grids(self, i: int, packed: PackedGrids) -> None:
        for name, chunk in (("grid/z_mm", packed.z_mm), ("grid/sigma_w_mm", packed.sigma_w_mm)):
            self._reserved(name, i + 1).id.write_direct_chunk((i, 0, 0), chunk)

    def _flush_points(self, rows: int) -> None:
        """The first `rows` buffered points (a whole stored chunk, or the rest at the end) to the file."""
        start = self._n_points - self._points_buffered
        for name, pieces in self._points.items():
            buffered = np.concatenate(pieces) if len(pieces) != 1 else pieces[0]
            head, rest = buffered[:rows], buffered[rows:]
            self._points[name] = [rest] if len(rest) else []
            if rows == POINTS_CHUNK_ROWS:
                self._queue_write(self._write_points_chunk, name, start, self._submit(_packed_chunk, head))
            else:
                self._queue_write(self._write_points_tail, name, start, head)
        self._points_buffered -= rows

    def _write_points_chunk(self, name: str, start: int, chunk: bytes) -> None:
        self._reserved(f"points/{name}", start + POINTS_CHUNK_ROWS).id.write_direct_chunk((start,), chunk)

    def _write_points_tail(self, name: str, start: int, values: np.ndarray) -> None:
        self._reserved(f"points/{name}", start + len(values))[start : start + len(values)] = values

    def _flush_columns(self) -> None:
        first = self._columns_written
        for name, values in self._columns.items():
            dataset = self._dataset(name)
            offset = 1 if name == "points/offsets" else 0  # offsets start with a 0
            dataset.resize(offset + self._n, axis=0)
            dataset[offset + first : offset + self._n] = np.asarray(values, dataset.dtype)
            values.clear()
        self._columns_written = self._n

    def _finish_writes(self) -> None:
        if self._points_buffered:
            self._flush_points(self._points_buffered)
        while self._writes:
            self._write_next()
        for name, room in self._rows_reserved.items():
            rows = self._n if name.startswith("grid/") else self._n_points
            if room != rows:
                self._dataset(name).resize(rows, axis=0)
        self._flush_columns()
        self._make_views()

    def close(self, summary: dict[str, Any]) -> Path:
        """Write the summary attributes, close the file and move it into place."""
        self._finish_writes()
        if self._pool is not None:
            self._pool.shutdown()
        file = self._file
        file.attrs["n_frames"] = self._n
        group = file.require_group("summary")
        for key, value in summary.items():
            group.attrs[key] = value
        file.close()
        self._flush_behind.close()
        return commit_partial(self._temp, self.path)

    def abort(self) -> None:
        try:
            if self._pool is not None:
                self._pool.shutdown(cancel_futures=True)
            self._file.close()
        finally:
            with contextlib.suppress(OSError):  # the file is removed: whether it reached the disk does not matter
                self._flush_behind.close()
            self._temp.unlink(missing_ok=True)


@dataclass(frozen=True)
class PackedGrids:
    """A frame's grid/z_mm and grid/sigma_w_mm as their stored HDF5 chunks (`pack_grids`), and where Z has data
    (ny, nx) bool (the frame's QA)."""

    z_mm: bytes
    sigma_w_mm: bytes
    z_finite: np.ndarray


def pack_grids(z_grid_mm: np.ndarray, sigma_grid_mm: np.ndarray) -> PackedGrids:
    """A frame's gridded Z and σ (ny, nx) as the result file stores them (float32, one chunk each, through the
    datasets' filters: byte shuffle, then zlib level 1): a worker packs the frames it measured, in parallel, and
    the writer stores the chunks as they are (`TopographyWriter.append(packed=...)`). The values read back are
    those of the grids given, whoever packed them."""
    return PackedGrids(
        z_mm=_packed_chunk(z_grid_mm), sigma_w_mm=_packed_chunk(sigma_grid_mm), z_finite=np.isfinite(z_grid_mm)
    )


def _packed_chunk(values: np.ndarray) -> bytes:
    """A whole chunk of a dataset created with shuffle=True, compression="gzip", compression_opts=1, as the HDF5
    filters would store it (the shuffle filter groups the bytes by their place in the item, then a zlib stream of
    them, level 1: ISA-L's, a little larger than zlib's and read by the same inflate), in float32 for floats and as
    given for integers."""
    array = np.ascontiguousarray(values, np.float32 if values.dtype.kind == "f" else values.dtype)
    shuffled = array.view(np.uint8).reshape(-1, array.dtype.itemsize).T.tobytes()
    return deflate(shuffled, GZIP_LEVEL)


XDMF_GROUP = "xdmf"


def _start_xdmf_views(file: h5py.File, grid: Grid) -> h5py.Group:
    """What an XDMF sidecar points at: the grid nodes (N, 2) and its quads (M, 4) once, and a group that takes a
    view of each frame's grid (`_add_xdmf_views`), since XDMF readers without hyperslab support (meshio) need one
    dataset per time step."""
    group = file.create_group(XDMF_GROUP)
    group.attrs["description"] = "views of /grid for the XDMF sidecar (ParaView); no data of their own"
    ny, nx = grid.shape
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    unit_dataset(group, "nodes_xy_mm", np.column_stack([gx.ravel(), gy.ravel()]), unit="mm",
                 description="grid nodes (ny·nx, 2), row-major as grid/z_mm[i].ravel()")  # fmt: skip
    node = np.arange(ny * nx).reshape(ny, nx)
    quads = np.column_stack(
        [node[:-1, :-1].ravel(), node[:-1, 1:].ravel(), node[1:, 1:].ravel(), node[1:, :-1].ravel()]
    )
    unit_dataset(group, "quads", quads.astype(np.int64), unit="1", description="node indices of each grid cell")
    return group.create_group("z_mm")


def _add_xdmf_views(views: h5py.Group, frames: range, shape: tuple[int, int]) -> None:
    """The views of frames `frames`: each a virtual dataset (ny, nx) of grid/z_mm[i] (no copy)."""
    source = h5py.VirtualSource(".", "grid/z_mm", shape=(frames.stop, *shape), dtype=np.float32)
    for i in frames:
        layout = h5py.VirtualLayout(shape=shape, dtype=np.float32)
        layout[:, :] = source[i, :, :]
        views.create_virtual_dataset(f"{i:06d}", layout, fillvalue=np.nan)


def _data_item(dimensions: str, number_type: str, precision: int, where: str) -> str:
    from xml.sax.saxutils import escape

    return (
        f'<DataItem Dimensions="{dimensions}" NumberType="{number_type}" Precision="{precision}" Format="HDF">'
        f"{escape(where)}</DataItem>"
    )


def write_xdmf(result_path: str | Path, xdmf_path: str | Path | None = None) -> Path:
    """An XDMF 3 sidecar (default `<result stem>.xdmf` beside it) so ParaView (File > Open, "Xdmf3 Reader") and
    meshio open a topography result directly: a temporal collection of the grid surface (quads on the X, Y
    nodes) with node data z_mm per frame, at time_s where logged, else the frame index. The sidecar names the
    result file relatively, so keep the two together. Results written before the views existed are refused
    with what to do."""
    result_path = Path(result_path)
    xdmf_path = result_path.with_suffix(".xdmf") if xdmf_path is None else Path(xdmf_path)
    with TopographyResult(result_path) as result:
        if XDMF_GROUP not in result.file:
            raise ValueError(f"{result_path.name}: written before XDMF views existed; run the topography again")
        ny, nx = result.grid.shape
        n_nodes, n_quads = ny * nx, int(result.file[f"{XDMF_GROUP}/quads"].shape[0])
        times = result.column("frames/time_s")
        name = result_path.name
        steps = []
        for i, frame in enumerate(result.frames):
            time = float(times[i]) if np.isfinite(times[i]) else float(frame)
            steps.append(
                f'''      <Grid Name="frame {int(frame)}" GridType="Uniform">
        <Time Value="{time!r}"/>
        <xi:include xpointer="xpointer(//Grid[@Name='surface']/*[self::Topology or self::Geometry])"/>
        <Attribute Name="z_mm" AttributeType="Scalar" Center="Node">
          {_data_item(f"{ny} {nx}", "Float", 4, f"{name}:/{XDMF_GROUP}/z_mm/{i:06d}")}
        </Attribute>
      </Grid>'''
            )
    text = f'''<?xml version="1.0"?>
<Xdmf xmlns:xi="http://www.w3.org/2001/XInclude" Version="3.0">
  <Domain>
    <Grid Name="surface" GridType="Uniform">
      <Topology TopologyType="Quadrilateral" NumberOfElements="{n_quads}">
        {_data_item(f"{n_quads} 4", "Int", 8, f"{name}:/{XDMF_GROUP}/quads")}
      </Topology>
      <Geometry GeometryType="XY">
        {_data_item(f"{n_nodes} 2", "Float", 8, f"{name}:/{XDMF_GROUP}/nodes_xy_mm")}
      </Geometry>
    </Grid>
    <Grid Name="z_mm over time" GridType="Collection" CollectionType="Temporal">
{chr(10).join(steps)}
    </Grid>
  </Domain>
</Xdmf>
'''
    with atomic_path(xdmf_path) as temp:
        temp.write_text(text)
    return xdmf_path


GRID_BUDGET_NODES = 250  # per side: a 250 × 250 float32 frame is 250 kB, what a browser redraws smoothly


class ResultUnavailable(ValueError):
    """A result file is missing, unreadable or incomplete; the message says which and what to do."""


class FrameNotInResult(ResultUnavailable):
    """The frame asked for was not computed."""


class OutsideGrid(ResultUnavailable):
    """A point, line or window lies outside the result's grid."""


@dataclass(frozen=True)
class GridCut:
    """A frame's deflection w = z − z_flat on (part of) the grid: w_mm (ny, nx) float32, NaN where no data;
    x_mm (nx,), y_mm (ny,) the node (or block-centre) coordinates; step: grid nodes per returned node."""

    frame: int
    x_mm: np.ndarray
    y_mm: np.ndarray
    w_mm: np.ndarray
    step: int


class TopographyResult(ResultReader):
    """A topography result file opened read-only: the one reader, for the API, the worker and scripts.

    Reads are windowed: one frame's grid (or a window of it), one frame's points, the 2 × 2 nodes around a point
    in every frame; memory does not grow with the number of frames. Use as a context manager or call `close()`.
    Frame positions i are 0..n_frames−1 (the order in the file); `frames` holds their recording indices, and the
    methods taking `frame` name a frame by that index. Raises ResultUnavailable (a ValueError) for a file that is
    not a complete result.
    """

    def __init__(self, path: str | Path, *, frame_cache: FrameCache | None = None) -> None:
        self.path = Path(path)
        # Whole frames of the grids (one stored chunk each) and the header come from `frame_cache` when one is
        # given (the API's), by the identity of the file at `path`; the file is then opened only to read what is
        # not kept (a profile of frames read before opens nothing).
        self._frame_cache = frame_cache
        self._open: h5py.File | None = None
        if frame_cache is None:
            self._open = open_read_only(self.path, ResultUnavailable)
        self._file_key = path_key(self.path, ResultUnavailable) if frame_cache is not None else None
        try:
            self.grid = Grid(x_mm=self._header("grid/x_mm"), y_mm=self._header("grid/y_mm"))
            self.frames = self._header("frames/index")
            self.z_flat_mm = float(self._header("z_flat_mm"))
        except ValueError as error:
            self.close()
            raise ResultUnavailable(str(error)) from None
        except KeyError as error:
            self.close()
            raise ResultUnavailable(f"{self.path.name} is not a complete topography result ({error})") from None

    @property
    def file(self) -> h5py.File:
        """The open file (opened on first use when a frame cache is given: it must be the file the cache's keys
        name, or ResultUnavailable)."""
        if self._open is None:
            opened = open_read_only(self.path, ResultUnavailable)
            if file_key(opened) != self._file_key:
                opened.close()
                raise ResultUnavailable(f"{self.path.name} was written again while it was read; ask again")
            self._open = opened
        return self._open

    @file.setter
    def file(self, opened: h5py.File) -> None:
        self._open = opened

    def close(self) -> None:
        if self._open is not None:
            self._open.close()

    def _has(self, name: str) -> bool:
        """Whether the file holds the dataset `name` (kept with the header when a frame cache is given)."""
        if self._frame_cache is None:
            return name in self.file
        return bool(self._frame_cache.get_or_read((self._file_key, "has", name), lambda: np.asarray(name in self.file)))

    @property
    def x_mm(self) -> np.ndarray:
        return self.grid.x_mm

    @property
    def y_mm(self) -> np.ndarray:
        return self.grid.y_mm

    def position(self, frame: int) -> int:
        """The position in the file of recording frame `frame`; FrameNotInResult if it was not computed."""
        found = np.flatnonzero(self.frames == frame)
        if found.size == 0:
            span = f"{self.frames[0]}..{self.frames[-1]}" if self.frames.size else "none"
            raise FrameNotInResult(f"frame {frame} is not in this result (frames {span})")
        return int(found[0])

    def column(self, name: str) -> np.ndarray:
        """A per-frame dataset, e.g. "frames/time_s", "peak/w_mm", "qa/n_points" (NaN where a file lacks it;
        frames/camera_frame: the recording index in results written before the camera's numbering was kept)."""
        if name == "frames/camera_frame" and name not in self.file:
            return self.frames.copy()
        return self.file[name][()] if name in self.file else np.full(self.frames.shape, np.nan)

    @cached_property
    def offsets(self) -> np.ndarray:
        """Frame position i's points are rows offsets[i]:offsets[i + 1] of the /points datasets."""
        return self.file["points/offsets"][()]

    @property
    def camera_frames(self) -> np.ndarray:
        """Frame numbers as the camera counts them (n,) (a .cine from its trigger; else the recording index)."""
        return self.column("frames/camera_frame")

    @property
    def time_source(self) -> str:
        """Where frames/time_s came from ("frames.csv", the recording's time stamps, "none"); "" in older files."""
        return str(self.file.attrs.get("time_source", ""))

    def points(self, i: int) -> np.ndarray:
        """The 3-D points (N, 3) of frame position i."""
        lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
        return np.column_stack([self.file[f"points/{axis}_mm"][lo:hi] for axis in "xyz"]).astype(np.float64)

    def point_labels(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Edge index and scan line (N,) of the points of frame position i."""
        lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
        return self.file["points/edge"][lo:hi], self.file["points/line"][lo:hi]

    def _header(self, name: str) -> np.ndarray:
        """The dataset (or root attribute) `name` that every reader of the file reads first, its schema checked:
        through `frame_cache` when one is given, so that a file the process has read before is checked and read
        once (reading them was most of a profile's cost once its frames were cached)."""

        def read() -> np.ndarray:
            require_schema(self.file, TOPOGRAPHY_SCHEMA, self.path, version_optional=True)
            return np.asarray(self.file[name][()] if "/" in name else self.file.attrs[name])

        return read() if self._frame_cache is None else self._frame_cache.get_or_read((self._file_key, name), read)

    def _stored_frame(self, name: str, i: int) -> np.ndarray:
        """Frame position i of the gridded dataset `name` as stored (float32, read-only when cached)."""
        if self._frame_cache is None:
            return self.file[name][i]
        return self._frame_cache.get_or_read((self._file_key, name, i), lambda: self.file[name][i])

    def z_grid(self, i: int) -> np.ndarray:
        """Gridded Z (ny, nx) of frame position i (NaN outside the data)."""
        return self._stored_frame("grid/z_mm", i).astype(np.float64)

    def sigma_points(self, i: int) -> np.ndarray | None:
        """σ_w (N,) of the points of frame position i; None for a file written before σ was stored."""
        if "points/sigma_w_mm" not in self.file:
            return None
        lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
        return self.file["points/sigma_w_mm"][lo:hi].astype(np.float64)

    def sigma_grid(self, i: int) -> np.ndarray | None:
        """σ_w (ny, nx) of the grid of frame position i; None for a file written before σ was stored."""
        if "grid/sigma_w_mm" not in self.file:
            return None
        return self._stored_frame("grid/sigma_w_mm", i).astype(np.float64)

    def w_grid(self, i: int) -> np.ndarray:
        """Gridded deflection w = z − z_flat (ny, nx) of frame position i."""
        return self.z_grid(i) - self.z_flat_mm

    def peak_measurements(self) -> list[PeakMeasurement | None]:
        """Per frame: whether its peak was measured and why not (`science.peaks`); None where the file does not
        say (written before peak/measured existed)."""
        if "peak/missing_nodes" not in self.file:
            return [None] * self.n_frames
        dataset = self.file["peak/missing_nodes"]
        radius = float(dataset.attrs.get("radius_mm", PUNCH_RADIUS_MM))
        return [PeakMeasurement(int(n), radius) for n in dataset[()]]

    def measured_peaks(self) -> np.ndarray:
        """Per frame: peak/w_mm where the peak was measured (or the file does not say), NaN where it is only a lower
        bound: what every per-frame peak curve, table and export shows as the peak."""
        return np.where(self.peak_measured() == 0.0, np.nan, self.column("peak/w_mm"))

    def peak_measured(self) -> np.ndarray:
        """Per frame: 1.0 where the peak was measured, 0.0 where peak/w_mm is a lower bound, NaN: unknown (a file
        written before peak/measured existed)."""
        if "peak/measured" not in self.file:
            return np.full(self.n_frames, np.nan)
        return self.file["peak/measured"][()].astype(np.float64)

    def coverage(self) -> dict[str, np.ndarray]:
        """Per frame: measured_fraction, visible_area_mm2, measured_area_mm2, missing_<reason>_mm2,
        n_order_conflicts, n_temporal_jumps and peak_region_coverage (float; NaN in files written before they
        existed, and for n_temporal_jumps where the frame was not cross-checked)."""
        names = ["measured_fraction", "visible_area_mm2", "measured_area_mm2", "n_order_conflicts", "n_temporal_jumps"]
        names += ["peak_region_coverage"]
        names += [f"missing_{name}_mm2" for name in MISSING_REASONS]
        qa = self.file.get("qa", {})  # a file may have no QA at all
        columns = {
            name: qa[name][()].astype(np.float64) if name in qa else np.full(self.n_frames, np.nan) for name in names
        }
        columns["n_temporal_jumps"][columns["n_temporal_jumps"] < 0] = np.nan
        return columns

    def summary(self) -> dict[str, Any]:
        """The /summary attributes as stored (NaN where a value was not measured)."""
        return dict(self.file["summary"].attrs) if "summary" in self.file else {}

    def grid_cut(
        self,
        frame: int,
        *,
        budget: int = GRID_BUDGET_NODES,
        window_mm: tuple[float, float, float, float] | None = None,
    ) -> GridCut:
        """w of one frame, block-averaged (NaN-aware) to at most `budget` nodes per side; `window_mm`
        (x_min, x_max, y_min, y_max) cuts a zoom window first, at full resolution when it fits the budget."""
        i = self.position(frame)
        ix = np.arange(self.x_mm.size)
        iy = np.arange(self.y_mm.size)
        if window_mm is not None:
            x_min, x_max, y_min, y_max = window_mm
            ix = np.flatnonzero((self.x_mm >= x_min) & (self.x_mm <= x_max))
            iy = np.flatnonzero((self.y_mm >= y_min) & (self.y_mm <= y_max))
            if ix.size == 0 or iy.size == 0:
                raise OutsideGrid(
                    f"the window holds no grid node; the grid spans X {self.x_mm[0]:g}..{self.x_mm[-1]:g} mm, "
                    f"Y {self.y_mm[0]:g}..{self.y_mm[-1]:g} mm"
                )
        rows, cols = slice(iy[0], iy[-1] + 1), slice(ix[0], ix[-1] + 1)
        w = self._stored_frame("grid/z_mm", i)[rows, cols].astype(np.float32) - np.float32(self.z_flat_mm)
        step = max(1, math.ceil(max(w.shape) / budget))
        return GridCut(
            frame=frame,
            x_mm=_block_mean(self.x_mm[cols][None, :], step)[0],
            y_mm=_block_mean(self.y_mm[rows][:, None], step)[:, 0],
            w_mm=_block_mean(w, step).astype(np.float32),
            step=step,
        )

    def profile(self, frames: list[int], line_mm: tuple[float, float, float, float], *, n_points: int) -> dict:
        """w along the segment (x0, y0) → (x1, y1) for each frame, bilinear between grid nodes (NaN when a
        neighbouring node has no data), with its σ_w sampled the same way (None for a file written before σ was
        stored); s_mm is the distance from (x0, y0)."""
        x0, y0, x1, y1 = line_mm
        t = np.linspace(0.0, 1.0, n_points)
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        weights = self._bilinear(x, y)
        has_sigma = self._has("grid/sigma_w_mm")
        profiles = []
        for frame in frames:
            i = self.position(frame)
            # Sampled as stored (float32, promoted by the float64 weights: the same values as converting first).
            z = self._stored_frame("grid/z_mm", i)
            sigma = self._stored_frame("grid/sigma_w_mm", i) if has_sigma else None
            profiles.append({"frame": frame, "w_mm": _sample(z, weights) - self.z_flat_mm,
                             "sigma_w_mm": None if sigma is None else _sample(sigma, weights)})  # fmt: skip
        return {"s_mm": t * math.hypot(x1 - x0, y1 - y0), "x_mm": x, "y_mm": y, "profiles": profiles}

    def history(self, x_mm: float, y_mm: float) -> np.ndarray:
        """w(t) at one object point over every frame of the result (bilinear; NaN where it has no data). Reads
        only the 2 × 2 nodes around the point from each frame; OutsideGrid for a point outside the grid."""
        return self._at_point("grid/z_mm", x_mm, y_mm) - self.z_flat_mm

    def sigma_history(self, x_mm: float, y_mm: float) -> np.ndarray | None:
        """σ_w(t) at one object point over every frame, sampled as `history` samples w; None for a file written
        before σ was stored."""
        return self._at_point("grid/sigma_w_mm", x_mm, y_mm) if "grid/sigma_w_mm" in self.file else None

    def _at_point(self, name: str, x_mm: float, y_mm: float) -> np.ndarray:
        (iy, ix, wy, wx) = self._bilinear(np.array([x_mm]), np.array([y_mm]))
        rows, cols = slice(int(iy[0]), int(iy[0]) + 2), slice(int(ix[0]), int(ix[0]) + 2)
        block = self.file[name][:, rows, cols].astype(np.float64)
        return (
            block[:, 0, 0] * (1 - wy[0]) * (1 - wx[0])
            + block[:, 0, 1] * (1 - wy[0]) * wx[0]
            + block[:, 1, 0] * wy[0] * (1 - wx[0])
            + block[:, 1, 1] * wy[0] * wx[0]
        )

    def _bilinear(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Lower-left node indices and fractional weights of points on the (regular, increasing) grid."""
        for name, values, axis in (("X", x, self.x_mm), ("Y", y, self.y_mm)):
            if np.any(values < axis[0]) or np.any(values > axis[-1]):
                raise OutsideGrid(f"{name} must lie within the grid, {axis[0]:g}..{axis[-1]:g} mm")
        fx = np.interp(x, self.x_mm, np.arange(self.x_mm.size, dtype=np.float64))
        fy = np.interp(y, self.y_mm, np.arange(self.y_mm.size, dtype=np.float64))
        ix = np.minimum(np.floor(fx).astype(int), max(self.x_mm.size - 2, 0))
        iy = np.minimum(np.floor(fy).astype(int), max(self.y_mm.size - 2, 0))
        return iy, ix, fy - iy, fx - ix


def _sample(z: np.ndarray, weights: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    iy, ix, wy, wx = weights
    return (
        z[iy, ix] * (1 - wy) * (1 - wx)
        + z[iy, ix + 1] * (1 - wy) * wx
        + z[iy + 1, ix] * wy * (1 - wx)
        + z[iy + 1, ix + 1] * wy * wx
    )


def _block_mean(values: np.ndarray, step: int) -> np.ndarray:
    """Mean over step × step blocks, ignoring NaN (a block without data stays NaN); the last blocks may be
    smaller."""
    if step == 1:
        return values
    ny, nx = values.shape
    pad_y, pad_x = (-ny) % step, (-nx) % step
    padded = np.pad(values.astype(np.float64), ((0, pad_y), (0, pad_x)), constant_values=np.nan)
    blocks = padded.reshape(padded.shape[0] // step, step, padded.shape[1] // step, step)
    finite = np.isfinite(blocks)
    count = finite.sum(axis=(1, 3))
    total = np.where(finite, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)

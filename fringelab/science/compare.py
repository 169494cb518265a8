"""Comparing a finite-element simulation with a measured topography: mapping, time alignment, sampling, differences.

Belongs here (pure numpy/SciPy, no files): putting a model (`fe_results.FEResults`, in its own frame and unit)
into the plate frame of the measurement (METHOD.md §2: X, Y in the plate plane, +Z toward the cameras, mm), the
choice of the model surface the cameras see, unfolding quarter and half models, pairing every test frame with
the simulation (by punch displacement, time or peak deflection), sampling the simulated deflection on the
measurement's grid and the per-frame differences. Every choice is a field of `MappingSettings`; those left None
are detected, and `Mapping` says which were and what was found. Not here: reading the files
(`fringelab.formats.simulations`), the comparison file (`fringelab.formats.comparison`).

Model frame → plate frame, in this order: scale to mm (length unit); rotate the model's out-of-plane axis onto Z
(x → (y, z, x), y → (z, x, y), a cyclic permutation, so still right-handed); if w_sign is −1, rotate 180° about X
((x, y, z) → (x, −y, −z)) so the deflection toward the cameras is +Z; unfold half or quarter models by mirroring
about the model's own X = 0 and/or Y = 0 planes; rotate about Z by rotation_deg; translate by origin_xy_mm.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from . import MeasurementError
from .fe_results import FEResults, solid_boundary_faces, triangles_of_faces
from .fields import Grid, rasterize_triangles

SYMMETRIES = ("none", "half-x", "half-y", "quarter")
LENGTH_UNITS = {"mm": 1.0, "m": 1000.0}
ALIGNMENTS = ("displacement", "time", "peak")
SURFACES = ("toward-cameras", "away", "mid")
AXES = ("x", "y", "z")
# Model length unit / symmetry candidates are accepted when the unfolded model's extent is within this factor of
# the measured plate's: a model of the right plate in the right unit is 1×; the next candidate is 2× (a half model
# taken as full) or 1000× (the other unit).
EXTENT_TOLERANCE = 1.6


class ComparisonError(MeasurementError):
    """The simulation cannot be compared with the measurement as set (the message names what to set)."""


# The messages here (and the simulation readers') name a setting by its command-line option; the dashboard's mapping
# form and the job spec name it as below. `in_form_terms` turns one into the other, so one message serves both.
FORM_TERMS: dict[str, str] = {
    "--normal-axis x|y|z": "“Normal axis” x, y or z",
    "--units mm|m": "“Units” mm or m",
    "--symmetry none|half-x|half-y|quarter": "“Symmetry” none, half-x, half-y or quarter",
    "--shell-thickness": "“Shell thickness (mm)”",
    "--punch-node ID": "“Punch node”",
    "--align displacement|time|peak": "“Time alignment” by displacement, time or peak",
    "--align displacement|time": "“Time alignment” by displacement or time",
    "--align time|peak": "“Time alignment” by time or peak",
    "--origin X,Y in mm": "“Origin x (mm)” and “Origin y (mm)”",
    "--rotation DEG": "“Rotation (°)”",
    "--time-offset S": "“Time offset (s)”",
}


def in_form_terms(message: str) -> str:
    """A message with the command-line options it names replaced by the mapping form's names of the settings.

    >>> in_form_terms("set the units (--units mm|m)")
    'set the units (“Units” mm or m)'
    """
    for option in sorted(FORM_TERMS, key=len, reverse=True):
        message = message.replace(option, FORM_TERMS[option])
    return message


@dataclass(frozen=True)
class MappingSettings:
    """How a model is put into the plate frame; None means: detect (see `map_model`).

    length_unit: "mm" or "m". symmetry: "none", "half-x" (the model is one side of X = 0), "half-y", "quarter".
    normal_axis: the model axis out of the plate ("x", "y", "z"). w_sign: +1 or −1, the sign that makes the
    deflection toward the cameras positive. origin_xy_mm: where the model's origin lies in the plate frame
    (None: the model's own punch axis goes on the measured punch axis, and the fit to the measurement refines it:
    a symmetric model's symmetry axis, a full model's centre of deflection at its first loaded state; (0, 0)
    keeps a model that is in plate coordinates where it is). rotation_deg: about Z, after unfolding.
    surface: which surface the cameras see: "toward-cameras" (the side +Z points to: the rear of the plate in the
    paper's set-up), "away", or "mid" (the shell mid-surface, no thickness offset). shell_thickness_mm: overrides
    the file's. punch_node: the node whose travel is the punch displacement (when the file has no punch curve).
    time_unit_s, force_unit_kN: override the file's (None: declared, else s and kN for mm models, N for m).
    time_offset_s: added to the simulation's times before aligning by time.
    """

    length_unit: str | None = None
    symmetry: str | None = None
    normal_axis: str | None = None
    w_sign: int | None = None
    origin_xy_mm: tuple[float, float] | None = None
    rotation_deg: float = 0.0
    surface: str = "toward-cameras"
    shell_thickness_mm: float | None = None
    time_unit_s: float | None = None
    force_unit_kN: float | None = None
    time_offset_s: float = 0.0

    def __post_init__(self) -> None:
        for name, allowed in (("length_unit", tuple(LENGTH_UNITS)), ("symmetry", SYMMETRIES), ("normal_axis", AXES)):
            value = getattr(self, name)
            if value is not None and value not in allowed:
                raise ValueError(f"{name}: expected one of {allowed}, got {value!r}")
        if self.w_sign not in (None, 1, -1):
            raise ValueError(f"w_sign: expected 1 or -1, got {self.w_sign!r}")
        if self.surface not in SURFACES:
            raise ValueError(f"surface: expected one of {SURFACES}, got {self.surface!r}")


@dataclass(frozen=True)
class PlateFrame:
    """What the measurement says about the plate: the punch axis, and the extent of the first frame's data
    (x_min, x_max, y_min, y_max in mm)."""

    axis_xy_mm: tuple[float, float]
    data_box_mm: tuple[float, float, float, float]

    @property
    def extent_mm(self) -> float:
        x0, x1, y0, y1 = self.data_box_mm
        return max(x1 - x0, y1 - y0)


@dataclass(frozen=True)
class Mapping:
    """A resolved mapping: every choice made, `detected` naming those that were detected rather than set."""

    length_unit: str
    symmetry: str
    normal_axis: str
    w_sign: int
    origin_xy_mm: tuple[float, float]
    rotation_deg: float
    surface: str
    shell_thickness_mm: float | None
    time_unit_s: float
    force_unit_kN: float
    time_offset_s: float
    detected: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    origin_on_axis: bool = False  # the origin was put on the measured punch axis (to be refined by `fit_origin`)

    def as_dict(self) -> dict[str, object]:
        return {
            "length_unit": self.length_unit, "symmetry": self.symmetry, "normal_axis": self.normal_axis,
            "w_sign": self.w_sign, "origin_xy_mm": list(self.origin_xy_mm), "rotation_deg": self.rotation_deg,
            "surface": self.surface, "shell_thickness_mm": self.shell_thickness_mm, "time_unit_s": self.time_unit_s,
            "force_unit_kN": self.force_unit_kN, "time_offset_s": self.time_offset_s,
            "detected": list(self.detected), "notes": list(self.notes), "origin_on_axis": self.origin_on_axis,
        }  # fmt: skip


_PERMUTATION = {"x": [1, 2, 0], "y": [2, 0, 1], "z": [0, 1, 2]}


def _oriented(xyz: np.ndarray, normal_axis: str, w_sign: int) -> np.ndarray:
    """Model axes rotated so the plate normal is Z and the deflection toward the cameras is +Z (no scale)."""
    out = xyz[:, _PERMUTATION[normal_axis]]
    if w_sign < 0:
        out = out * np.array([1.0, -1.0, -1.0])
    return out


@dataclass(frozen=True, eq=False)
class ModelSurface:
    """The model surface the cameras see, in the oriented model frame (model units, not yet unfolded).

    nodes (M,) positions into the model's nodes; triangles (T, 3) positions into `nodes`; offset_fraction: the
    shell offset is offset_fraction × thickness along the normal toward +Z (½ toward the cameras, −½ away, 0);
    thickness (M,) in model units (zeros for solids and point clouds)."""

    nodes: np.ndarray
    triangles: np.ndarray
    offset_fraction: float
    thickness: np.ndarray
    origin: str

    def normals(self, xyz: np.ndarray) -> np.ndarray:
        """Unit nodal normals (M, 3) of the surface at positions xyz (M, 3), oriented with n_z ≥ 0."""
        a, b, c = (xyz[self.triangles[:, i]] for i in range(3))
        face = np.cross(b - a, c - a)
        face *= np.where(face[:, 2:3] < 0, -1.0, 1.0)
        face = np.nan_to_num(face)  # a face with an eroded corner (NaN) adds nothing to its neighbours' normals
        nodal = np.zeros_like(xyz)
        for i in range(3):
            np.add.at(nodal, self.triangles[:, i], face)
        length = np.linalg.norm(nodal, axis=1, keepdims=True)
        return np.where(length > 0, nodal / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))


def model_surface(
    results: FEResults, oriented_xyz: np.ndarray, *, surface: str, thickness: float | None
) -> ModelSurface:
    """The surface of the model that the cameras see, from shells, the boundary of solids, or bare nodes.

    Shells: their nodes, offset by half the thickness toward (or away from) the cameras. Solids: the boundary
    faces lying across the normal (|n_z| > 0.7) on the cameras' side (their centre above the median of those
    faces) or the other. Bare nodes (the CSV): for each in-plane position the node nearest the cameras (or
    farthest), triangulated in the plane (Delaunay), without triangles much larger than the local node spacing.
    """
    from scipy.spatial import Delaunay

    sign = {"toward-cameras": 1.0, "away": -1.0, "mid": 0.0}[surface]
    if len(results.shells):
        tri = triangles_of_faces(results.shells)
        nodes, inverse = np.unique(tri, return_inverse=True)
        tri = inverse.reshape(tri.shape)
        if thickness is not None:
            t = np.full(len(nodes), float(thickness))
        elif results.shell_thickness is not None:
            t = np.nan_to_num(results.shell_thickness[nodes])
        else:
            t = np.zeros(len(nodes))
        return ModelSurface(nodes, tri, 0.5 * sign, t, "shells")
    if len(results.solids):
        faces = solid_boundary_faces(results.solids)
        tri = triangles_of_faces(faces)
        a, b, c = (oriented_xyz[tri[:, i]] for i in range(3))
        normal = np.cross(b - a, c - a)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        across = np.abs(normal[:, 2]) > 0.7
        if not np.any(across):
            raise ComparisonError(
                f"{results.source}: the solid mesh has no faces across the plate normal; set the normal axis"
            )
        centre_z = (a[:, 2] + b[:, 2] + c[:, 2]) / 3.0
        middle = np.median(centre_z[across])
        side = centre_z > middle if sign >= 0 else centre_z < middle
        if not np.any(across & side):
            side = np.ones_like(across)
        tri = tri[across & side]
        nodes, inverse = np.unique(tri, return_inverse=True)
        return ModelSurface(nodes, inverse.reshape(tri.shape), 0.0, np.zeros(len(nodes)), "solid boundary")
    xyz = oriented_xyz
    span = float(np.ptp(xyz[:, :2], axis=0).max()) or 1.0
    key = np.round(xyz[:, :2] / (1e-6 * span)).astype(np.int64)
    # Per in-plane position, the node nearest the cameras (farthest for "away") comes first.
    order = np.lexsort((-xyz[:, 2] if sign >= 0 else xyz[:, 2], key[:, 1], key[:, 0]))
    sorted_key = key[order]
    first = np.ones(len(order), bool)
    first[1:] = np.any(sorted_key[1:] != sorted_key[:-1], axis=1)
    nodes = np.sort(order[first])
    if len(nodes) < 3:
        raise ComparisonError(f"{results.source}: fewer than 3 nodes; no surface to compare with")
    try:
        tri = Delaunay(xyz[nodes, :2]).simplices.astype(np.int64)
    except Exception as error:  # Qhull's error for collinear or degenerate points
        raise ComparisonError(f"{results.source}: the nodes span no surface ({type(error).__name__})") from None
    # A triangle is kept when no side is longer than 4 × the nearest-neighbour spacing at its corners: graded
    # meshes keep their coarse triangles, holes and re-entrant outlines stay open.
    from scipy.spatial import cKDTree

    plane = xyz[nodes, :2]
    spacing = cKDTree(plane).query(plane, k=2)[0][:, 1]
    corners = plane[tri]
    side = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)
    keep = np.all(side <= 4.0 * spacing[tri].max(axis=1, keepdims=True), axis=1)
    return ModelSurface(nodes, tri[keep], 0.0, np.zeros(len(nodes)), "nodes (triangulated)")


def _unfolds(symmetry: str) -> list[tuple[float, float]]:
    """The mirror images (sign of X, sign of Y) that make up the whole plate."""
    return {"none": [(1.0, 1.0)], "half-x": [(1.0, 1.0), (-1.0, 1.0)], "half-y": [(1.0, 1.0), (1.0, -1.0)],
            "quarter": [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)]}[symmetry]  # fmt: skip


def _touches(lo: float, hi: float, tol: float) -> bool:
    return (lo > -tol and hi > tol) or (hi < tol and lo < -tol)


@dataclass(frozen=True, eq=False)
class MappedModel:
    """A model in the plate frame: what `map_model` returns, and what samples its states on a grid."""

    results: FEResults
    mapping: Mapping
    surface: ModelSurface
    reference_mm: np.ndarray  # (M, 3) the surface nodes' reference positions, oriented and scaled (not unfolded)
    # Deflected surfaces of the last states read (they do not depend on the origin or rotation, so copies of the
    # model with another origin share it).
    _surfaces: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    def with_origin(self, origin_xy_mm: tuple[float, float], *, note: str | None = None) -> MappedModel:
        """The same model with another origin (and a note on why)."""
        notes = self.mapping.notes + ((note,) if note else ())
        mapping = replace(self.mapping, origin_xy_mm=(float(origin_xy_mm[0]), float(origin_xy_mm[1])), notes=notes)
        return replace(self, mapping=mapping)

    def _to_plate_xy(self, xy: np.ndarray) -> np.ndarray:
        angle = np.deg2rad(self.mapping.rotation_deg)
        c, s = np.cos(angle), np.sin(angle)
        out = np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]])
        return out + np.asarray(self.mapping.origin_xy_mm)

    def surface_w(self, state: int) -> tuple[np.ndarray, np.ndarray]:
        """Deflected surface of one state before unfolding: xy (M, 2) in the oriented, scaled model frame and w (M,)."""
        surface = self._surfaces.get(state)
        if surface is None:  # the one made here is returned: another thread may drop it from the cache meanwhile
            while len(self._surfaces) >= 4:
                self._surfaces.pop(next(iter(self._surfaces)), None)
            surface = self._surfaces[state] = self._surface_w(state)
        return surface

    def _surface_w(self, state: int) -> tuple[np.ndarray, np.ndarray]:
        scale = LENGTH_UNITS[self.mapping.length_unit]
        u = _oriented(
            self.results.displacement(state)[self.surface.nodes], self.mapping.normal_axis, self.mapping.w_sign
        )
        current = self.reference_mm + scale * u
        fraction = self.surface.offset_fraction
        if fraction and np.any(self.surface.thickness > 0):
            thickness = scale * self.surface.thickness[:, None]
            ref_normals = self.surface.normals(self.reference_mm)
            cur_normals = self.surface.normals(current)
            face_ref = self.reference_mm + fraction * thickness * ref_normals
            face_cur = current + fraction * thickness * cur_normals
        else:
            face_ref, face_cur = self.reference_mm, current
        return face_cur[:, :2], face_cur[:, 2] - face_ref[:, 2]

    def peak_w_mm(self, state: int) -> float:
        """The largest simulated deflection of a state (over the surface nodes)."""
        return float(np.nanmax(self.surface_w(state)[1]))

    def sample(self, state: int, grid: Grid) -> np.ndarray:
        """The simulated deflection w (ny, nx) of one state on the grid (linear on the model's triangles, NaN
        outside the model)."""
        xy, w = self.surface_w(state)
        return self._rasterize(xy, w, grid)

    def sample_between(self, state_lo: int, fraction: float, grid: Grid) -> np.ndarray:
        """w (ny, nx) on the grid of the surface blended between two states node by node ((1 − f)·state_lo +
        f·(state_lo + 1) of positions and w): one rasterization, where `StateSampler.at` blends two grids. The
        same up to the in-plane motion between the states; for fitting, which samples a blend many times."""
        if fraction <= 0.0 or state_lo + 1 >= self.results.n_states:
            return self.sample(state_lo, grid)
        xy0, w0 = self.surface_w(state_lo)
        xy1, w1 = self.surface_w(state_lo + 1)
        return self._rasterize((1.0 - fraction) * xy0 + fraction * xy1, (1.0 - fraction) * w0 + fraction * w1, grid)

    def _rasterize(self, xy: np.ndarray, w: np.ndarray, grid: Grid) -> np.ndarray:
        # A triangle with a node the state does not have (an eroded element's, NaN) is a hole in that state.
        present = np.isfinite(w) & np.all(np.isfinite(xy), axis=1)
        triangles = self.surface.triangles[np.all(present[self.surface.triangles], axis=1)]
        corner_xy, corner_w = [], []
        for sx, sy in _unfolds(self.mapping.symmetry):
            plate_xy = self._to_plate_xy(xy * np.array([sx, sy]))
            corner_xy.append(plate_xy[triangles])
            corner_w.append(w[triangles])
        return rasterize_triangles(np.concatenate(corner_xy), np.concatenate(corner_w), grid)

    def footprint_xy_mm(self) -> np.ndarray:
        """The unfolded reference surface nodes (K, 2) in the plate frame."""
        xy = self.reference_mm[:, :2]
        return np.concatenate([self._to_plate_xy(xy * np.array(f)) for f in _unfolds(self.mapping.symmetry)])


def map_model(results: FEResults, plate: PlateFrame, settings: MappingSettings | None = None) -> MappedModel:
    """Put a model into the plate frame, detecting what `settings` leaves None (see `MappingSettings`).

    Detection: the normal axis is the model's axis of smallest extent (it must be under a tenth of the others:
    a plate); symmetry and length unit together, as the candidates (the model on one side of X = 0 or Y = 0 can
    be half or quarter; mm or m unless the file or the settings say) whose unfolded extent is nearest the
    measured plate's, within EXTENT_TOLERANCE; w_sign from the largest displacement along the normal in the last
    state. Raises ComparisonError naming the setting when a choice cannot be made or the model does not fit.
    """
    settings = settings or MappingSettings()
    detected: list[str] = []
    notes: list[str] = []
    xyz = results.node_xyz
    where = results.source.rsplit("/", 1)[-1]
    # The normal: the smallest extent of the nodes that can form the surface.
    candidates = np.unique(results.shells) if len(results.shells) else np.arange(results.n_nodes)
    span = np.ptp(xyz[candidates], axis=0)
    normal_axis = settings.normal_axis
    if normal_axis is None:
        normal_axis = AXES[int(np.argmin(span))]
        detected.append("normal_axis")
    in_plane = [span[i] for i in range(3) if AXES[i] != normal_axis]
    thin = span[AXES.index(normal_axis)]
    if not (min(in_plane) > 0 and thin <= 0.1 * min(in_plane)):
        raise ComparisonError(
            f"{where}: no plate-like surface: the model spans {span[0]:.4g} × {span[1]:.4g} × {span[2]:.4g} "
            f"(its own units) along x, y, z; a plate is thin along its normal ({normal_axis}). Set the normal axis "
            "(--normal-axis x|y|z) or give the plate part only"
        )
    w_sign = settings.w_sign
    if w_sign is None:
        u_last = results.displacement(results.n_states - 1)[candidates, AXES.index(normal_axis)]
        finite = np.isfinite(u_last)  # (an eroded node has no displacement in the last state)
        w_sign = -1 if np.any(finite) and u_last[finite][int(np.argmax(np.abs(u_last[finite])))] < 0 else 1
        detected.append("w_sign")
    oriented = _oriented(xyz, normal_axis, w_sign)
    surface = model_surface(results, oriented, surface=settings.surface, thickness=None)
    surface_xyz = oriented[surface.nodes]
    lo, hi = surface_xyz[:, :2].min(axis=0), surface_xyz[:, :2].max(axis=0)
    tol = 0.02 * float(np.max(hi - lo))
    if settings.symmetry is not None:
        symmetries = [settings.symmetry]
    else:
        half_x, half_y = _touches(lo[0], hi[0], tol), _touches(lo[1], hi[1], tol)
        symmetries = ["none"] + (["half-x"] if half_x else []) + (["half-y"] if half_y else [])
        symmetries += ["quarter"] if half_x and half_y else []
    unit = settings.length_unit or results.length_unit
    units = [unit] if unit else list(LENGTH_UNITS)
    measured = plate.extent_mm
    x0, x1, y0, y1 = plate.data_box_mm
    measured_xy = np.array([x1 - x0, y1 - y0])
    scored = []
    for symmetry in symmetries:
        unfold = [2.0 if symmetry in ("half-x", "quarter") else 1.0, 2.0 if symmetry in ("half-y", "quarter") else 1.0]
        extent_xy = (hi - lo) * np.array(unfold)
        for candidate in units:
            scaled = extent_xy * LENGTH_UNITS[candidate]
            score = float(np.sum(np.abs(np.log(np.maximum(scaled, 1e-300) / measured_xy))))
            scored.append((score, symmetry, candidate, float(np.max(scaled)) / measured))
    scored.sort()
    _, symmetry, length_unit, ratio = scored[0]
    if settings.symmetry is None:
        detected.append("symmetry")
    if unit is None:
        detected.append("length_unit")
    if not (1.0 / EXTENT_TOLERANCE / 2.0 < ratio < EXTENT_TOLERANCE) and unit is None:
        raise ComparisonError(
            f"{where}: units cannot be decided: the model spans {float(np.max(hi - lo)):.4g} (its own units), the "
            f"measured plate {measured:.0f} mm; neither mm nor m fits. Set the units (--units mm|m) and check that "
            "the model is the plate"
        )
    if unit is not None and ratio < 1.0 / EXTENT_TOLERANCE / 2.0:
        # A unit that was given (set, or declared by the file) and is wrong makes the model a speck on the plate:
        # compared as it is, it would give differences of the whole deflection and no error.
        given = "set" if settings.length_unit else "declared by the file"
        raise ComparisonError(
            f"{where}: the model ({ratio * measured:.3g} mm across as {symmetry}, in {length_unit} as "
            f"{given}) is far smaller than the measured plate ({measured:.0f} mm): check the units (--units mm|m) "
            "and the symmetry (--symmetry none|half-x|half-y|quarter)"
        )
    if ratio > EXTENT_TOLERANCE:
        raise ComparisonError(
            f"{where}: the model ({ratio * measured:.0f} mm across as {symmetry}, in {length_unit}) is larger than the "
            f"measured plate ({measured:.0f} mm): check the units (--units mm|m) and the symmetry "
            "(--symmetry none|half-x|half-y|quarter), or give the plate part only"
        )
    if len(scored) > 1 and settings.symmetry is None and unit is None:
        notes.append(f"model extent {ratio:.2f} × the measured plate's as {symmetry} in {length_unit}")
    scale = LENGTH_UNITS[length_unit]
    reference_mm = scale * surface_xyz
    origin = settings.origin_xy_mm
    origin_on_axis = False
    if origin is None:
        detected.append("origin_xy_mm")
        axis = np.asarray(plate.axis_xy_mm, np.float64)
        if symmetry == "none":
            own_axis, how = _model_punch_axis(results, surface.nodes, scale * surface_xyz[:, :2],
                                              normal_axis=normal_axis, w_sign=w_sign)  # fmt: skip
            if own_axis is None:
                own_axis, how = 0.5 * (lo + hi) * scale, "the centre of its extent (no state deflects it)"
            angle = np.deg2rad(settings.rotation_deg)
            turned = np.array([np.cos(angle) * own_axis[0] - np.sin(angle) * own_axis[1],
                               np.sin(angle) * own_axis[0] + np.cos(angle) * own_axis[1]])  # fmt: skip
            origin = (float(axis[0] - turned[0]), float(axis[1] - turned[1]))
            origin_on_axis = True
            notes.append(
                f"model's punch axis ({how}, at ({own_axis[0]:.2f}, {own_axis[1]:.2f}) mm in its own frame) put on "
                f"the measured punch axis ({axis[0]:.2f}, {axis[1]:.2f}) mm: model moved by ({origin[0]:.2f}, "
                f"{origin[1]:.2f}) mm (an origin of 0, 0 keeps a model in plate coordinates)"
            )
        else:
            origin = (float(axis[0]), float(axis[1]))
            origin_on_axis = True
            notes.append("model origin (its symmetry axis) put on the measured punch axis")
    thickness = settings.shell_thickness_mm / scale if settings.shell_thickness_mm is not None else None
    if len(results.shells):
        if thickness is not None:
            surface = model_surface(results, oriented, surface=settings.surface, thickness=thickness)
        elif results.shell_thickness is None and settings.surface != "mid":
            notes.append("shell thickness not in the file: the mid-surface is compared (set --shell-thickness)")
    t_nodes = surface.thickness
    shell_thickness_mm = float(np.median(t_nodes) * scale) if len(results.shells) and np.any(t_nodes > 0) else None
    time_unit_s = settings.time_unit_s or results.time_unit_s
    if time_unit_s is None:
        time_unit_s = 1.0
        notes.append("time unit not in the file: taken as s")
    force_unit = settings.force_unit_kN or results.force_unit_kN
    if force_unit is None:
        force_unit = 1.0 if length_unit == "mm" else 1e-3
        if results.force is not None:
            notes.append(f"force unit not in the file: taken as {'kN' if length_unit == 'mm' else 'N'}")
    mapping = Mapping(
        length_unit=length_unit, symmetry=symmetry, normal_axis=normal_axis, w_sign=w_sign,
        origin_xy_mm=(float(origin[0]), float(origin[1])), rotation_deg=settings.rotation_deg,
        surface=settings.surface, shell_thickness_mm=shell_thickness_mm, time_unit_s=float(time_unit_s),
        force_unit_kN=float(force_unit), time_offset_s=settings.time_offset_s, detected=tuple(detected),
        notes=tuple(notes), origin_on_axis=origin_on_axis,
    )  # fmt: skip
    return MappedModel(results, mapping, surface, reference_mm)


def _model_punch_axis(
    results: FEResults, nodes: np.ndarray, reference_xy_mm: np.ndarray, *, normal_axis: str, w_sign: int
) -> tuple[np.ndarray | None, str]:
    """A full model's own punch axis, (X, Y) mm in its oriented, scaled frame: the centroid of the area above
    half the deflection (as `fields.field_peak` locates the measured one) at the first loaded state, the first
    whose largest deflection reaches a tenth of the last state's; None when no state deflects the surface.

    nodes: the surface nodes; reference_xy_mm (M, 2): their oriented, scaled reference positions."""

    def deflection(state: int) -> np.ndarray:
        return _oriented(results.displacement(state)[nodes], normal_axis, w_sign)[:, 2]

    last = deflection(results.n_states - 1)
    largest = float(np.nanmax(last)) if np.any(np.isfinite(last)) else 0.0
    if not largest > 0:
        return None, ""
    for state in range(results.n_states):
        w = deflection(state)
        peak = float(np.nanmax(w)) if np.any(np.isfinite(w)) else 0.0
        if peak > 0 and peak >= 0.1 * largest:
            weight = np.nan_to_num(np.where(w >= 0.5 * peak, w - 0.5 * peak, 0.0))
            centre = (weight[:, None] * reference_xy_mm).sum(axis=0) / weight.sum()
            return centre, f"the centre of its deflection at state {state}"
    return None, ""


# ----------------------------------------------------------------------------------------------------------------
# Time alignment


@dataclass(frozen=True, eq=False)
class Alignment:
    """Which simulation states each test frame is compared with: w_sim = (1 − fraction)·W[lo] + fraction·W[lo + 1].

    state_lo (n,) int64 (−1 where the frame has no partner), fraction (n,), reason (n,) ("" where aligned);
    frame_value, state_value: what was matched (punch displacement in mm, time in s or peak deflection in mm)."""

    method: str
    state_lo: np.ndarray
    fraction: np.ndarray
    reason: tuple[str, ...]
    frame_value: np.ndarray
    state_value: np.ndarray

    @property
    def aligned(self) -> np.ndarray:
        return self.state_lo >= 0


def align_by_values(method: str, frame_value: np.ndarray, state_value: np.ndarray, *, unit: str) -> Alignment:
    """Pair frames with states by a quantity that grows through the test (punch travel, time, peak deflection).

    Only the states up to the quantity's maximum are used (after it, a punch retracts or a peak falls), with a
    running maximum so small dips do not make the pairing ambiguous. A frame whose value is NaN or outside the
    states' range gets no partner, with the reason.
    """
    state_value = np.asarray(state_value, np.float64)
    frame_value = np.asarray(frame_value, np.float64)
    finite = np.isfinite(state_value)
    if not np.any(finite):
        raise ComparisonError(f"align by {method}: the simulation has no finite {method} value in any state")
    last = int(np.nanargmax(np.where(finite, state_value, -np.inf)))
    rising = np.maximum.accumulate(np.nan_to_num(state_value[: last + 1], nan=-np.inf))
    lo_value, hi_value = float(rising[0]), float(rising[-1])
    n = len(frame_value)
    state_lo = np.full(n, -1, np.int64)
    fraction = np.zeros(n)
    reasons = []
    tolerance = 1e-9 * max(abs(hi_value), 1.0)
    for i, value in enumerate(frame_value):
        if not np.isfinite(value):
            reasons.append(f"no {method} logged for this frame")
            continue
        if value < lo_value - tolerance or value > hi_value + tolerance:
            reasons.append(f"{method} {value:.4g} {unit} outside the simulation's {lo_value:.4g}–{hi_value:.4g} {unit}")
            continue
        if len(rising) == 1:
            state_lo[i], fraction[i] = 0, 0.0
            reasons.append("")
            continue
        j = int(np.clip(np.searchsorted(rising, value, side="left") - 1, 0, len(rising) - 2))
        # Within ties (a flat run) the first state at that value is taken.
        span = rising[j + 1] - rising[j]
        state_lo[i] = j
        fraction[i] = float(np.clip((value - rising[j]) / span, 0.0, 1.0)) if span > 0 else 0.0
        reasons.append("")
    if not np.any(state_lo >= 0):
        raise ComparisonError(
            f"align by {method}: no test frame lies within the simulation's {lo_value:.4g}–{hi_value:.4g} {unit} "
            f"(frames: {np.nanmin(frame_value) if np.any(np.isfinite(frame_value)) else float('nan'):.4g}–"
            f"{np.nanmax(frame_value) if np.any(np.isfinite(frame_value)) else float('nan'):.4g} {unit}); "
            "choose another alignment (--align displacement|time|peak) or check the units and time offset"
        )
    return Alignment(method, state_lo, fraction, tuple(reasons), frame_value, state_value)


def interpolate_history(time: np.ndarray, history_time: np.ndarray, values: np.ndarray) -> np.ndarray:
    """values (P,) of a time history at `time` (S,), linear; NaN outside the history's span.

    The span is widened by a round-off of the history's times (1e-5 of the largest |time|): LS-DYNA prints nodout
    and rcforc times with 5 to 8 digits while d3plot holds them as float32, so the last state's time may lie a hair
    after the history's last (its punch travel would be lost, and with it the last state)."""
    history_time = np.asarray(history_time, np.float64)
    time = np.asarray(time, np.float64)
    if len(history_time) == 0:
        return np.full(len(time), np.nan)
    lo, hi = float(np.min(history_time)), float(np.max(history_time))
    slack = 1e-5 * max(abs(lo), abs(hi), float(np.max(np.abs(time))) if len(time) else 0.0)
    inside = (time >= lo - slack) & (time <= hi + slack)
    out = np.interp(np.clip(time, lo, hi), history_time, values)
    return np.where(inside, out, np.nan)


def state_punch_mm(model: MappedModel) -> np.ndarray | None:
    """The punch travel (S,) in mm at the simulation's states, or None when the simulation has none."""
    results = model.results
    if results.punch_displacement is None or results.punch_time is None:
        return None
    scale = 1.0 if results.punch_in_mm else LENGTH_UNITS[model.mapping.length_unit]
    return scale * interpolate_history(results.time, results.punch_time, results.punch_displacement)


def state_force_kN(model: MappedModel) -> np.ndarray | None:
    """The punch force (S,) in kN at the simulation's states, or None."""
    results = model.results
    if results.force is None or results.force_time is None:
        return None
    return model.mapping.force_unit_kN * interpolate_history(results.time, results.force_time, results.force)


def align_frames(
    model: MappedModel,
    method: str,
    *,
    frame_time_s: np.ndarray,
    frame_punch_mm: np.ndarray,
    frame_peak_mm: np.ndarray,
    state_peak_mm: np.ndarray | None = None,
) -> Alignment:
    """Pair the test frames with the simulation's states by punch displacement, time or peak deflection.

    state_peak_mm (S,): the simulated peak per state, for "peak" (computed here when not given).
    """
    if method not in ALIGNMENTS:
        raise ValueError(f"align: expected one of {ALIGNMENTS}, got {method!r}")
    if method == "displacement":
        punch = state_punch_mm(model)
        if punch is None:
            raise ComparisonError(
                "align by displacement: the simulation has no punch displacement; give the punch node "
                "(--punch-node ID), a nodout or a punch CSV with punch_displacement_mm, or align by time or peak "
                "(--align time|peak)"
            )
        if not np.any(np.isfinite(frame_punch_mm)):
            raise ComparisonError(
                "align by displacement: the result has no punch displacement (frames.csv column "
                "punch_displacement_mm); align by time or peak (--align time|peak)"
            )
        return align_by_values("punch displacement", frame_punch_mm, punch, unit="mm")
    if method == "time":
        state_time = model.results.time * model.mapping.time_unit_s + model.mapping.time_offset_s
        if not np.any(np.isfinite(frame_time_s)):
            raise ComparisonError(
                "align by time: the result has no frame times (frames.csv column time_s); align by peak"
            )
        return align_by_values("time", frame_time_s, state_time, unit="s")
    peaks = (
        np.array([model.peak_w_mm(s) for s in range(model.results.n_states)])
        if state_peak_mm is None
        else state_peak_mm
    )
    return align_by_values("peak deflection", frame_peak_mm, peaks, unit="mm")


def align_by_footprint_peak(
    model: MappedModel, grid: Grid, measured_w: Callable[[int], np.ndarray], n_frames: int
) -> Alignment:
    """Pair frames with states by peak deflection, each frame against the simulated peak over its own measured
    footprint: a measurement that lost the top of the dome (a hole, points out of range) reports a lower peak,
    and so does the simulation seen through the same nodes. measured_w(i): frame i's w (ny, nx), read once.

    The peak finds the states around the frame; the blend between them is then the one whose w fits the frame's
    measured w best over its footprint (least squares, `_fitted_blend`). The highest measured node alone would
    carry the measurement's largest error (the steep top of the dome, where gridding cuts the curvature: up to
    0.8 mm low on the virtual test) into the whole simulated field, which no longer equals the measurement's
    error then. The states' grids are sampled once and held (S × ny × nx floats)."""
    states = [model.sample(s, grid) for s in range(model.results.n_states)]
    frame_peak = np.full(n_frames, np.nan)
    state_lo = np.full(n_frames, -1, np.int64)
    fraction = np.zeros(n_frames)
    reasons = []
    curves = np.full((n_frames, len(states)), np.nan)
    for i in range(n_frames):
        w = measured_w(i)
        seen = np.isfinite(w)
        frame_peak[i] = np.nanmax(w) if np.any(seen) else np.nan
        curves[i] = [np.nanmax(np.where(seen, s, np.nan)) if np.any(seen & np.isfinite(s)) else np.nan for s in states]
        try:
            one = align_by_values("peak deflection", frame_peak[i : i + 1], curves[i], unit="mm")
        except ComparisonError as error:
            reasons.append(str(error).split(";")[0])
            continue
        state_lo[i], fraction[i] = _fitted_blend(w, states, int(one.state_lo[0]))
        reasons.append(one.reason[0])
    if not np.any(state_lo >= 0):
        raise ComparisonError("align by peak deflection: no test frame's peak lies within the simulation's; "
                              "choose another alignment (--align displacement|time)")  # fmt: skip
    return Alignment("peak deflection", state_lo, fraction, tuple(reasons), frame_peak, np.nanmax(curves, axis=0))


def _fitted_blend(measured_w: np.ndarray, states: list[np.ndarray], near: int) -> tuple[int, float]:
    """(state_lo, fraction) of the blend (1 − f)·W[lo] + f·W[lo + 1] nearest to measured_w (ny, nx) in least
    squares over the nodes where both have data, lo within one state of `near` (f clipped to 0…1)."""
    if len(states) == 1:
        return 0, 0.0
    best = (np.inf, near, 0.0)
    for lo in range(max(near - 1, 0), min(near + 1, len(states) - 2) + 1):
        a, b = states[lo], states[lo + 1]
        both = np.isfinite(measured_w) & np.isfinite(a) & np.isfinite(b)
        if not np.any(both):
            continue
        step, rest = (b - a)[both], (measured_w - a)[both]
        norm = float(step @ step)
        f = float(np.clip(rest @ step / norm, 0.0, 1.0)) if norm > 0 else 0.0
        misfit = float(np.mean((rest - f * step) ** 2))
        if misfit < best[0]:
            best = (misfit, lo, f)
    return best[1], best[2]


def fit_origin(model: MappedModel, grid: Grid, measured_w: np.ndarray, *, state_lo: int, fraction: float,
               search_mm: float = 10.0) -> MappedModel:  # fmt: skip
    """The model moved in the plane to fit a measured frame best (least squares of w_meas − w_sim), within
    search_mm of where it is: for a model whose axis was put on the measured punch axis, which is only as good
    as the measured dome's centroid. Use a well-deflected frame; the move is in the mapping's notes."""
    from scipy.optimize import minimize

    start = np.asarray(model.mapping.origin_xy_mm, np.float64)

    def misfit(offset: np.ndarray) -> float:
        if np.hypot(*offset) > search_mm:
            return 1e6 + float(np.hypot(*offset))
        moved = model.with_origin((start[0] + offset[0], start[1] + offset[1]))
        diff = measured_w - moved.sample_between(state_lo, fraction, grid)
        both = np.isfinite(diff)
        return float(np.mean(diff[both] ** 2)) if np.count_nonzero(both) > 100 else 1e6

    simplex = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    options = {"initial_simplex": simplex, "xatol": 0.02, "fatol": 1e-9, "maxiter": 200}
    offset = minimize(misfit, np.zeros(2), method="Nelder-Mead", options=options).x
    note = f"origin fitted to the measurement: moved by ({offset[0]:.2f}, {offset[1]:.2f}) mm"
    return model.with_origin((start[0] + offset[0], start[1] + offset[1]), note=note)


# ----------------------------------------------------------------------------------------------------------------
# Sampling and differences


class StateSampler:
    """Simulated deflection grids of states, sampled once each and kept for the next frames (the last few)."""

    def __init__(self, model: MappedModel, grid: Grid, *, keep: int = 4) -> None:
        self.model = model
        self.grid = grid
        self.keep = keep
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def state(self, s: int) -> np.ndarray:
        # The grid made here is the one returned: a sampler shared by threads (the preview's) may lose it meanwhile.
        grid_w = self._cache.get(s)
        if grid_w is None:
            grid_w = self._cache[s] = self.model.sample(s, self.grid)
            while len(self._cache) > self.keep:
                self._cache.popitem(last=False)
        return grid_w

    def at(self, state_lo: int, fraction: float) -> np.ndarray:
        """w_sim (ny, nx) between states state_lo and state_lo + 1 (NaN where either has no data)."""
        if fraction <= 0.0 or state_lo + 1 >= self.model.results.n_states:
            return self.state(state_lo)
        return (1.0 - fraction) * self.state(state_lo) + fraction * self.state(state_lo + 1)


@dataclass(frozen=True)
class FrameDifference:
    """Differences of one frame inside the evaluated region (nodes with both measured and simulated w).

    rms_diff_mm, max_diff_mm: RMS and largest |w_meas − w_sim|; n_nodes: nodes compared;
    fraction_beyond_2sigma: of those with a σ_w, the fraction where |diff| > 2σ (NaN without σ)."""

    rms_diff_mm: float
    max_diff_mm: float
    mean_diff_mm: float
    n_nodes: int
    fraction_beyond_2sigma: float


def frame_difference(
    w_meas_mm: np.ndarray,
    w_sim_mm: np.ndarray,
    *,
    sigma_w_mm: np.ndarray | None = None,
    region: np.ndarray | None = None,
) -> tuple[np.ndarray, FrameDifference]:
    """The difference map w_meas − w_sim (ny, nx) (NaN outside the evaluated region) and its statistics."""
    diff = w_meas_mm - w_sim_mm
    inside = np.isfinite(diff) if region is None else np.isfinite(diff) & region
    diff = np.where(inside, diff, np.nan)
    n = int(inside.sum())
    if n == 0:
        nan = float("nan")
        return diff, FrameDifference(nan, nan, nan, 0, nan)
    values = diff[inside]
    beyond = float("nan")
    if sigma_w_mm is not None:
        has = inside & np.isfinite(sigma_w_mm)
        if np.any(has):
            beyond = float(np.mean(np.abs(diff[has]) > 2.0 * sigma_w_mm[has]))
    return diff, FrameDifference(
        rms_diff_mm=float(np.sqrt(np.mean(values**2))), max_diff_mm=float(np.max(np.abs(values))),
        mean_diff_mm=float(np.mean(values)), n_nodes=n, fraction_beyond_2sigma=beyond,
    )  # fmt: skip


def overlap_fraction(model: MappedModel, grid: Grid, model_w: np.ndarray, measured_w: np.ndarray) -> float:
    """The share of the model's area (its unfolded reference surface) where the measurement has data too."""
    xy = model.reference_mm[:, :2]
    a, b, c = (xy[model.surface.triangles[:, i]] for i in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    area = 0.5 * float(np.abs(cross).sum()) * len(_unfolds(model.mapping.symmetry))
    if not area > 0:
        return 0.0
    both = np.count_nonzero(np.isfinite(model_w) & np.isfinite(measured_w))
    return min(both * grid.step_mm**2 / area, 1.0)


def check_overlap(
    model: MappedModel, grid: Grid, model_w: np.ndarray, measured_w: np.ndarray, *, minimum: float = 0.5
) -> float:
    """Raise ComparisonError naming the origin setting when the model and the measurement barely overlap."""
    share = overlap_fraction(model, grid, model_w, measured_w)
    if share < minimum:
        xy = model.footprint_xy_mm()
        has = np.isfinite(measured_w)
        gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
        box = (gx[has].min(), gx[has].max(), gy[has].min(), gy[has].max()) if np.any(has) else (np.nan,) * 4
        raise ComparisonError(
            f"the model (x {xy[:, 0].min():.0f}…{xy[:, 0].max():.0f} mm, "
            f"y {xy[:, 1].min():.0f}…{xy[:, 1].max():.0f} mm in the plate frame) and the measurement "
            f"(x {box[0]:.0f}…{box[1]:.0f}, y {box[2]:.0f}…{box[3]:.0f}) "
            f"overlap on {100 * share:.0f} % of the model: set where the model's origin lies (--origin X,Y in mm), "
            "its rotation (--rotation DEG) or its units (--units mm|m)"
        )
    return share


@dataclass(frozen=True, eq=False)
class Profiles:
    """Profiles along a line: s_mm (M,), measured, simulated and σ_w (M,) (NaN where not available)."""

    s_mm: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    measured_mm: np.ndarray
    simulated_mm: np.ndarray
    sigma_mm: np.ndarray


def profiles_along(
    grid: Grid, start_xy_mm: tuple[float, float], end_xy_mm: tuple[float, float], *, measured: np.ndarray,
    simulated: np.ndarray, sigma: np.ndarray | None = None,
) -> Profiles:  # fmt: skip
    """Measured and simulated deflection (and σ_w) along a straight line on the grid."""
    from .fields import line_profile

    stack = np.stack([measured, simulated, sigma if sigma is not None else np.full_like(measured, np.nan)])
    profile = line_profile(stack, grid, start_xy_mm, end_xy_mm)
    return Profiles(profile.s_mm, profile.x_mm, profile.y_mm, *profile.values)


# ----------------------------------------------------------------------------------------------------------------
# Pairing: the one way a simulation is put next to a measurement (the comparison and its live preview)


def plate_frame_of(grid: Grid, first_w_mm: np.ndarray, *, axis_xy_mm: tuple[float, float] | None) -> PlateFrame:
    """The plate as the measurement sees it: the extent of the first frame's data (ny, nx) on `grid`, and the
    punch axis (axis_xy_mm: the result's punch axis or clamp centre; None: the centre of the data)."""
    has = np.isfinite(first_w_mm)
    if not np.any(has):
        raise ComparisonError("the result's first frame has no data to compare with")
    gx, gy = np.meshgrid(grid.x_mm, grid.y_mm)
    box = (float(gx[has].min()), float(gx[has].max()), float(gy[has].min()), float(gy[has].max()))
    axis = axis_xy_mm if axis_xy_mm is not None and np.all(np.isfinite(axis_xy_mm)) else None
    if axis is None:
        axis = (0.5 * (box[0] + box[1]), 0.5 * (box[2] + box[3]))
    return PlateFrame(axis_xy_mm=(float(axis[0]), float(axis[1])), data_box_mm=box)


@dataclass(frozen=True, eq=False)
class Pairing:
    """A simulation mapped into the plate frame and paired with the test's frames: what the comparison compares.

    state_peak_mm (S,): the simulated peak per state; sampler: w_sim on the grid for a frame's (state_lo, fraction);
    overlap: the share of the model's area the measurement covers (in the first paired frame)."""

    model: MappedModel
    alignment: Alignment
    state_peak_mm: np.ndarray
    sampler: StateSampler
    overlap: float

    def simulated_w(self, i: int) -> np.ndarray | None:
        """w_sim (ny, nx) paired with frame position i, or None where the frame has no partner."""
        lo = int(self.alignment.state_lo[i])
        return None if lo < 0 else self.sampler.at(lo, float(self.alignment.fraction[i]))


def pair_with_measurement(
    results: FEResults,
    *,
    grid: Grid,
    plate: PlateFrame,
    measured_w: Callable[[int], np.ndarray],
    frame_time_s: np.ndarray,
    frame_punch_mm: np.ndarray,
    frame_peak_mm: np.ndarray,
    mapping: MappingSettings | None = None,
    align: str = "displacement",
) -> Pairing:
    """Map a simulation into the plate frame and pair every test frame with its states (`map_model`,
    `align_frames` or `align_by_footprint_peak`); a model put on the measured punch axis is then moved to fit the
    frame that deflects most (`fit_origin`), and the overlap with the measurement checked (`check_overlap`).

    measured_w(i): frame position i's measured w (ny, nx) on `grid`; frame_* (n,): the test log and measured peak
    per frame (NaN where unknown). Raises ComparisonError naming the setting when a step cannot be done.
    """
    if align not in ALIGNMENTS:
        raise ValueError(f"align: expected one of {ALIGNMENTS}, got {align!r}")
    n_frames = len(frame_time_s)
    model = map_model(results, plate, mapping)
    state_peak = np.array([model.peak_w_mm(s) for s in range(results.n_states)])
    if align == "peak":
        alignment = align_by_footprint_peak(model, grid, measured_w, n_frames)
    else:
        alignment = align_frames(model, align, frame_time_s=frame_time_s, frame_punch_mm=frame_punch_mm,
                                 frame_peak_mm=frame_peak_mm, state_peak_mm=state_peak)  # fmt: skip
    if model.mapping.origin_on_axis:
        # The measured punch axis is the dome's centroid, biased where the top has no data: fit the model's
        # position on the frame that deflects most.
        aligned = np.flatnonzero(alignment.aligned)
        best = int(aligned[np.argmax(np.nan_to_num(frame_peak_mm[aligned], nan=-np.inf))])
        model = fit_origin(model, grid, measured_w(best), state_lo=int(alignment.state_lo[best]),
                           fraction=float(alignment.fraction[best]))  # fmt: skip
    sampler = StateSampler(model, grid)
    first = int(np.flatnonzero(alignment.aligned)[0])
    lo, fraction = int(alignment.state_lo[first]), float(alignment.fraction[first])
    overlap = check_overlap(model, grid, sampler.at(lo, fraction), measured_w(first))
    return Pairing(model, alignment, state_peak, sampler, overlap)

"""Camera–projector calibration from chessboard poses under Gray code (Moreno & Taubin 2012; docs/procam.md §1).

Belongs here: for each pose, the board's inner corners in the camera, their projector coordinates from a local
homography (camera → projector) fitted around each corner to the stripe edges of both coded sequences (columns and
rows) and, where a window has too few edges, to the decoded per-pixel codes; then the camera and the projector
each calibrated by cv2.calibrateCamera and the pair by cv2.stereoCalibrate, with per-pose RMS, residuals and a
verdict. Not here: decoding (`graycode.py`), the model (`procam.py`), reading recordings (`fringelab.formats`).

The local homography is Moreno & Taubin's idea: around a corner the board is a plane, so camera and projector
pixels are related by a homography there, and the corner's projector position is that homography applied to the
corner's camera position. Stripe edges fix one projector coordinate each at sub-pixel accuracy (a column edge fixes
x, a row edge y); the fit takes each as one equation. Only pixels on the white squares' interior take part: at a
square's border the camera's blur mixes two albedos, which no threshold undoes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from . import Cancelled, MeasurementError
from .chessboard import Board, BoardNotFoundError, detect_board
from .graycode import CodedEdges, DecodeSettings, Decoding, DecodingError, PatternSequence, coded_edges, decode
from .procam import ProcamModel
from .verdict import Verdict, check, verdict_of

ProgressCallback = Callable[[int, int, str], None]

# The homography window's half-size, as a fraction of the smallest corner spacing in the camera: large enough to
# hold several stripe edges of each direction, small enough to stay off the neighbouring corners' squares.
WINDOW_FRACTION = 0.45
# Fewest edge points of each direction a window needs for its homography from edges (else decoded pixels).
MIN_EDGE_POINTS = 12
# Fewest decoded pixels a window needs for a homography from codes.
MIN_CODE_PIXELS = 30


class ProcamCalibrationError(MeasurementError):
    """The camera–projector calibration cannot be made: a pose without its board or its projector corners, too
    few poses."""


@dataclass(frozen=True, eq=False)
class PoseCorners:
    """One pose's corners: points_board_mm (N, 3), camera q_px (N, 2), projector q_px (N, 2), and which corners'
    projector positions came from stripe edges (True) or from decoded pixels (False)."""

    pose: str
    points_board_mm: np.ndarray
    camera_q_px: np.ndarray
    projector_q_px: np.ndarray
    from_edges: np.ndarray


@dataclass(frozen=True, eq=False)
class PoseResult:
    """Per-pose reprojection: RMS (px) of camera and projector, and residual vectors (N, 2) at camera_q_px and
    projector_q_px."""

    pose: str
    camera_rms_px: float
    projector_rms_px: float
    camera_q_px: np.ndarray
    camera_residual_px: np.ndarray
    projector_q_px: np.ndarray
    projector_residual_px: np.ndarray
    share_from_edges: float


@dataclass(frozen=True, eq=False)
class ProcamCalibration:
    """The calibrated pair and its report: RMS of the camera's, the projector's and the stereo calibration, per pose
    results and the verdict."""

    model: ProcamModel
    camera_rms_px: float
    projector_rms_px: float
    stereo_rms_px: float
    poses: tuple[PoseResult, ...]
    verdict: Verdict
    n_corners: int


def _local_homography(
    q_cam: np.ndarray, coordinate: np.ndarray, which: np.ndarray, weight: np.ndarray
) -> np.ndarray | None:
    """Homography H (3, 3), camera → projector, from points with one known projector coordinate each
    (which = 0: x, 1: y): the DLT rows h_which·q − c·h_3·q = 0, weighted, points normalised (Hartley)."""
    if len(q_cam) < 8:
        return None
    mean = q_cam.mean(axis=0)
    scale = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(q_cam - mean, axis=1))), 1e-9)
    t_cam = np.array([[scale, 0, -scale * mean[0]], [0, scale, -scale * mean[1]], [0, 0, 1.0]])
    c_mean = np.array([np.mean(coordinate[which == 0]) if np.any(which == 0) else 0.0,
                       np.mean(coordinate[which == 1]) if np.any(which == 1) else 0.0])  # fmt: skip
    c_scale = 1.0 / max(float(np.std(coordinate)), 1e-9)
    t_proj = np.array([[c_scale, 0, -c_scale * c_mean[0]], [0, c_scale, -c_scale * c_mean[1]], [0, 0, 1.0]])
    qh = np.column_stack([q_cam, np.ones(len(q_cam))]) @ t_cam.T
    c = (coordinate - c_mean[which]) * c_scale
    rows = np.zeros((len(q_cam), 9))
    for axis in (0, 1):
        m = which == axis
        rows[m, 3 * axis : 3 * axis + 3] = qh[m]
        rows[m, 6:9] = -c[m, None] * qh[m]
    rows *= np.sqrt(weight)[:, None]
    _, _, vt = np.linalg.svd(rows, full_matrices=False)
    h_norm = vt[-1].reshape(3, 3)
    h = np.linalg.inv(t_proj) @ h_norm @ t_cam
    return h / h[2, 2]


def _apply(h: np.ndarray, q: np.ndarray) -> np.ndarray:
    p = np.column_stack([q, np.ones(len(q))]) @ h.T
    return p[:, :2] / p[:, 2:3]


def _fit_robust(q: np.ndarray, coordinate: np.ndarray, which: np.ndarray, sigma: np.ndarray) -> np.ndarray | None:
    """The local homography, refitted twice without the points beyond 4 robust σ of its residuals."""
    keep = np.ones(len(q), bool)
    h = None
    for _ in range(3):
        h = _local_homography(q[keep], coordinate[keep], which[keep], 1.0 / sigma[keep] ** 2)
        if h is None:
            return None
        predicted = _apply(h, q)[np.arange(len(q)), which]
        normalised = (predicted - coordinate) / sigma
        spread = 1.4826 * float(np.median(np.abs(normalised[keep]))) + 1e-12
        new_keep = np.abs(normalised) <= max(4.0 * spread, 4.0)
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return h


def _window_edges(
    edges: CodedEdges, corner_px: tuple[float, float], window_px: float, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge points within the window around a corner that lie on `mask` (the white squares' interior):
    camera pixels (M, 2), projector coordinates (M,), σ along the scan line (M,), at least 0.02 px."""
    height, width = mask.shape
    q = edges.q_px
    near = (np.abs(q[:, 0] - corner_px[0]) <= window_px) & (np.abs(q[:, 1] - corner_px[1]) <= window_px)
    iu = np.clip(np.rint(q[near, 0]).astype(int), 0, width - 1)
    iv = np.clip(np.rint(q[near, 1]).astype(int), 0, height - 1)
    idx = np.flatnonzero(near)[mask[iv, iu]]
    return q[idx], edges.projector_px[idx], np.maximum(edges.sigma_t_px[idx], 0.02)


def projector_corners(
    camera_q_px: np.ndarray,
    columns: Decoding,
    rows: Decoding,
    column_edges: CodedEdges,
    row_edges: CodedEdges,
    *,
    window_px: float,
    pose: str,
    projector_size_wh_px: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Projector positions (N, 2) of camera corners (N, 2), and whether each came from edges (N,) bool.

    Raises ProcamCalibrationError naming the pose when any corner has neither enough edges nor enough decoded
    pixels around it.
    """
    shading = np.minimum(columns.shading_grey, rows.shading_grey)
    height, width = shading.shape
    out = np.full((len(camera_q_px), 2), np.nan)
    from_edges = np.zeros(len(camera_q_px), bool)
    half = int(np.ceil(window_px))
    column_centre, row_centre = columns.code_centre_px(), rows.code_centre_px()
    column_sigma, row_sigma = columns.code_sigma_px(), rows.code_sigma_px()
    missing = []
    for n, (u, v) in enumerate(camera_q_px):
        u0, u1 = max(int(u) - half, 0), min(int(u) + half + 2, width)
        v0, v1 = max(int(v) - half, 0), min(int(v) + half + 2, height)
        patch = shading[v0:v1, u0:u1]
        if patch.size == 0:
            missing.append(n)
            continue
        # The white squares' interior: at least half the window's brightest shading, 2 px off the squares' borders.
        white = (patch >= 0.5 * float(np.percentile(patch, 95))).astype(np.uint8)
        white = cv2.erode(white, np.ones((5, 5), np.uint8)).astype(bool)
        mask = np.zeros(shading.shape, bool)
        mask[v0:v1, u0:u1] = white

        qx, cx, sx = _window_edges(column_edges, (u, v), window_px, mask)
        qy, cy, sy = _window_edges(row_edges, (u, v), window_px, mask)
        h = None
        if len(qx) >= MIN_EDGE_POINTS and len(qy) >= MIN_EDGE_POINTS and len(np.unique(cx)) >= 2 and len(
                np.unique(cy)) >= 2:  # fmt: skip
            q = np.vstack([qx, qy])
            c = np.concatenate([cx, cy])
            which = np.concatenate([np.zeros(len(qx), int), np.ones(len(qy), int)])
            # σ in projector px of an edge point: its camera σ is along the camera's scan line; ~1 px of the
            # projector per camera px is close enough for weights.
            h = _fit_robust(q, c, which, np.concatenate([sx, sy]))
            from_edges[n] = h is not None
        if h is None:
            vv, uu = np.nonzero(mask & np.isfinite(column_centre) & np.isfinite(row_centre))
            distinct = len(np.unique(column_centre[vv, uu])) >= 3 and len(np.unique(row_centre[vv, uu])) >= 3
            if len(vv) >= MIN_CODE_PIXELS and distinct:
                q = np.column_stack([uu, vv]).astype(np.float64)
                q2 = np.vstack([q, q])
                c = np.concatenate([column_centre[vv, uu], row_centre[vv, uu]])
                which = np.concatenate([np.zeros(len(q), int), np.ones(len(q), int)])
                sigma = np.concatenate([column_sigma[vv, uu], row_sigma[vv, uu]])
                h = _fit_robust(q2, c, which, sigma)
        corner = _apply(h, np.array([[u, v]]))[0] if h is not None else np.full(2, np.nan)
        if not (np.all(np.isfinite(corner)) and -0.5 <= corner[0] <= projector_size_wh_px[0] - 0.5
                and -0.5 <= corner[1] <= projector_size_wh_px[1] - 0.5):  # fmt: skip
            missing.append(n)
            continue
        out[n] = corner
    if missing:
        raise ProcamCalibrationError(
            f"{pose}: the projector corners could not be found at {len(missing)} of {len(camera_q_px)} board corners "
            f"(first at camera pixel ({camera_q_px[missing[0]][0]:.0f}, {camera_q_px[missing[0]][1]:.0f})): too few "
            "decoded stripes around them; check that the projector lights the whole board in this pose and that "
            "the coded sequences are in focus"
        )
    return out, from_edges


def pose_corners(
    frames: Sequence[np.ndarray],
    *,
    columns: PatternSequence,
    rows: PatternSequence,
    board: Board,
    pose: str,
    white_frame: int,
    decode_settings: DecodeSettings | None = None,
) -> PoseCorners:
    """The corners of one pose (see the module docstring); raises ProcamCalibrationError naming the pose."""
    try:
        corners = detect_board(np.asarray(frames[white_frame]), board=board, frame=pose)
    except BoardNotFoundError as error:
        raise ProcamCalibrationError(f"{pose}: {error}".replace(f"{pose}: {pose}:", f"{pose}:")) from error
    try:
        decoded_columns = decode(frames, columns, settings=decode_settings)
        decoded_rows = decode(frames, rows, settings=decode_settings)
    except (DecodingError, ValueError) as error:
        raise ProcamCalibrationError(f"{pose}: {error}") from error
    grid = corners.q_px
    spacing = np.min(np.linalg.norm(grid[1:] - grid[:-1], axis=1))
    window = WINDOW_FRACTION * float(spacing)
    q_proj, from_edges = projector_corners(
        grid, decoded_columns, decoded_rows, coded_edges(decoded_columns), coded_edges(decoded_rows),
        window_px=window, pose=pose, projector_size_wh_px=columns.projector_size_wh_px,
    )  # fmt: skip
    points = np.column_stack([corners.points_board_mm, np.zeros(len(grid))])
    return PoseCorners(pose=pose, points_board_mm=points, camera_q_px=grid, projector_q_px=q_proj,
                       from_edges=from_edges)  # fmt: skip


def calibrate_procam(
    poses: Sequence[PoseCorners],
    *,
    camera_size_wh_px: tuple[int, int],
    projector_size_wh_px: tuple[int, int],
    fix_k3: bool = True,
) -> ProcamCalibration:
    """Calibrate the camera, the projector and the pair from the poses' corners."""
    if len(poses) < 3:
        raise ProcamCalibrationError(
            f"a camera–projector calibration needs at least 3 chessboard poses, got {len(poses)}"
        )
    obj = [p.points_board_mm.astype(np.float32) for p in poses]
    cam = [p.camera_q_px.astype(np.float32).reshape(-1, 1, 2) for p in poses]
    proj = [p.projector_q_px.astype(np.float32).reshape(-1, 1, 2) for p in poses]
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    camera_rms, k_cam, d_cam, _, _ = cv2.calibrateCamera(obj, cam, camera_size_wh_px, None, None, flags=flags,
                                                          criteria=criteria)  # fmt: skip
    projector_rms, k_proj, d_proj, _, _ = cv2.calibrateCamera(obj, proj, projector_size_wh_px, None, None,
                                                              flags=flags, criteria=criteria)  # fmt: skip
    stereo_rms, k_cam, d_cam, k_proj, d_proj, rotation, translation, _, _ = cv2.stereoCalibrate(
        obj, cam, proj, k_cam, d_cam, k_proj, d_proj, camera_size_wh_px,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | flags, criteria=criteria,
    )  # fmt: skip
    n_observations = 2 * sum(len(p.points_board_mm) for p in poses)
    model = ProcamModel(
        camera_matrix=k_cam, camera_dist=d_cam.ravel()[:5], camera_size_wh_px=camera_size_wh_px,
        projector_matrix=k_proj, projector_dist=d_proj.ravel()[:5], projector_size_wh_px=projector_size_wh_px,
        r_proj_from_cam=rotation, t_proj_from_cam_mm=translation.ravel(),
    )  # fmt: skip
    results = []
    all_cam, all_proj = [], []
    for p in poses:
        ok, rvec, tvec = cv2.solvePnP(p.points_board_mm, p.camera_q_px, model.camera_matrix, model.camera_dist)
        cam_pred = cv2.projectPoints(p.points_board_mm, rvec, tvec, model.camera_matrix, model.camera_dist)[0]
        points_cam = p.points_board_mm @ cv2.Rodrigues(rvec)[0].T + tvec.ravel()
        rvec_p, _ = cv2.Rodrigues(model.r_proj_from_cam)
        proj_pred = cv2.projectPoints(points_cam, rvec_p, model.t_proj_from_cam_mm, model.projector_matrix,
                                      model.projector_dist)[0]  # fmt: skip
        cam_res = p.camera_q_px - cam_pred.reshape(-1, 2)
        proj_res = p.projector_q_px - proj_pred.reshape(-1, 2)
        all_cam.append(cam_res)
        all_proj.append(proj_res)
        results.append(PoseResult(
            pose=p.pose, camera_rms_px=float(np.sqrt(np.mean(np.sum(cam_res**2, axis=1)))),
            projector_rms_px=float(np.sqrt(np.mean(np.sum(proj_res**2, axis=1)))), camera_q_px=p.camera_q_px,
            camera_residual_px=cam_res, projector_q_px=p.projector_q_px, projector_residual_px=proj_res,
            share_from_edges=float(np.mean(p.from_edges)),
        ))  # fmt: skip
    cam_rms_final = float(np.sqrt(np.mean(np.sum(np.vstack(all_cam) ** 2, axis=1))))
    proj_rms_final = float(np.sqrt(np.mean(np.sum(np.vstack(all_proj) ** 2, axis=1))))
    model = ProcamModel(
        camera_matrix=model.camera_matrix, camera_dist=model.camera_dist, camera_size_wh_px=camera_size_wh_px,
        projector_matrix=model.projector_matrix, projector_dist=model.projector_dist,
        projector_size_wh_px=projector_size_wh_px, r_proj_from_cam=model.r_proj_from_cam,
        t_proj_from_cam_mm=model.t_proj_from_cam_mm, camera_rms_px=cam_rms_final, projector_rms_px=proj_rms_final,
        n_observations=n_observations,
    )  # fmt: skip
    worst = max(results, key=lambda r: max(r.camera_rms_px, r.projector_rms_px))
    checks = [
        check("camera_rms", float(camera_rms), "px", good=0.3, bad=1.0, what="camera reprojection RMS"),
        check("projector_rms", float(projector_rms), "px", good=0.3, bad=1.0, what="projector reprojection RMS"),
        check("stereo_rms", float(stereo_rms), "px", good=0.3, bad=1.0, what="stereo reprojection RMS (both together)"),
        check("worst_pose", max(worst.camera_rms_px, worst.projector_rms_px), "px", good=0.5, bad=1.5,
              what=f"worst pose {worst.pose} RMS (camera {worst.camera_rms_px:.3f} px, projector "
              f"{worst.projector_rms_px:.3f} px)"),
        check("poses", float(len(poses)), "poses", good=6.0, bad=3.0, higher_is_better=True,
              what="chessboard poses used (tilted poses in several directions fix the focal lengths)"),
    ]  # fmt: skip
    return ProcamCalibration(
        model=model, camera_rms_px=float(camera_rms), projector_rms_px=float(projector_rms),
        stereo_rms_px=float(stereo_rms), poses=tuple(results), verdict=verdict_of(checks),
        n_corners=sum(len(p.points_board_mm) for p in poses),
    )  # fmt: skip


def calibrate_procam_from_recordings(
    recordings: Sequence[tuple[str, Sequence[np.ndarray]]],
    *,
    columns: PatternSequence,
    rows: PatternSequence,
    board: Board,
    white_frame: int,
    decode_settings: DecodeSettings | None = None,
    progress: ProgressCallback | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ProcamCalibration:
    """The whole calibration from (pose name, frames) pairs, each pose's frames in the sequences' numbering."""
    poses = []
    size: tuple[int, int] | None = None
    for done, (name, frames) in enumerate(recordings):
        if should_cancel is not None and should_cancel():
            raise Cancelled(f"cancelled after {done} of {len(recordings)} poses")
        shape = np.asarray(frames[0]).shape
        this = (int(shape[1]), int(shape[0]))
        if size is not None and this != size:
            raise ProcamCalibrationError(f"{name}: frames of {this[0]} × {this[1]} px, the other poses' are "
                                         f"{size[0]} × {size[1]} px")  # fmt: skip
        size = this
        poses.append(pose_corners(frames, columns=columns, rows=rows, board=board, pose=name, white_frame=white_frame,
                                  decode_settings=decode_settings))  # fmt: skip
        if progress is not None:
            progress(done + 1, len(recordings) + 1, "poses")
    if size is None:
        raise ProcamCalibrationError("no chessboard poses given")
    return calibrate_procam(poses, camera_size_wh_px=size, projector_size_wh_px=columns.projector_size_wh_px)

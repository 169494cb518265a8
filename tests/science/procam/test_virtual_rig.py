"""The camera–projector science against the virtual digital-projector rig's truth (docs/procam.md): decoding,
the sphere scan and its σ, the calibration from chessboard poses, and the bad input of each step."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fringelab.science.chessboard import Board
from fringelab.science.graycode import (
    DecodingError,
    InverseFrames,
    MeanOf,
    PatternSequence,
    PhaseFrames,
    WhiteBlack,
    binary_from_gray,
    decode,
    gray_from_binary,
)
from fringelab.science.procam import (
    ProcamModel,
    project_to_camera,
    project_to_projector,
    reprojection_of_truth_px,
    triangulate,
)
from fringelab.science.procam_calibration import ProcamCalibrationError, calibrate_procam_from_recordings
from fringelab.science.scan import SOURCE_CODE, SOURCE_EDGE, SOURCE_PHASE, ScanMismatchError, fit_sphere, scan
from fringelab.science.virtual_procam import (
    ChessboardPose,
    Pattern,
    Plane,
    ProcamImaging,
    ProcamRenderer,
    Sphere,
    gray_code_patterns,
    in_frame_order,
)
from tests.procam_rig import POSE_COLUMNS, POSE_ROWS, RIG

SPHERE = Sphere((5.0, 3.0, 290.0), 25.0)
SCREEN = Plane((0.0, 0.0, -1.0), -330.0)
# Columns code: 8 bits of 2 projector px (the finest bit left out), white and black first, 4-step phase last.
COLUMNS = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 10)),
                          band_px=2.0, threshold=WhiteBlack(0, 1),
                          phase=PhaseFrames(frames=(10, 11, 12, 13), period_px=16.0, offset_px=0.0))  # fmt: skip


@pytest.fixture(scope="module")
def renderer() -> ProcamRenderer:
    return ProcamRenderer(RIG)


@pytest.fixture(scope="module")
def sphere_frames(renderer: ProcamRenderer) -> list[np.ndarray]:
    return renderer.render([SPHERE, SCREEN], in_frame_order(gray_code_patterns(COLUMNS)), rng=np.random.default_rng(1))


def test_gray_code_round_trips() -> None:
    values = np.arange(1024)
    assert np.array_equal(binary_from_gray(gray_from_binary(values), 10), values)
    # Neighbours differ in exactly one bit.
    flips = gray_from_binary(values[1:]) ^ gray_from_binary(values[:-1])
    assert np.all(flips & (flips - 1) == 0)


def _true_code(renderer: ProcamRenderer, surfaces: list) -> np.ndarray:
    """The code each camera pixel centre's scene point lies in (−1: none)."""
    width, height = RIG.camera_size_wh_px
    v, u = np.mgrid[0:height, 0:width]
    points = renderer.true_points(surfaces, np.column_stack([u.ravel(), v.ravel()]).astype(float))
    ok = np.isfinite(points[:, 0])
    x = np.full(len(points), np.nan)
    x[ok] = project_to_projector(RIG, points[ok])[:, 0]
    code = np.where(np.isfinite(x), np.floor((x + 0.5) / COLUMNS.band_px), -1)
    return code.reshape(height, width).astype(int)


@pytest.mark.parametrize("mode", ["white-black", "inverse", "mean-of"])
def test_each_threshold_mode_decodes_the_true_code(renderer: ProcamRenderer, mode: str) -> None:
    surfaces = [SCREEN]
    base = gray_code_patterns(COLUMNS)
    bits = [base[i] for i in COLUMNS.gray_frames]
    if mode == "white-black":
        sequence, patterns = COLUMNS, in_frame_order(base)
    elif mode == "inverse":
        inverse = [Pattern("columns", 1.0 - b.values) for b in bits]
        patterns = bits + inverse
        n = len(bits)
        sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(n)),
                                   band_px=2.0, threshold=InverseFrames(tuple(range(n, 2 * n))))  # fmt: skip
    else:
        x = np.arange(320)
        sines = [Pattern("columns", 0.5 + 0.5 * np.cos(2 * np.pi * x / 16.0 - 2 * np.pi * s / 3)) for s in range(3)]
        patterns = sines + bits
        sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(3, 11)),
                                   band_px=2.0, threshold=MeanOf((0, 1, 2)))  # fmt: skip
    frames = renderer.render(surfaces, patterns, rng=np.random.default_rng(2))
    decoding = decode(frames, sequence)
    truth = _true_code(renderer, surfaces)
    valid = decoding.valid
    assert decoding.valid_share > 0.5
    # A valid pixel may straddle a band's edge (its centre in one band, part of it in the next): at most one off.
    assert np.all(np.abs(decoding.code[valid] - truth[valid]) <= 1)
    assert np.mean(decoding.code[valid] == truth[valid]) > 0.97


def test_the_sphere_is_scanned_within_its_tolerance_and_sigma_covers_the_errors(
    renderer: ProcamRenderer, sphere_frames: list[np.ndarray]
) -> None:
    sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=COLUMNS.gray_frames,
                               band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    result = scan(sphere_frames, sequence, RIG)
    edge = result.source == SOURCE_EDGE
    truth = renderer.true_points([SPHERE, SCREEN], result.q_px[edge])
    on_sphere = np.linalg.norm(truth - np.asarray(SPHERE.centre_cam_mm), axis=1) < SPHERE.radius_mm + 1e-6
    error = np.linalg.norm(result.points_cam_mm[edge] - truth, axis=1)
    sigma = result.sigma_mm[edge]
    assert np.count_nonzero(on_sphere) > 3000
    # Issue's tolerance: 0.05 mm RMS on the sphere (measured 0.019 mm).
    rms = float(np.sqrt(np.mean(error[on_sphere] ** 2)))
    assert rms < 0.05, rms
    # ±2σ covers 90–99 % of the errors (measured ~97 % over sphere and screen).
    covered = float(np.mean(error < 2.0 * sigma))
    assert 0.90 <= covered <= 0.99, covered
    # The sphere fitted to the scanned points: centre and radius of the truth.
    centre, radius, _ = fit_sphere(result.points_cam_mm[edge][on_sphere])
    assert abs(radius - SPHERE.radius_mm) < 0.02
    assert np.linalg.norm(centre - np.asarray(SPHERE.centre_cam_mm)) < 0.03
    # Per-pixel code points fill in with a σ that says they are a band wide.
    code = result.source == SOURCE_CODE
    assert np.median(result.sigma_mm[code]) > 20 * np.median(sigma)
    assert np.isfinite(result.depth_z_mm).mean() > 0.5


def test_the_phase_unwrapped_by_the_code_gives_dense_points(
    renderer: ProcamRenderer, sphere_frames: list[np.ndarray]
) -> None:
    result = scan(sphere_frames, COLUMNS, RIG)
    phase = result.source == SOURCE_PHASE
    truth = renderer.true_points([SPHERE, SCREEN], result.q_px[phase])
    error = np.linalg.norm(result.points_cam_mm[phase] - truth, axis=1)
    assert np.count_nonzero(phase) > 0.5 * result.decoding.code.size
    # Phase points at every pixel; away from the sphere's rim (mixed pixels) they are within a few tenths of a mm.
    assert np.median(error) < 0.05
    assert np.percentile(error, 90) < 0.2


def test_recording_and_calibration_of_other_sizes_are_refused(sphere_frames: list[np.ndarray]) -> None:
    small = [f[:200] for f in sphere_frames]
    with pytest.raises(ScanMismatchError, match="360 × 200 px but the calibration's camera is 360 × 270 px"):
        scan(small, COLUMNS, RIG)
    other = PatternSequence(axis="columns", projector_size_wh_px=(640, 200), gray_frames=COLUMNS.gray_frames,
                            band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    with pytest.raises(ScanMismatchError, match=r"projector_size_px \[640, 200\]"):
        scan(sphere_frames, other, RIG)


def test_codes_that_decode_to_nothing_or_beyond_the_projector_are_refused(sphere_frames: list[np.ndarray]) -> None:
    dark = [np.zeros_like(f) for f in sphere_frames]
    with pytest.raises(DecodingError, match="decodes to no valid pixel"):
        decode(dark, COLUMNS)
    narrow = PatternSequence(axis="columns", projector_size_wh_px=(100, 200), gray_frames=COLUMNS.gray_frames,
                             band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    with pytest.raises(DecodingError, match=r"projector_size_px \[100, 200\] is smaller than the code needs"):
        decode(sphere_frames, narrow)
    with pytest.raises(ValueError, match="names frames \\[13\\]"):
        decode(sphere_frames[:13], COLUMNS)


def test_triangulation_meets_the_distorted_projector_column() -> None:
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(-40, 40, 200), rng.uniform(-30, 30, 200), rng.uniform(260, 340, 200)])
    q = project_to_camera(RIG, points)
    x = project_to_projector(RIG, points)[:, 0]
    found, rate = triangulate(RIG, q, x, axis="columns")
    assert np.max(np.linalg.norm(found - points, axis=1)) < 1e-6
    assert np.all(rate > 0)


# ---- calibration ---------------------------------------------------------------------------------------------

CAL_COLUMNS, CAL_ROWS = POSE_COLUMNS, POSE_ROWS
BOARD = Board(cols=9, rows=7, square_mm=8.0)
TILTS_DEG = [(0, 0), (25, 0), (-25, 0), (0, 25), (0, -25), (18, 18), (-18, 15), (15, -18), (-16, -16), (8, -8)]


def _pose(i: int, tilt: tuple[float, float], rng: np.random.Generator) -> ChessboardPose:
    rotation = cv2.Rodrigues(np.deg2rad(np.array([tilt[0], tilt[1], 3.0 * (i % 5) - 6.0])))[0]
    centre = np.array([(BOARD.cols - 1) * BOARD.square_mm / 2, (BOARD.rows - 1) * BOARD.square_mm / 2, 0.0])
    tvec = np.array([rng.uniform(-8, 8), rng.uniform(-6, 6), 290 + 8 * (i % 3)]) - rotation @ centre
    return ChessboardPose(BOARD.cols, BOARD.rows, BOARD.square_mm, tuple(cv2.Rodrigues(rotation)[0].ravel()),
                          tuple(tvec))  # fmt: skip


@pytest.fixture(scope="module")
def rendered_poses() -> list[tuple[ChessboardPose, list[np.ndarray]]]:
    """Each pose (its truth) and its recording."""
    renderer = ProcamRenderer(RIG, imaging=ProcamImaging(supersample=2))
    patterns = in_frame_order(gray_code_patterns(CAL_COLUMNS), gray_code_patterns(CAL_ROWS))
    rng = np.random.default_rng(3)
    out = []
    for i, tilt in enumerate(TILTS_DEG):
        pose = _pose(i, tilt, rng)
        out.append((pose, renderer.render([pose], patterns, rng=rng)))
    return out


@pytest.fixture(scope="module")
def pose_recordings(rendered_poses) -> list[tuple[str, list[np.ndarray]]]:
    return [(f"pose {i}", frames) for i, (_, frames) in enumerate(rendered_poses)]


def _true_corners(pose: ChessboardPose, found_q_px: np.ndarray) -> np.ndarray:
    """The board coordinates (N, 3) of the inner corners found at camera pixels found_q_px (N, 2): each the
    truth's corner whose true camera pixel is nearest (the detector's numbering is its own)."""
    board = pose.inner_corners_board_mm()
    true_q = project_to_camera(RIG, pose.inner_corners_cam_mm())
    nearest = np.argmin(np.linalg.norm(found_q_px[:, None] - true_q[None], axis=2), axis=1)
    return board[nearest]


def test_both_models_are_recovered_from_chessboard_poses_under_gray_code(rendered_poses, pose_recordings) -> None:
    calibration = calibrate_procam_from_recordings(pose_recordings, columns=CAL_COLUMNS, rows=CAL_ROWS, board=BOARD,
                                                   white_frame=0)  # fmt: skip
    assert calibration.verdict.level == "good"
    assert calibration.stereo_rms_px < 0.1
    assert all(p.share_from_edges > 0.8 for p in calibration.poses)
    # Reprojection of the truth over the volume both see, after the rigid motion that takes the truth's camera frame
    # into the recovered one: issue's tolerance 0.02 px RMS (measured 0.007 px camera, 0.017 px projector).
    grid = np.stack(np.meshgrid(np.linspace(-45, 45, 7), np.linspace(-32, 32, 5), np.linspace(270, 330, 4)), -1)
    camera, projector = reprojection_of_truth_px(calibration.model, RIG, grid.reshape(-1, 3))
    assert np.sqrt(np.mean(camera**2)) < 0.02, np.sqrt(np.mean(camera**2))
    assert np.sqrt(np.mean(projector**2)) < 0.02, np.sqrt(np.mean(projector**2))
    assert isinstance(calibration.model, ProcamModel) and np.isfinite(calibration.model.projector_sigma_px)

    # Why the rigid motion, and why it is not a convention offset hidden by it (docs/procam.md §6):
    # 1. The corners the calibration is made of are unbiased: each pose's camera and projector corners against the
    #    truth's pixels of the same board corners, means within 0.015 px (measured ≤ 0.012 px) at an RMS of ~0.035 px.
    #    A pixel-centre convention (0 vs ½), a band_px or Gray-boundary offset, or a pose sign would show here.
    observations = []
    for (pose, _), result in zip(rendered_poses, calibration.poses, strict=True):
        board = _true_corners(pose, result.camera_q_px)
        points = board @ pose.rotation.T + np.asarray(pose.tvec_mm)
        camera_error = result.camera_q_px - project_to_camera(RIG, points)
        projector_error = result.projector_q_px - project_to_projector(RIG, points)
        assert np.all(np.abs(camera_error.mean(axis=0)) < 0.015), (result.pose, camera_error.mean(axis=0))
        assert np.all(np.abs(projector_error.mean(axis=0)) < 0.015), (result.pose, projector_error.mean(axis=0))
        assert np.sqrt(np.mean(np.sum(camera_error**2, axis=1))) < 0.06
        assert np.sqrt(np.mean(np.sum(projector_error**2, axis=1))) < 0.06
        observations.append((board, result.camera_q_px, result.projector_q_px))
    # 2. What 10 poses of a board in the middle of the field fix: the principal point to σ ≈ 0.6–0.8 px (OpenCV's
    #    covariance of these very corners), and a principal point off by δ is the same camera turned by δ/f to
    #    within ~3 % of δ over the field. The recovered intrinsics are off by less than 2.5 of their σ (measured
    #    camera cx −0.30, cy −0.28 px; projector cx −0.80 px, all within 1.1 σ), so the truth's pixels unaligned are
    #    ~0.3–0.4 px RMS (measured 0.42 px camera, 0.34 px projector): the calibration's uncertainty of its camera
    #    frame's orientation, ~1 mrad, not a bias. It moves every measured point together (shapes, radii and plane
    #    fits do not change); 0.02 px unaligned would need ~400 times the poses' information.
    unaligned_camera = np.linalg.norm(project_to_camera(calibration.model, grid.reshape(-1, 3))
                                      - project_to_camera(RIG, grid.reshape(-1, 3)), axis=1)  # fmt: skip
    assert 0.02 < np.sqrt(np.mean(unaligned_camera**2)) < 1.0
    for device, key, size, truth in (("camera", 1, RIG.camera_size_wh_px, RIG.camera_matrix),
                                     ("projector", 2, RIG.projector_size_wh_px, RIG.projector_matrix)):  # fmt: skip
        found = calibration.model.camera_matrix if device == "camera" else calibration.model.projector_matrix
        *_, sigma_intrinsics, _, _ = cv2.calibrateCameraExtended(
            [o[0].astype(np.float32) for o in observations],
            [o[key].astype(np.float32).reshape(-1, 1, 2) for o in observations], size, None, None,
            flags=cv2.CALIB_FIX_K3,
        )  # fmt: skip
        error = (found - truth)[[0, 1, 0, 1], [0, 1, 2, 2]]  # fx, fy, cx, cy
        sigma = sigma_intrinsics.ravel()[:4]
        assert np.all(sigma > 0.3), (device, sigma)  # measured 0.58–0.84 px: what these poses fix
        assert np.all(np.abs(error) < 2.5 * sigma), (device, error, sigma)


def test_a_pose_without_projector_light_is_named(pose_recordings) -> None:
    name, frames = pose_recordings[0]
    unlit = [frames[0]] + [np.full_like(f, 10) for f in frames[1:]]
    recordings = [pose_recordings[1], pose_recordings[2], ("pose 7b", unlit)]
    with pytest.raises(ProcamCalibrationError, match="pose 7b: the projector corners could not be found"):
        calibrate_procam_from_recordings(recordings, columns=CAL_COLUMNS, rows=CAL_ROWS, board=BOARD, white_frame=0)

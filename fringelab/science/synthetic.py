"""Synthetic camera-calibration recordings with known truth: reference cameras and a chessboard renderer.

Belongs here: cameras with the size of distortion in the paper's Table 1, the chessboard renderer (the board
through the Heikkilä model with supersampled edges, blur, uneven illumination and 8-bit noise) and Z-stack
recordings built from it. Whole experiments (stripes on a deforming plate) live in `virtual_test.py`, which may
import from here.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera, camera_centre_obj_mm, fit_inverse_model, ideal_from_pixels, project_points
from .chessboard import Board

# Table 1 of Grytten et al. (2007) gives |k1|, |k2|, |p1|, |p2| and f for its two cameras; the text extraction
# lost the signs, so the reference cameras keep the magnitudes (pincushion on the first, barrel on the second,
# to exercise both) and put the principal point near the image centre with a realistic offset.
_TABLE1_ANGLES_DEG = (153.21, 9.2471, 3.0433)


def reference_camera(size: str = "512x480") -> Camera:
    """A camera of the paper's kind about 2 m above a plate at Z = 0, looking at the object origin.

    size: "512x480" (Kodak-like: D = 96 px/mm, s_v = 1.1337 on v) or "1024x1024" (Phantom-like: D = 212.59 px/mm,
    s_u = 0.9993 on u).
    """
    omega, phi, kappa = np.deg2rad(_TABLE1_ANGLES_DEG)
    common = dict(x0_mm=12.0, y0_mm=-9.0, z0_mm=2000.0, omega_rad=omega, phi_rad=phi, kappa_rad=kappa)
    if size == "512x480":
        return Camera(
            image_width_px=512, image_height_px=480, du_px_per_mm=96.0, dv_px_per_mm=96.0, su=1.1337,
            f_mm=22.8519, u0_px=262.3, v0_px=236.9, k1_per_mm2=0.0022457, k2_per_mm4=2.8207e-5,
            p1_per_mm=0.0039274, p2_per_mm=0.0029374, scale_on="v", **common,
        )  # fmt: skip
    if size == "1024x1024":
        return Camera(
            image_width_px=1024, image_height_px=1024, du_px_per_mm=212.59, dv_px_per_mm=212.59, su=0.9993,
            f_mm=19.6022, u0_px=519.4, v0_px=502.7, k1_per_mm2=-0.0022437, k2_per_mm4=3.9023e-5,
            p1_per_mm=0.00020071, p2_per_mm=0.0046827, scale_on="u", **common,
        )  # fmt: skip
    raise ValueError(f"size: expected '512x480' or '1024x1024', got {size!r}")


@dataclass(frozen=True)
class ImagingConditions:
    """How a rendered frame departs from a perfect image; grey levels are of the 8-bit output."""

    supersampling: int = 8
    blur_sigma_px: float = 0.7
    black_grey: float = 30.0
    white_grey: float = 215.0
    background_grey: float = 110.0
    illumination_falloff: float = 0.25
    illumination_tilt: float = 0.10
    noise_sigma_grey: float = 2.0


@dataclass(frozen=True, eq=False)
class BoardPose:
    """Board frame → object frame: points_obj = rotation · [X_b, Y_b, 0] + translation_mm."""

    rotation: np.ndarray
    translation_mm: np.ndarray


def board_pose_at_z(z_mm: float) -> BoardPose:
    """The pose of a board lying in the plane Z = z_mm, axes along the object axes (a Z-stack frame)."""
    return BoardPose(rotation=np.eye(3), translation_mm=np.array([0.0, 0.0, float(z_mm)]))


def board_corner_points_mm(board: Board) -> np.ndarray:
    """Inner corners of an unrotated board in its own frame, shape (N, 2), ordered as `label_board_corners`."""
    i0 = (board.cols - 1) // 2 if board.origin is None else board.origin[0]
    j0 = (board.rows - 1) // 2 if board.origin is None else board.origin[1]
    j_index, i_index = np.mgrid[0 : board.rows, 0 : board.cols]
    return np.column_stack([(i_index.ravel() - i0), (j_index.ravel() - j0)]).astype(np.float64) * board.square_mm


def _board_pixel_corner_coordinates(
    camera: Camera, pose: BoardPose, ideal_mm: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Board coordinates (X_b, Y_b) where the rays of the pixel-corner grid meet the board plane."""
    ut, vt = ideal_mm
    directions_cam = np.stack([ut, vt, np.full_like(ut, camera.f_mm)], axis=-1)
    to_board = pose.rotation.T
    directions_board = directions_cam @ (to_board @ camera.rotation.T).T
    centre_board = to_board @ (camera_centre_obj_mm(camera) - pose.translation_mm)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -centre_board[2] / directions_board[..., 2]
    lam = np.where(lam > 0, lam, np.nan)
    return centre_board[0] + lam * directions_board[..., 0], centre_board[1] + lam * directions_board[..., 1]


def _reflectance(x_mm: np.ndarray, y_mm: np.ndarray, board: Board, background: float) -> np.ndarray:
    """Chessboard reflectance (0 black, 1 white) at board coordinates; one white square of margin around it."""
    i0 = (board.cols - 1) // 2 if board.origin is None else board.origin[0]
    j0 = (board.rows - 1) // 2 if board.origin is None else board.origin[1]
    # Cell indices counted from the square just outside the lower-left inner corner.
    cell_x = np.floor(x_mm / board.square_mm + i0 + 1)
    cell_y = np.floor(y_mm / board.square_mm + j0 + 1)
    inside = (cell_x >= 0) & (cell_x <= board.cols) & (cell_y >= 0) & (cell_y <= board.rows)
    on_plate = (cell_x >= -1) & (cell_x <= board.cols + 1) & (cell_y >= -1) & (cell_y <= board.rows + 1)
    black = ((cell_x + cell_y) % 2 == 0) & inside
    out = np.where(black, 0.0, 1.0)
    return np.where(on_plate, out, background)


class ChessboardRenderer:
    """Renders a chessboard through a camera; the pixel-corner rays are computed once per camera."""

    def __init__(self, camera: Camera, board: Board, *, conditions: ImagingConditions | None = None) -> None:
        self.camera = camera
        self.board = board
        self.conditions = conditions or ImagingConditions()
        width, height = camera.image_width_px, camera.image_height_px
        corner_u, corner_v = np.meshgrid(np.arange(width + 1) - 0.5, np.arange(height + 1) - 0.5)
        q_px = np.column_stack([corner_u.ravel(), corner_v.ravel()])
        ut, vt = ideal_from_pixels(camera, q_px, inverse=fit_inverse_model(camera))
        self._ideal_mm = (ut.reshape(height + 1, width + 1), vt.reshape(height + 1, width + 1))
        v_norm, u_norm = np.mgrid[0:height, 0:width]
        u_norm = (u_norm - 0.5 * width) / (0.5 * width)
        v_norm = (v_norm - 0.5 * height) / (0.5 * height)
        c = self.conditions
        self._illumination = 1.0 - c.illumination_falloff * 0.5 * (u_norm**2 + v_norm**2) + c.illumination_tilt * u_norm

    def true_corners_px(self, pose: BoardPose) -> np.ndarray:
        """Pixels of the inner corners, shape (N, 2), in `board_corner_points_mm` order."""
        return project_points(self.camera, self.corner_points_obj_mm(pose))

    def corner_points_obj_mm(self, pose: BoardPose) -> np.ndarray:
        """Object coordinates of the inner corners, shape (N, 3)."""
        xy = board_corner_points_mm(self.board)
        return np.column_stack([xy, np.zeros(len(xy))]) @ pose.rotation.T + pose.translation_mm

    def reflectance(self, pose: BoardPose) -> np.ndarray:
        """Noise-free pixel-averaged reflectance, shape (H, W): the area of each pixel covered by white."""
        c = self.conditions
        x_corner, y_corner = _board_pixel_corner_coordinates(self.camera, pose, self._ideal_mm)
        background = (c.background_grey - c.black_grey) / (c.white_grey - c.black_grey)
        corner_value = _reflectance(x_corner, y_corner, self.board, background)
        quad = [corner_value[:-1, :-1], corner_value[:-1, 1:], corner_value[1:, :-1], corner_value[1:, 1:]]
        image = 0.25 * (quad[0] + quad[1] + quad[2] + quad[3])
        # Only pixels whose four corners disagree hold an edge; supersample those. The map from pixel to board
        # is smooth across one pixel, so bilinear interpolation of the corner coordinates is exact to ~1e-6 px.
        mixed = np.nonzero((quad[0] != quad[1]) | (quad[0] != quad[2]) | (quad[0] != quad[3]))
        n = c.supersampling
        offsets = (np.arange(n) + 0.5) / n
        s, t = np.meshgrid(offsets, offsets)
        s, t = s.ravel()[None, :], t.ravel()[None, :]
        rows, cols = mixed[0][:, None], mixed[1][:, None]

        def interpolate(field: np.ndarray) -> np.ndarray:
            top = field[rows, cols] * (1 - s) + field[rows, cols + 1] * s
            bottom = field[rows + 1, cols] * (1 - s) + field[rows + 1, cols + 1] * s
            return top * (1 - t) + bottom * t

        samples = _reflectance(interpolate(x_corner), interpolate(y_corner), self.board, background)
        image[mixed] = samples.mean(axis=1)
        return np.nan_to_num(image, nan=background)

    def render(self, pose: BoardPose, *, rng: np.random.Generator) -> np.ndarray:
        """An 8-bit frame, shape (H, W): reflectance, blur, uneven illumination, Gaussian noise, rounding."""
        c = self.conditions
        image = self.reflectance(pose)
        if c.blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), c.blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
        grey = (c.black_grey + (c.white_grey - c.black_grey) * image) * self._illumination
        grey = grey + rng.normal(0.0, c.noise_sigma_grey, grey.shape)
        return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def render_zstack_frames(
    camera: Camera,
    board: Board,
    z_mm: np.ndarray,
    *,
    rng: np.random.Generator,
    conditions: ImagingConditions | None = None,
) -> list[np.ndarray]:
    """8-bit frames, each shape (H, W), of `board` lying at each height of z_mm, shape (F,): a Z-stack recording."""
    renderer = ChessboardRenderer(camera, board, conditions=conditions)
    return [renderer.render(board_pose_at_z(float(z)), rng=rng) for z in np.asarray(z_mm, dtype=np.float64)]


def zstack_board(camera: Camera, *, square_mm: float = 25.0) -> Board:
    """A glass-plate chessboard covering about 75 % × 60 % of the view of `camera` at its distance z0."""
    fx, fy = (camera.f_mm * scale for scale in camera.pixels_per_mm)
    view_width_mm = camera.image_width_px / fx * camera.z0_mm
    view_height_mm = camera.image_height_px / fy * camera.z0_mm
    return Board(
        cols=int(0.75 * view_width_mm / square_mm), rows=int(0.6 * view_height_mm / square_mm), square_mm=square_mm
    )

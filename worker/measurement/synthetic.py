"""Synthetic camera-calibration recordings with known truth: reference cameras and a chessboard renderer.

Belongs here: cameras with the size of distortion in the paper's Table 1, the chessboard renderer (the board
through the Heikkilä model with supersampled edges, blur, uneven illumination and 8-bit noise) and Z-stack
recordings built from it. Whole experiments (stripes on a deforming plate) live in `simulate.py`, which may
import from here.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera

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

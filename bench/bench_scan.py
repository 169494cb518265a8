"""Benchmark of camera–projector scans (docs/procam.md §3) on one core: decoding, coded edges, triangulation.

Run from the repository root:  .venv/bin/python bench/bench_scan.py [--repeats 3]

Cases: the virtual rig's sphere in front of a screen (360 × 270 px, 8 Gray bits, rendered here, not timed), and the
real scan's rows sequence (1936 × 1464 px, ../shared/data/real_structured_light_sphere) when present. For each it
prints the median time of
  decode     graycode.decode (threshold, bits, validity),
  edges      graycode.coded_edges (fringes.locate_edges on every bit frame, named by the codes),
  scan       science.scan.scan end to end without the per-pixel code points, and with them,
the numbers of points, and the rate of procam.triangulate (points per second).
"""

from __future__ import annotations

import os

for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[variable] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fringelab.formats.patterns import read_patterns_json  # noqa: E402
from fringelab.formats.procam import read_procam_calibration  # noqa: E402
from fringelab.science.graycode import PatternSequence, WhiteBlack, coded_edges, decode  # noqa: E402
from fringelab.science.procam import ProcamModel, triangulate  # noqa: E402
from fringelab.science.scan import ScanSettings, scan  # noqa: E402
from fringelab.science.virtual_procam import (  # noqa: E402
    Plane,
    ProcamRenderer,
    Sphere,
    gray_code_patterns,
    in_frame_order,
    virtual_procam_rig,
)

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real_structured_light_sphere"


def timed(action: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = action()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def bench(name: str, frames: list[np.ndarray], sequence: PatternSequence, model: ProcamModel, repeats: int,
          settings: ScanSettings) -> None:  # fmt: skip
    t_decode, decoding = timed(lambda: decode(frames, sequence), repeats)
    t_edges, edges = timed(lambda: coded_edges(decoding), repeats)
    without = ScanSettings(code_points=False, projector_scale_xy=settings.projector_scale_xy)
    t_scan, result = timed(lambda: scan(frames, sequence, model, settings=without), repeats)
    t_full, full = timed(lambda: scan(frames, sequence, model, settings=settings), 1)
    print(f"{name}: {frames[0].shape[1]} × {frames[0].shape[0]} px, {len(sequence.gray_frames)} bits; "
          f"{100 * decoding.valid_share:.1f} % decoded, {len(edges)} edge points")  # fmt: skip
    print(f"  decode {t_decode:.3f} s   edges {t_edges:.3f} s   scan (edges only) {t_scan:.3f} s "
          f"({len(result)} points)   scan with code points {t_full:.3f} s ({len(full)} points)")  # fmt: skip
    q = np.column_stack([np.tile(np.arange(0, frames[0].shape[1], 2.0), 50), np.repeat(np.linspace(
        10, frames[0].shape[0] - 10, 50), len(np.arange(0, frames[0].shape[1], 2.0)))])  # fmt: skip
    x = np.full(len(q), 0.5 * (model.projector_size_wh_px[0 if sequence.axis == "columns" else 1] - 1))
    t_tri, _ = timed(lambda: triangulate(model, q, x, axis=sequence.axis), repeats)
    print(f"  triangulate {len(q) / t_tri:,.0f} points/s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rig = virtual_procam_rig()
    sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 10)),
                               band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    scene = [Sphere((5.0, 3.0, 290.0), 25.0), Plane((0.0, 0.0, -1.0), -330.0)]
    patterns = in_frame_order(gray_code_patterns(sequence))
    frames = ProcamRenderer(rig).render(scene, patterns, rng=np.random.default_rng(1))
    bench("virtual sphere", frames, sequence, rig, args.repeats, ScanSettings())
    if REAL.is_dir():
        frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((REAL / "rows").glob("*.png"))]
        sequence = read_patterns_json((REAL / "rows" / "patterns.json").read_text(), n_frames=len(frames))
        model = read_procam_calibration(REAL / "calibration.yml")
        bench("real rows scan", frames, sequence, model, args.repeats, ScanSettings(projector_scale_xy=(1.0, 0.5)))
    else:
        print(f"real scan: {REAL.resolve()} not found (it ships only beside the repository)")


if __name__ == "__main__":
    main()

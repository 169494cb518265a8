"""Benchmark of reading high-speed recordings frame by frame: milliseconds per 1024 × 1024 frame, as the
topography reads them (random access, one frame at a time).

    python bench/bench_recordings.py [--frames 30] [--repeats 5]

Formats: Phantom .cine 8/16-bit and packed P10/P12L (unpacked with numpy), Photron MRAW 8/12/16-bit; files
written as the cameras lay them out (tests/formats/recording_files.py). Prints the median over repeats and each
format's ratio to the 16-bit .cine (the plain copy). The target: unpacking costs less than locating a frame's
edges (~40 ms at 1024², bench_topography.py), so packed files do not slow the topography down.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fringelab.formats.recordings import open_recording  # noqa: E402
from tests.formats.recording_files import write_cine, write_mraw  # noqa: E402


def frames_of(bits: int, n: int, size: int = 1024) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    dtype = np.uint8 if bits == 8 else np.uint16
    return [rng.integers(0, 1 << bits, (size, size), dtype=dtype) for _ in range(n)]


def ms_per_frame(path: Path, n: int, repeats: int) -> float:
    times = []
    order = np.random.default_rng(1).permutation(n)
    with open_recording(path) as source:
        for _ in range(repeats):
            start = time.perf_counter()
            for i in order:
                source[int(i)]
            times.append((time.perf_counter() - start) / n * 1000)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    n = args.frames
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        files = {
            "cine 8-bit": write_cine(root / "c8.cine", frames_of(8, n)),
            "cine 16-bit": write_cine(root / "c16.cine", frames_of(12, n), real_bpp=12),
            "cine P10": write_cine(root / "p10.cine", frames_of(10, n), packing="P10"),
            "cine P12L": write_cine(root / "p12.cine", frames_of(12, n), packing="P12L"),
            "mraw 8-bit": write_mraw(root / "m8", frames_of(8, n), bits=8),
            "mraw 12-bit": write_mraw(root / "m12", frames_of(12, n), bits=12),
            "mraw 16-bit": write_mraw(root / "m16", frames_of(12, n), bits=16),
        }
        results = {name: ms_per_frame(path, n, args.repeats) for name, path in files.items()}
    base = results["cine 16-bit"]
    print(f"1024 × 1024 frames, {n} frames in random order, median of {args.repeats}")
    for name, ms in results.items():
        print(f"  {name:12s} {ms:7.2f} ms/frame  ({ms / base:4.1f}× the 16-bit .cine)")


if __name__ == "__main__":
    main()

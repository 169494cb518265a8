"""Benchmark of the structured-light topography, single-threaded: frames per second per core, and peak memory.

    python bench/bench_topography.py [--frames 40] [--memory-frames 20,40,80]
    python bench/bench_topography.py --frames 20 --against 0e4c11a --rounds 3

Times are CPU seconds of this process (`time.process_time`, best of 3 passes): wall time on a shared or virtual
machine swings by a third from run to run. `--against COMMIT` compares this tree with another's: it checks COMMIT out
in a temporary git worktree and runs the speed figures of both trees in separate processes, alternately, `--rounds`
times each (the same renders, this file, each tree's own `fringelab`), then prints each figure's median per tree and
this tree's ratio to COMMIT's.

Reports, for the virtual test at 512 × 480 (kodak) and 1024 × 1024 (phantom):
- edges: `fringes.locate_edges` per frame (the part that runs in parallel chunks);
- order+Z+XY: `topography.track_and_measure` with the test's reference (fringe order of every frame on its own,
  what is missing, table lookup, back-projection) per frame;
- edges+order+Z+XY: both, the figure the targets are about (≥ 100 frames/s/core at 512 × 480, ≥ 25 at
  1024 × 1024);
- the shares of σ_w² (mean over the frames): the edges' own σ, the projector table's fit, the local check's τ²
  and what the frames' checks across edges added (`uncertainty.budget_shares`; the camera is exact here, so it
  has no term);
- gridding: `topography.grid_measurement` per frame (2 mm grid);
- peak memory (tracemalloc, all numpy buffers included) of `topography_recording` over PNG recordings of
  increasing length, read lazily: it must not grow with the frame count;
- edge location bias and noise on straight stripes with known sub-pixel edges (σ = 2 grey levels).
Frames are rendered with one sample per pixel (analytic blur) to keep the set-up short; rendering is not timed.
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from fringelab.formats.recordings import open_recording, write_recording  # noqa: E402
from fringelab.pipelines.topography import topography_recording  # noqa: E402
from fringelab.science.fringes import EdgeSettings, locate_edges  # noqa: E402
from fringelab.science.projector import build_projector_calibration, exact_camera_model  # noqa: E402
from fringelab.science.topography import (  # noqa: E402
    TopographySettings,
    grid_for_first_frame,
    grid_measurement,
    reference_for,
    track_and_measure,
)

try:  # absent from trees older than the σ budget (--against)
    from fringelab.science.uncertainty import budget_shares  # noqa: E402
except ImportError:
    budget_shares = None
from fringelab.science.virtual_test import (  # noqa: E402
    FringeRenderer,
    Imaging,
    preset,
    punch_timeline,
    render_straight_stripes,
)

cv2.setNumThreads(1)


def best_of(repeats: int, function):  # type: ignore[no-untyped-def]
    """The shortest of `repeats` runs (CPU seconds) and the last result: the least disturbed by other load."""
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.process_time()
        result = function()
        best = min(best, time.process_time() - start)
    return best, result


def speed(name: str, n_frames: int) -> dict[str, float]:
    setup = preset(name, imaging=Imaging(supersample=1))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(1)
    z_mm = np.arange(0.0, 80.0 + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    frames = [renderer.render_test(state, rng=rng) for state in punch_timeline(n_frames).states]

    edge_time, edges = best_of(3, lambda: [locate_edges(f, projector.edges) for f in frames])
    reference = reference_for(edges[0], projector, camera, TopographySettings())
    track_time, measurements = best_of(
        3, lambda: list(track_and_measure(edges, projector, camera, reference=reference))
    )
    grid, max_edge_mm = grid_for_first_frame(measurements[0], projector, TopographySettings())
    grid_time, _ = best_of(
        3, lambda: [grid_measurement(m, projector, grid, max_edge_mm=max_edge_mm) for m in measurements]
    )
    n_points = np.mean([len(m.k) for m in measurements])
    shares = [
        budget_shares(m.sigma_z_mm, m.table_sigma_z_mm, m.sigma_scale, m.local_variance_mm2)
        for m in measurements
        if budget_shares is not None and m.sigma_z_mm is not None
    ]
    return {
        "edges": n_frames / edge_time,
        "order+Z+XY": n_frames / track_time,
        "edges+order+Z+XY": n_frames / (edge_time + track_time),
        "gridding": n_frames / grid_time,
        "points per frame": float(n_points),
        "grid nodes": float(grid.shape[0] * grid.shape[1]),
        **({f"σ_w² share {t} %": 100.0 * float(np.mean([f[t] for f in shares])) for t in shares[0]} if shares else {}),
    }


SIZES = (("kodak", "512 x 480"), ("phantom", "1024 x 1024"))
SPEED_FIGURES = ("edges", "order+Z+XY", "edges+order+Z+XY", "gridding")


def compare_with(commit: str, *, n_frames: int, rounds: int) -> None:
    """Print the median speed figures of this tree and of `commit`'s, run alternately in separate processes, and
    this tree's ratio to `commit`'s (> 1: faster)."""
    here = Path(__file__).resolve().parents[1]
    runs: dict[str, list[dict[str, dict[str, float]]]] = {"this tree": [], commit: []}
    with tempfile.TemporaryDirectory() as folder:
        other = Path(folder) / "tree"
        subprocess.run(["git", "-C", str(here), "worktree", "add", "--detach", "-q", str(other), commit], check=True)
        try:
            trees = {"this tree": here, commit: other}
            for _ in range(rounds):
                for label, tree in trees.items():
                    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": str(Path(folder) / label)}
                    out = subprocess.run([sys.executable, __file__, "--frames", str(n_frames), "--speed-json"],
                                         env=env, check=True, capture_output=True, text=True).stdout  # fmt: skip
                    run = json.loads(out.splitlines()[-1])
                    if Path(run.pop("tree")) != tree.resolve():
                        raise SystemExit(f"the run for {label} imported fringelab from elsewhere than {tree}")
                    runs[label].append(run)
        finally:
            subprocess.run(["git", "-C", str(here), "worktree", "remove", "--force", str(other)], check=False)
    for _, size in SIZES:
        medians = {
            label: {k: statistics.median(r[size][k] for r in rs) for k in SPEED_FIGURES} for label, rs in runs.items()
        }
        print(f"{size}, median of {rounds} alternated runs, frames per CPU second: " + "; ".join(
            f"{k} {medians['this tree'][k]:.1f} vs {medians[commit][k]:.1f} ({commit}), ratio "
            f"{medians['this tree'][k] / medians[commit][k]:.2f}" for k in SPEED_FIGURES))  # fmt: skip
        each = {label: ", ".join(f"{r[size]['edges+order+Z+XY']:.1f}" for r in rs) for label, rs in runs.items()}
        print(f"{size}, each run's edges+order+Z+XY: " + "; ".join(f"{k} {v}" for k, v in each.items()))


def peak_memory(name: str, frame_counts: list[int]) -> dict[int, float]:
    setup = preset(name, imaging=Imaging(supersample=1))
    renderer = FringeRenderer(setup)
    rng = np.random.default_rng(2)
    z_mm = np.arange(0.0, 80.0 + 1e-9, 2.0)
    camera = exact_camera_model(setup.camera)
    projector = build_projector_calibration([renderer.render_flat(z, rng=rng) for z in z_mm], z_mm, camera)
    peaks = {}
    with tempfile.TemporaryDirectory() as folder:
        for n in frame_counts:
            states = punch_timeline(n).states
            recording = write_recording(Path(folder) / f"test{n}", (renderer.render_test(s, rng=rng) for s in states))
            tracemalloc.start()
            topography_recording(open_recording(recording), camera, projector, out_path=Path(folder) / f"r{n}.h5")
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            peaks[n] = peak / 2**20
    return peaks


def edge_bias_and_noise() -> dict[str, float]:
    rng = np.random.default_rng(3)
    errors_raw, errors = [], []
    for angle in (0.0, 7.0, 20.0):
        for phase in np.linspace(0.0, 1.0, 5, endpoint=False):
            image = render_straight_stripes((240, 256), period_px=10.0, angle_deg=angle, phase_px=phase, rng=rng)
            theta = np.deg2rad(angle)
            normal = np.array([np.cos(theta), np.sin(theta)])
            for smoothing, sink in ((0.0, errors_raw), (3.0, errors)):
                edges = locate_edges(image, EdgeSettings(axis="rows", period_px=10.0 / np.cos(theta),
                                                         edge_smoothing_lines=smoothing))  # fmt: skip
                x = edges.q_px() @ normal - phase
                sink.append(((x / 5.0 - np.round(x / 5.0)) * 5.0) / normal[0])
    raw, smooth = np.concatenate(errors_raw), np.concatenate(errors)
    return {
        "bias raw px": float(np.mean(raw)),
        "noise raw px": float(np.std(raw)),
        "bias smoothed px": float(np.mean(smooth)),
        "noise smoothed px": float(np.std(smooth)),
        "max |error| smoothed px": float(np.max(np.abs(smooth))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--memory-frames", default="20,40,80")
    parser.add_argument("--against", metavar="COMMIT", help="compare the speed with COMMIT's tree (see above)")
    parser.add_argument("--rounds", type=int, default=3, help="alternated runs of each tree with --against")
    parser.add_argument("--speed-json", action="store_true", help=argparse.SUPPRESS)  # one run of --against
    args = parser.parse_args()
    if args.speed_json:
        import fringelab

        figures = {size: speed(name, args.frames) for name, size in SIZES}
        print(json.dumps({"tree": str(Path(fringelab.__file__).resolve().parents[1]), **figures}))
        return
    print("single-threaded (OMP/OPENBLAS/MKL = 1, cv2.setNumThreads(1)); frames per CPU second")
    if args.against:
        compare_with(args.against, n_frames=args.frames, rounds=args.rounds)
        return
    for name, size in SIZES:
        figures = speed(name, args.frames)
        print(f"{size}: " + "; ".join(f"{k} {v:.1f}" for k, v in figures.items()))
    counts = [int(n) for n in args.memory_frames.split(",")]
    for name, size in SIZES:
        peaks = peak_memory(name, counts)
        print(f"{size}: peak traced memory of topography_recording: " + ", ".join(
            f"{n} frames {mb:.0f} MiB" for n, mb in peaks.items()))  # fmt: skip
    print("edge location on known stripes (period 10 px, σ = 2 grey, blur 0.7 px): " + "; ".join(
        f"{k} {v:+.4f}" if "bias" in k else f"{k} {v:.4f}" for k, v in edge_bias_and_noise().items()))  # fmt: skip


if __name__ == "__main__":
    main()

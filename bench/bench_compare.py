"""Benchmark of `fringelab compare`: reading a simulation state by state and comparing it with a topography.

Run from the repository root:  .venv/bin/python bench/bench_compare.py [--repeats 3] [--frames 8]

It renders a small virtual test (Kodak preset, --frames test frames; not timed), measures its topography,
writes the true surface as a simulation in every format (about 13 000 nodes, one state per frame) and prints, per
format, the median over the repeats of
  open      open_simulation (mesh, times, punch and force; no state),
  state     reading one state's displacements (median over the states),
  compare   the whole compare_result (mapping, alignment, origin, sampling on the 2 mm grid, file written),
  per frame compare / frames,
and the ratio compare / topography (the measurement's own time for the same frames). Target: a frame compared in
under 0.25 s on one core, well under what measuring it takes.
"""

from __future__ import annotations

import os

for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[variable] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fringelab.formats.camera import read_camera_json  # noqa: E402
from fringelab.formats.recordings import open_recording  # noqa: E402
from fringelab.formats.simulations import open_simulation  # noqa: E402
from fringelab.pipelines.comparison import compare_result  # noqa: E402
from fringelab.pipelines.projector_calibration import calibrate_projector_recording  # noqa: E402
from fringelab.pipelines.topography import topography_recording  # noqa: E402
from fringelab.pipelines.virtual_test import SIMULATION_WRITERS, write_true_simulation, write_virtual_test  # noqa: E402
from fringelab.science.virtual_test import calibration_heights_mm  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=8)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_compare_") as folder:
        root = Path(folder) / "kodak"
        experiment = write_virtual_test(root, "kodak", n_test_frames=args.frames,
                                         calibration_z_mm=calibration_heights_mm(4.0),
                                         camera_z_mm=(-20.0, 40.0, 100.0), seed=3)  # fmt: skip
        camera = read_camera_json(experiment.camera_json)
        projector = calibrate_projector_recording(open_recording(experiment.projector_calibration), camera)
        start = time.perf_counter()
        result = topography_recording(open_recording(experiment.test), camera, projector, out_path=root / "r.h5")
        topography_s = time.perf_counter() - start
        print(f"topography of {args.frames} frames: {topography_s:.2f} s ({topography_s / args.frames:.3f} s/frame)")
        print(f"{'format':8s} {'open s':>8s} {'state s':>8s} {'compare s':>10s} {'per frame s':>12s} {'ratio':>6s}")
        for kind in SIMULATION_WRITERS:
            if kind == "d3plot":
                try:
                    import lasso  # noqa: F401
                except ImportError:
                    print(f"{kind:8s} skipped: pip install 'fringelab[lsdyna]'")
                    continue
            simulation = write_true_simulation(experiment.truth_json, Path(folder) / kind, kind=kind)
            opened, states, compared = [], [], []
            for _ in range(args.repeats):
                start = time.perf_counter()
                results = open_simulation(simulation)
                opened.append(time.perf_counter() - start)
                for state in range(results.n_states):
                    start = time.perf_counter()
                    results.displacement(state)
                    states.append(time.perf_counter() - start)
                start = time.perf_counter()
                compare_result(result.path, simulation, Path(folder) / f"{kind}.h5")
                compared.append(time.perf_counter() - start)
            median = statistics.median(compared)
            print(f"{kind:8s} {statistics.median(opened):8.3f} {statistics.median(states):8.4f} {median:10.2f} "
                  f"{median / args.frames:12.3f} {median / topography_s:6.2f}")  # fmt: skip


if __name__ == "__main__":
    main()

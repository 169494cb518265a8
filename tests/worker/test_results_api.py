"""The topography results API on a result file in the documented layout (fringelab/formats/topography.py),
with a field whose answers are known exactly: a tilted plane rising frame by frame (bilinear interpolation of a
plane is exact), and a hole without data."""

from __future__ import annotations

import math
import os

import h5py
import numpy as np
import pytest

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job

Z_FLAT_MM = 1.5
X_MM = np.arange(-100.0, 100.0 + 1e-9, 2.0)  # 101 nodes
Y_MM = np.arange(-60.0, 60.0 + 1e-9, 2.0)  # 61 nodes
FRAMES = np.array([10, 11, 12, 13])
# float32 storage (≈ 4e-6 mm at these magnitudes) and the API's rounding to 1e-4 mm bound every comparison
TOLERANCE_MM = 2e-4


def plane_w_mm(frame: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.05 * (frame - 10) * (x + 100.0) + 0.01 * y


def sigma_w_mm(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """σ_w of the test's result: linear in x and y (bilinear sampling gives it back exactly), the same every frame."""
    return 0.02 + 1e-4 * (x + 100.0) + 5e-5 * (y + 100.0)


def write_result(path) -> None:
    y, x = np.meshgrid(Y_MM, X_MM, indexing="ij")
    with h5py.File(path, "w") as out:
        out.attrs["schema"] = "fringelab.topography"
        out.attrs["z_flat_mm"] = Z_FLAT_MM
        out["frames/index"] = FRAMES
        out["frames/time_s"] = (FRAMES - 10) * 1e-3
        out["frames/punch_displacement_mm"] = (FRAMES - 10) * 2.0
        out["frames/force_kN"] = np.full(FRAMES.shape, np.nan)
        out["grid/x_mm"], out["grid/y_mm"] = X_MM, Y_MM
        z = np.stack([Z_FLAT_MM + plane_w_mm(f, x, y) for f in FRAMES]).astype(np.float32)
        z[:, 30:34, 50:54] = np.nan  # a hole: nodes X, Y = 0..6 mm
        out.create_dataset("grid/z_mm", data=z, chunks=(1, *z.shape[1:]))
        sigma = np.where(np.isnan(z), np.nan, sigma_w_mm(x, y)).astype(np.float32)
        out.create_dataset("grid/sigma_w_mm", data=sigma, chunks=(1, *z.shape[1:]))
        out["peak/w_mm"] = np.nanmax(z.reshape(len(FRAMES), -1), axis=1) - Z_FLAT_MM
        out["peak/x_mm"] = np.full(FRAMES.shape, 100.0)
        out["peak/y_mm"] = np.full(FRAMES.shape, 60.0)
        out.create_group("summary").attrs["flat_rms_mm"] = 0.01


@pytest.fixture
def job_id(settings) -> str:
    directory = settings.data_path / "results" / "jobs" / "topo-1"
    directory.mkdir(parents=True)
    write_result(directory / "topography.h5")
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        entry = {"name": "topography.h5", "path": "results/jobs/topo-1/topography.h5", "size_bytes": 1,
                 "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
        session.add(Job(id="topo-1", kind="topography", state="succeeded", files=[entry]))
        session.add(Job(id="topo-2", kind="topography", state="running"))
        session.commit()
    engine.dispose()
    return "topo-1"


def test_overview_lists_frames_with_the_test_log_and_peaks(client, job_id):
    body = client.get(f"/api/v1/jobs/{job_id}/topography").json()
    assert body["frames"] == FRAMES.tolist()
    assert body["punch_displacement_mm"] == [0.0, 2.0, 4.0, 6.0]
    assert body["force_kN"] == [None] * 4  # not logged: null, not NaN
    assert body["peak_w_mm"][-1] == pytest.approx(plane_w_mm(13, 100.0, 60.0), abs=TOLERANCE_MM)
    assert body["grid"] == {"x_min_mm": -100.0, "x_max_mm": 100.0, "y_min_mm": -60.0, "y_max_mm": 60.0,
                            "nx": 101, "ny": 61, "step_mm": 2.0}  # fmt: skip
    assert body["summary"] == {"flat_rms_mm": 0.01}
    # A result written without coverage (an older file): unknown, never "all measured".
    assert body["measured_fraction"] == [None] * 4 and body["peak_measured"] == [None] * 4
    assert set(body["missing_mm2"]) == {"hole", "shadow", "low_contrast", "order_unresolved", "order_conflict",
                                        "out_of_range", "uneven_light"}  # fmt: skip
    # each reason named for a legend, with what it covers ("hole" is anything as black as the background)
    assert set(body["missing_reasons"]) == set(body["missing_mm2"])
    assert "punch" in body["missing_reasons"]["hole"]["label"] and body["missing_reasons"]["hole"]["description"]


def test_a_grid_is_block_averaged_to_the_budget_and_a_window_is_full_resolution(client, job_id):
    cut = client.get(f"/api/v1/jobs/{job_id}/topography/grid", params={"frame": 12, "budget": 25}).json()
    assert cut["step"] == 5  # ceil(101 / 25)
    w = np.array(cut["w_mm"], dtype=float)
    assert w.shape == (13, 21)  # ceil(61 / 5), ceil(101 / 5)
    y, x = np.meshgrid(Y_MM, X_MM, indexing="ij")
    full = plane_w_mm(12, x, y)
    full[30:34, 50:54] = np.nan
    block = full[5:10, 10:15]  # the block mean of a plane is the plane at the block centre
    assert w[1, 2] == pytest.approx(np.nanmean(block), abs=TOLERANCE_MM)
    assert cut["x_mm"][2] == pytest.approx(X_MM[10:15].mean()) and cut["y_mm"][1] == pytest.approx(Y_MM[5:10].mean())
    assert np.isfinite(w[6, 10])  # the 5 x 5 block holding part of the hole still has data

    window = {"frame": 12, "x_min": 0, "x_max": 10, "y_min": 0, "y_max": 10}
    zoom = client.get(f"/api/v1/jobs/{job_id}/topography/grid", params=window).json()
    assert zoom["step"] == 1 and zoom["x_mm"] == [0, 2, 4, 6, 8, 10] and zoom["y_mm"] == [0, 2, 4, 6, 8, 10]
    assert zoom["w_mm"][4][5] == pytest.approx(plane_w_mm(12, 10.0, 8.0), abs=TOLERANCE_MM)
    assert zoom["w_mm"][1][1] is None  # node (2, 2) mm lies in the hole

    raw = client.get(f"/api/v1/jobs/{job_id}/topography/grid", params=window | {"format": "f32"})
    assert raw.headers["content-type"] == "application/octet-stream"
    assert raw.headers["x-grid-shape"] == "6,6" and raw.headers["x-grid-x-mm"] == "0,2"
    values = np.frombuffer(raw.content, dtype="<f4").reshape(6, 6)
    assert np.isnan(values[1, 1])
    np.testing.assert_allclose(values[4], zoom["w_mm"][4], atol=TOLERANCE_MM)


def test_profiles_and_histories_sample_the_grid(client, job_id):
    line = {"x0_mm": -90.0, "y0_mm": -50.0, "x1_mm": 90.0, "y1_mm": 40.0, "n_points": 7}
    body = client.get(f"/api/v1/jobs/{job_id}/topography/profile", params=line | {"frames": [13, 11]}).json()
    old_names = {"x0": -90.0, "y0": -50.0, "x1": 90.0, "y1": 40.0, "n_points": 7, "frames": [13, 11]}
    assert client.get(f"/api/v1/jobs/{job_id}/topography/profile", params=old_names).json() == body  # deprecated
    half = client.get(f"/api/v1/jobs/{job_id}/topography/profile", params={"x0_mm": 1.0, "frames": [13]})
    assert half.status_code == 422 and "y0_mm, x1_mm, y1_mm" in half.json()["detail"]
    assert body["s_mm"][-1] == pytest.approx(math.hypot(180.0, 90.0))
    assert [p["frame"] for p in body["profiles"]] == [13, 11]
    x, y = np.array(body["x_mm"]), np.array(body["y_mm"])
    np.testing.assert_allclose(body["profiles"][0]["w_mm"], plane_w_mm(13, x, y), atol=TOLERANCE_MM)
    np.testing.assert_allclose(body["profiles"][1]["sigma_w_mm"], sigma_w_mm(x, y), atol=TOLERANCE_MM)

    history = client.get(f"/api/v1/jobs/{job_id}/topography/history", params={"x_mm": 33.3, "y_mm": -7.1}).json()
    assert history["frames"] == FRAMES.tolist() and history["time_s"] == [0.0, 0.001, 0.002, 0.003]
    np.testing.assert_allclose(history["w_mm"], [plane_w_mm(f, 33.3, -7.1) for f in FRAMES], atol=TOLERANCE_MM)
    np.testing.assert_allclose(history["sigma_w_mm"], [sigma_w_mm(33.3, -7.1)] * 4, atol=TOLERANCE_MM)
    in_hole = client.get(f"/api/v1/jobs/{job_id}/topography/history", params={"x_mm": 3.0, "y_mm": 1.0}).json()
    assert in_hole["w_mm"] == [None] * 4 and in_hole["sigma_w_mm"] == [None] * 4


def test_bad_result_requests_say_what_is_wrong(client, job_id):
    base = f"/api/v1/jobs/{job_id}/topography"
    missing_frame = client.get(f"{base}/grid", params={"frame": 3})
    assert missing_frame.status_code == 422
    assert missing_frame.json() == {"detail": "frame 3 is not in this result (frames 10..13)",
                                    "code": "frame_not_in_result", "field": "frame"}  # fmt: skip
    outside = client.get(f"{base}/history", params={"x_mm": 500, "y_mm": 0})
    assert outside.status_code == 422 and outside.json()["code"] == "outside_grid"
    assert "-100..100 mm" in outside.json()["detail"]
    half_window = client.get(f"{base}/grid", params={"frame": 10, "x_min": 0})
    assert half_window.status_code == 422 and half_window.json()["code"] == "incomplete_window"
    running = client.get("/api/v1/jobs/topo-2/topography")
    assert running.status_code == 409 and running.json()["code"] == "job_not_succeeded"
    assert client.get("/api/v1/jobs/nope/topography").status_code == 404


def test_a_peak_not_measured_is_no_peak_but_a_lower_bound_with_its_reason(client, settings):
    directory = settings.data_path / "results" / "jobs" / "topo-3"
    directory.mkdir(parents=True)
    path = directory / "topography.h5"
    write_result(path)
    with h5py.File(path, "a") as out:  # frame 12: data missing within the punch radius of its maximum
        out["peak/measured"] = np.array([1, 1, 0, 1], np.int8)
        out["peak/missing_nodes"] = np.array([0, 0, 12, 0], np.int32)
        out["peak/missing_nodes"].attrs["radius_mm"] = 10.0
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        entry = {"name": "topography.h5", "path": "results/jobs/topo-3/topography.h5", "size_bytes": 1,
                 "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
        session.add(Job(id="topo-3", kind="topography", state="succeeded", files=[entry]))
        session.commit()
    engine.dispose()
    body = client.get("/api/v1/jobs/topo-3/topography").json()
    assert body["peak_measured"] == [True, True, False, True]
    assert body["peak_w_mm"][2] is None and body["peak_w_mm"][3] is not None
    assert body["peak_w_lower_bound_mm"][2] == pytest.approx(plane_w_mm(12, 100.0, 60.0), abs=TOLERANCE_MM)
    assert body["peak_w_lower_bound_mm"][:2] == [None, None]
    assert body["peak_reason"][2] == (
        "data missing within 10 mm of the maximum (12 grid nodes): the value is a lower bound"
    )
    assert body["peak_reason"][0] is None
    # the test log has no force: said, and the plots' titles follow what the recording has
    assert body["log_columns"] == ["time_s", "punch_displacement_mm"]
    assert body["notes"] == ["no force for any frame: the recording has no frames.csv with those columns"]


def register_result(settings, job_id: str, measured: list[int], *, peak_shift_mm: float = 0.0) -> None:
    """A result of `write_result` as job `job_id`, with peak/measured flags and its peaks shifted."""
    directory = settings.data_path / "results" / "jobs" / job_id
    directory.mkdir(parents=True)
    path = directory / "topography.h5"
    write_result(path)
    with h5py.File(path, "a") as out:
        out["peak/w_mm"][...] += peak_shift_mm
        out["peak/measured"] = np.array(measured, np.int8)
        out["peak/missing_nodes"] = np.where(np.array(measured) == 1, 0, 9).astype(np.int32)
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        entry = {"name": "topography.h5", "path": f"results/jobs/{job_id}/topography.h5", "size_bytes": 1,
                 "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
        session.add(Job(id=job_id, kind="topography", state="succeeded", files=[entry]))
        session.commit()
    engine.dispose()


def test_camera_against_camera_leaves_out_what_either_did_not_measure(client, settings):
    register_result(settings, "cam-a", [1, 1, 0, 1])
    register_result(settings, "cam-b", [1, 0, 1, 1], peak_shift_mm=0.5)
    body = client.get("/api/v1/jobs/cam-a/topography/against/cam-b").json()
    assert body["aligned_by"] == "time" and body["other_frame"] == [10, 11, 12, 13]
    assert body["compared"] == [True, False, False, True]
    assert body["difference_w_mm"][0] == pytest.approx(-0.5, abs=TOLERANCE_MM)
    assert body["difference_w_mm"][1:3] == [None, None] and body["peak_w_mm"][1:3] == [None, None]
    assert body["left_out_frames"] == [
        {"frame": 11, "reason": "the other camera did not measure the peak at this instant"},
        {"frame": 12, "reason": "this camera did not measure the peak (a lower bound)"},
    ]
    assert body["n_compared"] == 2 and body["largest_difference_mm"] == pytest.approx(0.5, abs=TOLERANCE_MM)
    missing = client.get("/api/v1/jobs/cam-a/topography/against/no-such-job")
    assert missing.status_code == 404


def test_a_result_written_again_is_read_again_not_from_the_frames_kept(client, job_id, settings):
    """Each web server process keeps the frames it read (FRINGELAB_FRAME_CACHE_BYTES), by the file's identity
    (device, inode, size, modification time): a result written again and renamed into place is read anew, and one
    deleted is gone (410), never answered from the frames kept of the old file."""
    base = f"/api/v1/jobs/{job_id}/topography"
    line = {"x0_mm": -90.0, "y0_mm": -50.0, "x1_mm": 90.0, "y1_mm": 40.0, "frames": [12]}
    first = client.get(f"{base}/profile", params=line | {"n_points": 7}).json()
    x, y = np.array(first["x_mm"]), np.array(first["y_mm"])
    np.testing.assert_allclose(first["profiles"][0]["w_mm"], plane_w_mm(12, x, y), atol=TOLERANCE_MM)
    frames = client.app.state.fringelab.frames
    assert frames.held_bytes > 0  # frame 12 (and its σ) kept
    path = settings.data_path / "results" / "jobs" / "topo-1" / "topography.h5"
    again = path.with_name("again.h5")
    write_result(again)
    with h5py.File(again, "r+") as result:  # the same layout and size, every height 1 mm higher
        result["grid/z_mm"][...] = result["grid/z_mm"][()] + np.float32(1.0)
    os.replace(again, path)
    # Another line than before (no rendered answer kept for it): frame 12 must come from the new file.
    moved = client.get(f"{base}/profile", params=line | {"n_points": 5}).json()
    x, y = np.array(moved["x_mm"]), np.array(moved["y_mm"])
    np.testing.assert_allclose(moved["profiles"][0]["w_mm"], plane_w_mm(12, x, y) + 1.0, atol=TOLERANCE_MM)
    window = {"frame": 12, "x_min": 0, "x_max": 10, "y_min": 0, "y_max": 10, "format": "f32"}
    values = np.frombuffer(client.get(f"{base}/grid", params=window).content, dtype="<f4").reshape(6, 6)
    assert values[4, 5] == pytest.approx(plane_w_mm(12, 10.0, 8.0) + 1.0, abs=TOLERANCE_MM)
    path.unlink()
    gone = client.get(f"{base}/profile", params=line | {"n_points": 6})
    assert gone.status_code == 410 and gone.json()["code"] == "result_missing", gone.text


def test_a_grid_or_profile_asked_again_with_its_etag_is_304_and_a_result_written_again_is_not(client, job_id, settings):
    """A result never changes once its job succeeded: a grid or profile carries an ETag of the file's identity and
    the question, and asked again with it is answered 304 without a body (nothing read or rendered); another
    question, another encoding or a result written again gets its own tag and the full answer."""
    base = f"/api/v1/jobs/{job_id}/topography"
    grid = {"frame": 12, "budget": 25}
    first = client.get(f"{base}/grid", params=grid)
    tag = first.headers["etag"]
    assert first.status_code == 200 and first.headers["cache-control"] == "private, no-cache", first.headers
    again = client.get(f"{base}/grid", params=grid, headers={"If-None-Match": tag})
    assert (again.status_code, again.content, again.headers["etag"]) == (304, b"", tag)
    assert client.get(f"{base}/grid", params=grid | {"frame": 13}, headers={"If-None-Match": tag}).status_code == 200
    plain = client.get(f"{base}/grid", params=grid, headers={"If-None-Match": tag, "Accept-Encoding": "identity"})
    assert plain.status_code == 200 and plain.headers["etag"] != tag  # the other representation
    line = {"x0_mm": -90.0, "y0_mm": -50.0, "x1_mm": 90.0, "y1_mm": 40.0, "frames": [12]}
    profile = client.get(f"{base}/profile", params=line).headers["etag"]
    assert client.get(f"{base}/profile", params=line, headers={"If-None-Match": profile}).status_code == 304
    path = settings.data_path / "results" / "jobs" / "topo-1" / "topography.h5"
    written = path.with_name("again.h5")
    write_result(written)
    os.replace(written, path)
    anew = client.get(f"{base}/grid", params=grid, headers={"If-None-Match": tag})
    assert anew.status_code == 200 and anew.headers["etag"] != tag and anew.json()["frame"] == 12


def test_the_frames_kept_stay_within_their_bytes(tmp_path):
    """The frame cache holds at most its bytes (least recently used out first) and never one frame over an eighth
    of them, so one huge frame cannot flush the rest."""
    from fringelab.formats.hdf5 import FrameCache

    cache = FrameCache(max_bytes=8 * 4000)
    reads: list[int] = []

    def read(i: int, size: int = 1000) -> np.ndarray:
        reads.append(i)
        return np.full(size, i, dtype=np.float32)  # 4000 bytes

    for i in range(10):
        cache.get_or_read(("file", i), lambda i=i: read(i))
    assert cache.held_bytes == 8 * 4000 and reads == list(range(10))
    assert cache.get_or_read(("file", 9), lambda: read(99))[0] == 9 and reads[-1] == 9  # kept
    cache.get_or_read(("file", 0), lambda: read(0))
    assert reads[-1] == 0  # the oldest went first
    kept = cache.get_or_read(("file", "big"), lambda: read(-1, size=2000))
    assert kept.nbytes == 8000 and cache.held_bytes == 8 * 4000 and not kept.flags.writeable
    cache.get_or_read(("file", "big"), lambda: read(-2, size=2000))
    assert reads[-1] == -2  # over an eighth of the bound: never kept


def test_a_result_opened_again_is_checked_and_its_grid_read_once_per_file(job_id, settings):
    """What every reader reads first (schema, grid axes, frame indices, z_flat) comes from the frame cache for a
    file the process has read before, by the file's identity, and a profile of frames kept opens no file: a result
    written again is read anew, and one written again while a reader reads it is refused, never mixed."""
    from fringelab.formats.hdf5 import FrameCache
    from fringelab.formats.topography import ResultUnavailable, TopographyResult

    path = settings.data_path / "results" / "jobs" / "topo-1" / "topography.h5"
    cache = FrameCache(max_bytes=1 << 20)
    with TopographyResult(path, frame_cache=cache) as first:
        misses = cache.misses
        assert misses == 4 and first.z_flat_mm == Z_FLAT_MM and not first.grid.x_mm.flags.writeable
    with TopographyResult(path, frame_cache=cache) as again:
        assert (cache.misses, cache.hits) == (misses, 4)
        np.testing.assert_array_equal(again.frames, FRAMES)
        first_profile = again.profile([12], (-90.0, -50.0, 90.0, 40.0), n_points=5)  # reads frame 12 and its σ
    with TopographyResult(path, frame_cache=cache) as cached:
        profile = cached.profile([12], (-90.0, -50.0, 90.0, 40.0), n_points=5)
        assert cached._open is None  # everything it read was kept: the file was never opened
        np.testing.assert_array_equal(profile["profiles"][0]["w_mm"], first_profile["profiles"][0]["w_mm"])
    written = path.with_name("again.h5")
    write_result(written)
    with h5py.File(written, "r+") as result:
        result.attrs["z_flat_mm"] = Z_FLAT_MM + 1.0
    with TopographyResult(path, frame_cache=cache) as racing:
        os.replace(written, path)  # written again between the reader's start and its first read of the file
        with pytest.raises(ResultUnavailable, match="written again"):
            racing.profile([13], (-90.0, -50.0, 90.0, 40.0), n_points=5)
    misses = cache.misses
    with TopographyResult(path, frame_cache=cache) as anew:
        assert anew.z_flat_mm == Z_FLAT_MM + 1.0 and cache.misses == misses + 4  # its header read anew

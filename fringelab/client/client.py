"""The client: experiments and cameras, resumable uploads (tus 1.0), jobs followed by their event stream,
topography results as numpy arrays, exports and result files downloaded with their checksums checked.

Everything goes through the documented HTTP API (`/api/openapi.json`); method names follow its operation ids
(`create_job`, `get_topography_grid`). Errors: `ApiError` (the server refused: status, `code`, `detail`),
`JobFailed` (a job ended failed or cancelled, with its error), `ClientError` (anything else to act on).
"""

from __future__ import annotations

import base64
import hashlib
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

TUS = {"Tus-Resumable": "1.0.0"}
FINAL_STATES = ("succeeded", "failed", "cancelled")
Log = Callable[[str], None]


# The API's largest grid budget (nodes per side): what get_topography_grid asks for the result grid itself.
RESULT_GRID_MAX_NODES = 2000


class ClientError(Exception):
    """Something the user must act on; the message says what."""


class ApiError(ClientError):
    """The server refused a request: `status` (HTTP), `code` and `detail` from its `{"detail", "code"}` body;
    `body` the whole answer (e.g. `job_id` of a `duplicate_job`)."""

    def __init__(self, method: str, path: str, status: int, body: dict[str, Any]) -> None:
        self.status, self.body = status, body
        self.code = str(body.get("code", "")) or f"http_{status}"
        self.detail = str(body.get("detail", "")) or "no reason given"
        super().__init__(f"{method} {path} answered HTTP {status} ({self.code}): {self.detail}")


class JobFailed(ClientError):
    """A job ended failed or cancelled; `job` is its last state (its `error` says why)."""

    def __init__(self, job: dict[str, Any]) -> None:
        self.job = job
        super().__init__(f"{job['kind']} job {job['id']} {job['state']}: {job.get('error') or 'no reason given'}")


class _ServerTrouble(Exception):
    """A 5xx during an upload: worth a retry after a pause."""


@dataclass(frozen=True)
class Grid:
    """One frame of a topography on (part of) its grid: w_mm (ny, nx) float32 with NaN where no data, x_mm (nx,),
    y_mm (ny,) in mm in the object frame; step: grid nodes per returned node (1 at full resolution)."""

    frame: int
    x_mm: np.ndarray
    y_mm: np.ndarray
    w_mm: np.ndarray
    step: int


def _nan_array(values: list[float | None], dtype: Any = np.float64) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=dtype)


class Client:
    """A session with a fringelab server.

    server: the base URL you open the dashboard at (with any proxy sub-path), e.g. "http://lab:8000". token: an
    API token (`fringelab token create ...`), or None on a laptop with accounts off. log: where progress lines go
    (uploads resuming, job stages); default: nowhere. Use as a context manager, or call `close()`.
    """

    def __init__(
        self, server: str, token: str | None = None, *, timeout_s: float = 60.0, log: Log | None = None
    ) -> None:
        self.server = server.rstrip("/")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.server, headers=headers, timeout=timeout_s)
        self.log: Log = log or (lambda _line: None)
        self.upload_resumes = 0
        self._drop_after_bytes: int | None = None
        self._sent_bytes = 0

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.http.close()

    # ------------------------------------------------------------------------------------------ plumbing

    def _checked(self, response: httpx.Response, *expected: int) -> httpx.Response:
        if response.status_code not in (expected or (200,)):
            try:
                body = response.json()
            except ValueError:
                body = {"detail": response.text[:200]}
            request = response.request
            raise ApiError(
                request.method, request.url.path, response.status_code, body if isinstance(body, dict) else {}
            )
        return response

    def _get(self, path: str, **params: Any) -> Any:
        return self._checked(self.http.get(path, params={k: v for k, v in params.items() if v is not None})).json()

    def _send(self, method: str, path: str, body: dict[str, Any], *expected: int) -> Any:
        response = self._checked(self.http.request(method, path, json=body), *expected)
        return response.json() if response.content else None

    # ------------------------------------------------------------------------------------------ accounts

    def get_me(self) -> dict[str, Any]:
        return self._get("/api/v1/auth/me")

    # ------------------------------------------------------------------------------------------ experiments

    def create_experiment(self, name: str, **fields: Any) -> dict[str, Any]:
        return self._send("POST", "/api/v1/experiments", {"name": name, **fields}, 201)

    def list_experiments(self) -> list[dict[str, Any]]:
        answer = self._get("/api/v1/experiments")
        return answer["items"] if isinstance(answer, dict) and "items" in answer else answer

    def get_experiment(self, experiment_id: int) -> dict[str, Any]:
        return self._get(f"/api/v1/experiments/{experiment_id}")

    def create_camera(self, experiment_id: int, name: str, **fields: Any) -> dict[str, Any]:
        """A camera of an experiment; fields as the API takes them (image_width_px, image_height_px,
        pixel_pitch_um, ...)."""
        return self._send("POST", f"/api/v1/experiments/{experiment_id}/cameras", {"name": name, **fields}, 201)

    def list_cameras(self, experiment_id: int) -> list[dict[str, Any]]:
        return self._get(f"/api/v1/experiments/{experiment_id}/cameras")

    # ------------------------------------------------------------------------------------------ recordings

    def get_recording(self, recording_id: int) -> dict[str, Any]:
        return self._get(f"/api/v1/recordings/{recording_id}")

    def upload_recording(
        self, path: str | Path, *, camera_id: int, kind: str, chunk_bytes: int = 8 << 20, retries: int = 8
    ) -> int:
        """Upload a recording file (a ZIP of frames, TIFF, video, .cine) with the resumable tus protocol; its
        recording id. A dropped connection or a server error is retried from the offset the server has (HEAD),
        with a growing pause, up to `retries` times in a row."""
        path = Path(path)
        size = path.stat().st_size
        metadata = ",".join(
            f"{key} {base64.b64encode(str(value).encode()).decode()}"
            for key, value in {
                "filename": path.name,
                "filetype": "application/octet-stream",
                "camera_id": camera_id,
                "kind": kind,
            }.items()  # fmt: skip
        )
        created = self.http.post(
            "/api/v1/uploads", headers={**TUS, "Upload-Length": str(size), "Upload-Metadata": metadata}
        )
        location = self._checked(created, 201).headers["Location"]
        upload_id = location.rstrip("/").rsplit("/", 1)[1]
        offset: int | None = 0  # None: unknown after a failure, ask the server
        failures = 0
        with path.open("rb") as file:
            while True:
                try:
                    if offset is None:
                        offset = self._upload_offset(location)
                        self.log(f"  {path.name}: resuming at byte {offset} of {size}")
                    if offset >= size:
                        return self._recording_of_upload(upload_id)
                    file.seek(offset)
                    response = self._patch(location, offset, file.read(chunk_bytes))
                    if response.status_code >= 500:
                        raise _ServerTrouble(f"HTTP {response.status_code}")
                    self._checked(response, 204)
                    offset = int(response.headers["Upload-Offset"])
                    failures = 0
                    if "Fringelab-Recording-Id" in response.headers:
                        return int(response.headers["Fringelab-Recording-Id"])
                except (httpx.TransportError, _ServerTrouble) as error:
                    failures += 1
                    if failures > retries:
                        raise ClientError(f"uploading {path.name}: gave up after {retries} retries ({error})") from None
                    self.log(f"  {path.name}: connection lost ({error})")
                    time.sleep(min(30.0, 0.5 * 2 ** (failures - 1)))  # a server restarting, a network coming back
                    offset = None
                    self.upload_resumes += 1

    def simulate_upload_drop(self, after_bytes: int) -> None:
        """Testing aid: cut the upload connection once, after `after_bytes` bytes of uploads from now."""
        self._drop_after_bytes = self._sent_bytes + after_bytes

    def _patch(self, location: str, offset: int, data: bytes) -> httpx.Response:
        headers = {**TUS, "Upload-Offset": str(offset), "Content-Type": "application/offset+octet-stream"}
        drop_at = self._drop_after_bytes
        if drop_at is not None and self._sent_bytes + len(data) > drop_at:
            self._drop_after_bytes = None
            keep = max(0, drop_at - self._sent_bytes)
            self._sent_bytes += keep
            headers["Content-Length"] = str(len(data))  # the server expects all of it and gets only `keep` bytes
            return self.http.patch(location, headers=headers, content=_cut_after(data, keep))
        response = self.http.patch(location, headers=headers, content=data)
        self._sent_bytes += len(data)
        return response

    def _upload_offset(self, location: str) -> int:
        response = self.http.head(location, headers=TUS)
        if response.status_code == 404:
            raise ClientError(f"the server no longer has upload {location} (expired or removed); upload it again")
        return int(self._checked(response).headers["Upload-Offset"])

    def _recording_of_upload(self, upload_id: str) -> int:
        """The recording of a finished upload whose last answer was lost."""
        found = self._get("/api/v1/recordings", upload_id=upload_id)
        items = found["items"] if isinstance(found, dict) else found
        if not items:
            raise ClientError(f"upload {upload_id} is complete but the server made no recording of it")
        return int(items[0]["id"])

    def wait_recording(self, recording_id: int, *, timeout_s: float = 3600.0, poll_s: float = 0.5) -> dict[str, Any]:
        """The recording once its ingest has ended (`ready`); ClientError with the reason when it is invalid."""
        deadline = time.monotonic() + timeout_s
        while True:
            recording = self.get_recording(recording_id)
            if recording["state"] == "ready":
                return recording
            if recording["state"] == "invalid":
                raise ClientError(
                    f"recording {recording_id} ({recording['filename']}) is invalid: {recording['error']}"
                )
            if time.monotonic() > deadline:
                raise ClientError(f"recording {recording_id} is still {recording['state']} after {timeout_s:.0f} s")
            time.sleep(poll_s)

    # ------------------------------------------------------------------------------------------ jobs

    def create_job(self, spec: dict[str, Any], *, reuse_running: bool = False) -> dict[str, Any]:
        """Queue a job. An identical job still queued or running answers 409 `duplicate_job`: with reuse_running
        that job is returned instead of the error."""
        try:
            return self._send("POST", "/api/v1/jobs", spec, 201)
        except ApiError as error:
            if reuse_running and error.code == "duplicate_job" and error.body.get("job_id"):
                return self.get_job(str(error.body["job_id"]))
            raise

    def get_job(self, job_id: str) -> dict[str, Any]:
        return self._get(f"/api/v1/jobs/{job_id}")

    def cancel_job(self, job_id: str) -> dict[str, Any]:
        return self._send("POST", f"/api/v1/jobs/{job_id}/cancel", {}, 200, 202)

    def wait_job(self, job_id: str, *, timeout_s: float = 6 * 3600.0) -> dict[str, Any]:
        """Follow a job's progress from its event stream (polling if the stream breaks) until it ends; the
        succeeded job, or JobFailed. Each change of stage or percentage goes to `log`."""
        deadline = time.monotonic() + timeout_s
        try:
            self._follow_events(job_id, deadline=deadline)
        except (httpx.TransportError, ValueError) as error:  # a proxy cutting long streams, say: poll instead
            self.log(f"  progress stream interrupted ({error}); polling")
        job = self._poll_until_final(job_id, deadline=deadline)
        if job["state"] != "succeeded":
            raise JobFailed(job)
        return job

    def run_job(self, spec: dict[str, Any], *, timeout_s: float = 6 * 3600.0) -> dict[str, Any]:
        """create_job, then wait_job: the succeeded job."""
        job = self.create_job(spec)
        self.log(describe_job(job))
        return self.wait_job(job["id"], timeout_s=timeout_s)

    def _follow_events(self, job_id: str, *, deadline: float) -> None:
        last = ""
        timeout = httpx.Timeout(30.0, read=max(1.0, deadline - time.monotonic()))
        with self.http.stream(
            "GET", f"/api/v1/jobs/{job_id}/events", headers={"Accept": "text/event-stream"}, timeout=timeout
        ) as response:
            if response.status_code != 200:
                response.read()
                self._checked(response)
            for event, data in server_sent_events(response.iter_lines()):
                if event == "job":
                    line = describe_job(json.loads(data))
                    if line != last:
                        self.log(f"  {line}")
                        last = line
                elif event == "end" or time.monotonic() > deadline:
                    return

    def _poll_until_final(self, job_id: str, *, deadline: float) -> dict[str, Any]:
        last = ""
        while True:
            job = self.get_job(job_id)
            if job["state"] in FINAL_STATES and not job.get("stopping"):
                return job
            if time.monotonic() > deadline:
                raise ClientError(f"{job['kind']} job {job_id} did not end in time ({describe_job(job)})")
            if (line := describe_job(job)) != last:
                self.log(f"  {line}")
                last = line
            time.sleep(1.0)

    def download_job_files(self, job: dict[str, Any], out_dir: str | Path) -> list[Path]:
        """Every file of a job into out_dir, streamed and checked against the SHA-256 the server lists."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        return [self.download_file(entry, out_dir / Path(entry["name"]).name) for entry in job["files"]]

    def download_file(self, entry: dict[str, Any], target: str | Path) -> Path:
        """One listed file (`{"url", "sha256", ...}` of a job) to `target`; ClientError if its SHA-256 differs."""
        target = Path(target)
        digest = hashlib.sha256()
        with self.http.stream("GET", self.server + entry["url"]) as response:  # root-relative URL: base + url
            if response.status_code != 200:
                response.read()
                self._checked(response)
            with target.open("wb") as file:
                for block in response.iter_bytes():
                    digest.update(block)
                    file.write(block)
        if digest.hexdigest() != entry["sha256"]:
            raise ClientError(f"{entry['url']}: the download's SHA-256 differs from the server's; download it again")
        self.log(f"  saved {target} ({entry['size_bytes']} bytes)")
        return target

    # ------------------------------------------------------------------------------------------ results

    def get_topography(self, job_id: str) -> dict[str, Any]:
        """The overview of a topography job: frames, time_s, punch displacement, force and peak per frame (lists
        as the API gives them; see `topography_series` for numpy arrays)."""
        return self._get(f"/api/v1/jobs/{job_id}/topography")

    def topography_series(self, job_id: str) -> dict[str, np.ndarray]:
        """The per-frame columns of a topography as numpy arrays (None → NaN; frames as int64)."""
        overview = self.get_topography(job_id)
        series: dict[str, np.ndarray] = {}
        for name, values in overview.items():
            if isinstance(values, list) and values and all(v is None or isinstance(v, int | float) for v in values):
                series[name] = np.array(values, np.int64) if name == "frames" else _nan_array(values)
        return series

    def get_topography_grid(self, job_id: str, frame: int, *, display: bool = False, **params: Any) -> Grid:
        """One frame's deflection on the result grid as numpy arrays (the server's f32 binary answer, no JSON
        parsing): the grid the result holds (step 1), up to RESULT_GRID_MAX_NODES nodes per side (a larger grid is
        block-averaged to that, and `step` says so). display=True: the dashboard's block-averaged display grid
        (at most 250 nodes per side) instead. params as the API takes them (budget, x_min, ... for a zoom
        window)."""
        if not display:
            params.setdefault("budget", RESULT_GRID_MAX_NODES)
        response = self._checked(
            self.http.get(f"/api/v1/jobs/{job_id}/topography/grid", params={"frame": frame, **params, "format": "f32"})
        )
        headers = response.headers
        ny, nx = (int(v) for v in headers["X-Grid-Shape"].split(","))
        w_mm = np.frombuffer(response.content, dtype="<f4").reshape(ny, nx).astype(np.float32)
        x0, dx = (float(v) for v in headers["X-Grid-X-mm"].split(","))  # first node, step
        y0, dy = (float(v) for v in headers["X-Grid-Y-mm"].split(","))
        return Grid(frame=frame, x_mm=x0 + dx * np.arange(nx), y_mm=y0 + dy * np.arange(ny), w_mm=w_mm,
                    step=int(headers.get("X-Grid-Step", "1")))  # fmt: skip

    def get_topography_history(self, job_id: str, x_mm: float, y_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """(frames, w_mm) at one object point over every frame; NaN where the grid has no data."""
        answer = self._get(f"/api/v1/jobs/{job_id}/topography/history", x_mm=x_mm, y_mm=y_mm)
        return np.array(answer["frames"], np.int64), _nan_array(answer["w_mm"])

    def get_topography_profile(
        self, job_id: str, frames: list[int], line_mm: tuple[float, float, float, float], *, n_points: int = 200
    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """(s_mm, {frame: w_mm}) along the line (x0_mm, y0_mm, x1_mm, y1_mm); NaN where the grid has no data."""
        x0, y0, x1, y1 = line_mm
        answer = self._get(f"/api/v1/jobs/{job_id}/topography/profile", x0_mm=x0, y0_mm=y0, x1_mm=x1, y1_mm=y1,
                           frames=frames, n_points=n_points)  # fmt: skip
        return _nan_array(answer["s_mm"]), {int(p["frame"]): _nan_array(p["w_mm"]) for p in answer["profiles"]}

    def export(self, topography_job_id: str, fmt: str, out_dir: str | Path, **options: Any) -> list[Path]:
        """Run an export job of a topography (fmt: points-csv, grid-npz, mat, vtk, profile-csv) and download
        its files into out_dir; their paths."""
        job = self.run_job({"kind": "export", "job_id": topography_job_id, "format": fmt, **options})
        return self.download_job_files(job, out_dir)


def describe_job(job: dict[str, Any]) -> str:
    """One line: kind, id, state, stage and progress."""
    progress = job["progress"]
    share = (
        f" {100 * progress['fraction']:.0f}% ({progress['done']}/{progress['total']})"
        if progress["fraction"] is not None
        else ""
    )
    return f"{job['kind']} {job['id'][:8]}: {job['state']}, {progress['stage'] or 'waiting'}{share}"


def server_sent_events(lines: Iterator[str]) -> Iterator[tuple[str, str]]:
    """(event, data) of a text/event-stream, per the HTML standard's parsing rules (comments skipped)."""
    event, data = "message", list[str]()
    for line in lines:
        if not line:
            if data:
                yield event, "\n".join(data)
            event, data = "message", []
        elif not line.startswith(":"):
            name, _, value = line.partition(":")
            value = value.removeprefix(" ")
            if name == "event":
                event = value
            elif name == "data":
                data.append(value)


class _SimulatedDrop(httpx.WriteError):
    """The testing aid's cut connection."""


def _cut_after(data: bytes, keep: int) -> Iterator[bytes]:
    yield data[:keep]
    raise _SimulatedDrop(f"simulated connection drop after {keep} bytes of this request")

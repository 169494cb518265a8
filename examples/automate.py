#!/usr/bin/env python3
"""The whole fringelab round trip from a script, through the HTTP API only (httpx and the standard library).

    python examples/automate.py --server http://lab-server:8000 --token flb_... \\
        --recordings virtual/ --out results/

1. checks the token (`GET /api/v1/auth/me`);
2. creates an experiment and a camera (image size and pixel pitch from RECORDINGS/truth/experiment.json, as
   `fringelab simulate` writes it, or from --image-size and --pixel-pitch-um);
3. uploads RECORDINGS/camera_calibration, projector_calibration and test (folders are zipped first, ZIPs go as
   they are) with the resumable tus protocol: a dropped connection is resumed from the offset the server has
   (`HEAD`), not started again;
4. waits for each recording's ingest (`ready`, or the reason it is `invalid`);
5. runs the camera calibration, the projector calibration and the topography, printing each job's stage and
   progress as the server streams it (Server-Sent Events; polling if the stream breaks);
6. exports the topography (--export, default grid-npz) and downloads every result file into OUT, checking each
   against the SHA-256 the server lists; OUT/summary.json names what was made (ids, files, peak deflections).

Any failure (refused request, invalid recording, failed job) prints one readable line on stderr and exits 1.
`--simulate-drop-after-bytes N` is a testing aid: the upload connection is cut once, after N bytes of the
uploads have been sent, to show that the upload resumes.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import json
import os
import sys
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

KINDS = ("camera_calibration", "projector_calibration", "test")
TUS = {"Tus-Resumable": "1.0.0"}
FINAL_STATES = ("succeeded", "failed", "cancelled")
EXPORT_FORMATS = ("points-csv", "grid-npz", "mat", "vtk", "profile-csv")


class Failed(Exception):
    """Something the user must act on; the message says what."""


class SimulatedDrop(httpx.WriteError):
    """The connection cut by --simulate-drop-after-bytes."""


class ServerTrouble(Exception):
    """A 5xx answer to a PATCH (a proxy timing out, a server restarting): worth resuming like a dropped line."""


# ---------------------------------------------------------------------------------------------- HTTP helpers


def api_error(response: httpx.Response) -> Failed:
    """A Failed naming the request and the server's `{"detail", "code"}`."""
    try:
        body = response.json()
        reason = f"{body['detail']} ({body['code']})"
    except (ValueError, KeyError, TypeError):
        reason = response.text[:300] or response.reason_phrase
    request = response.request
    return Failed(f"{request.method} {request.url.path} answered HTTP {response.status_code}: {reason}")


def checked(response: httpx.Response, *expected: int) -> httpx.Response:
    if response.status_code not in (expected or (200,)):
        raise api_error(response)
    return response


class Client:
    """The API at one server with one token."""

    def __init__(self, server: str, token: str | None, *, timeout_s: float = 60) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=server.rstrip("/"), headers=headers, timeout=timeout_s)

    def get(self, path: str, **kwargs: Any) -> Any:
        return checked(self.http.get(path, **kwargs)).json()

    def post(self, path: str, body: dict[str, Any], *expected: int) -> Any:
        return checked(self.http.post(path, json=body), *(expected or (200, 201))).json()


# ---------------------------------------------------------------------------------------------- inputs


def camera_from_truth(recordings: Path) -> dict[str, Any]:
    """Image size, pixel pitch and scale axis of the virtual camera, from `fringelab simulate`'s ground truth."""
    path = recordings / "truth" / "experiment.json"
    if not path.is_file():
        return {}
    camera = json.loads(path.read_text())["camera"]
    return {
        "image_width_px": int(camera["image_width_px"]),
        "image_height_px": int(camera["image_height_px"]),
        "pixel_pitch_um": 1000.0 / float(camera["du_px_per_mm"]),
        "scale_on": camera.get("scale_on", "u"),
    }


def recording_file(recordings: Path, kind: str, work_dir: Path) -> Path:
    """RECORDINGS/<kind>.zip as it is, or RECORDINGS/<kind>/ zipped (frames and sidecars at the top level)."""
    as_zip = recordings / f"{kind}.zip"
    if as_zip.is_file():
        return as_zip
    folder = recordings / kind
    if not folder.is_dir():
        raise Failed(f"{recordings} has neither {kind}.zip nor a folder {kind}/")
    target = work_dir / f"{kind}.zip"
    with zipfile.ZipFile(target, "w", zipfile.ZIP_STORED) as archive:  # frames are PNG/TIFF: already compressed
        for path in sorted(folder.iterdir()):
            if path.is_file():
                archive.write(path, path.name)
    return target


# ---------------------------------------------------------------------------------------------- tus upload


def tus_metadata(**items: object) -> str:
    return ",".join(f"{key} {base64.b64encode(str(value).encode()).decode()}" for key, value in items.items())


class Uploader:
    """A tus 1.0 client: create, PATCH in chunks, and after a network error ask the offset and go on from there."""

    def __init__(
        self, client: Client, *, chunk_bytes: int, retries: int = 8, drop_after_bytes: int | None = None
    ) -> None:
        self.client = client
        self.chunk_bytes = chunk_bytes
        self.retries = retries
        self.drop_after_bytes = drop_after_bytes  # the testing aid: cut the connection once, here
        self.sent_bytes = 0
        self.resumes = 0

    def upload(self, path: Path, *, camera_id: int, kind: str) -> int:
        """Upload `path` as a recording of `kind`; its recording id."""
        size = path.stat().st_size
        metadata = tus_metadata(filename=path.name, filetype="application/zip", camera_id=camera_id, kind=kind)
        created = self.client.http.post(
            "/api/v1/uploads", headers={**TUS, "Upload-Length": str(size), "Upload-Metadata": metadata}
        )
        location = checked(created, 201).headers["Location"]
        upload_id = location.rstrip("/").rsplit("/", 1)[1]
        offset: int | None = 0  # None: unknown after a failure, ask the server
        failures = 0
        with path.open("rb") as file:
            while True:
                try:
                    if offset is None:
                        offset = self._offset(location)
                        print(f"  {path.name}: resuming at byte {offset} of {size}", flush=True)
                    if offset >= size:
                        return self._recording_of(upload_id)
                    file.seek(offset)
                    response = self._patch(location, offset, file.read(self.chunk_bytes))
                    if response.status_code >= 500:
                        raise ServerTrouble(f"HTTP {response.status_code}")
                    checked(response, 204)
                    offset = int(response.headers["Upload-Offset"])
                    failures = 0
                    if "Fringelab-Recording-Id" in response.headers:
                        return int(response.headers["Fringelab-Recording-Id"])
                except (httpx.TransportError, ServerTrouble) as error:
                    failures += 1
                    if failures > self.retries:
                        raise Failed(f"uploading {path.name}: gave up after {self.retries} retries ({error})") from None
                    print(f"  {path.name}: connection lost ({error})", flush=True)
                    time.sleep(min(30.0, 0.5 * 2 ** (failures - 1)))  # a server restarting, a network coming back
                    offset = None
                    self.resumes += 1

    def _patch(self, location: str, offset: int, data: bytes) -> httpx.Response:
        headers = {**TUS, "Upload-Offset": str(offset), "Content-Type": "application/offset+octet-stream"}
        drop_at = self.drop_after_bytes
        if drop_at is not None and self.sent_bytes + len(data) > drop_at:
            self.drop_after_bytes = None
            keep = max(0, drop_at - self.sent_bytes)
            self.sent_bytes += keep
            headers["Content-Length"] = str(len(data))  # the server expects all of it and gets only `keep` bytes
            return self.client.http.patch(location, headers=headers, content=_cut_after(data, keep))
        response = self.client.http.patch(location, headers=headers, content=data)
        self.sent_bytes += len(data)
        return response

    def _offset(self, location: str) -> int:
        response = self.client.http.head(location, headers=TUS)
        if response.status_code == 404:
            raise Failed(f"the server no longer has upload {location} (expired or removed); upload it again")
        return int(checked(response).headers["Upload-Offset"])

    def _recording_of(self, upload_id: str) -> int:
        """The recording of a finished upload whose last answer was lost."""
        found = self.client.get("/api/v1/recordings", params={"upload_id": upload_id})
        if not found:
            raise Failed(f"upload {upload_id} is complete but the server made no recording of it")
        return int(found[0]["id"])


def _cut_after(data: bytes, keep: int) -> Iterator[bytes]:
    yield data[:keep]
    raise SimulatedDrop(f"simulated connection drop after {keep} bytes of this request")


def wait_ready(client: Client, recording_id: int, *, timeout_s: float) -> dict[str, Any]:
    """The recording once its ingest has ended; Failed with the reason when it is invalid."""
    deadline = time.monotonic() + timeout_s
    while True:
        recording = client.get(f"/api/v1/recordings/{recording_id}")
        if recording["state"] == "ready":
            return recording
        if recording["state"] == "invalid":
            raise Failed(f"recording {recording_id} ({recording['filename']}) is invalid: {recording['error']}")
        if time.monotonic() > deadline:
            raise Failed(f"recording {recording_id} is still {recording['state']} after {timeout_s:.0f} s")
        time.sleep(0.5)


# ---------------------------------------------------------------------------------------------- jobs


def describe(job: dict[str, Any]) -> str:
    progress = job["progress"]
    share = (
        f" {100 * progress['fraction']:.0f}% ({progress['done']}/{progress['total']})"
        if progress["fraction"] is not None
        else ""
    )
    return f"{job['kind']} {job['id'][:8]}: {job['state']}, {progress['stage'] or 'waiting'}{share}"


def run_job(client: Client, spec: dict[str, Any], *, timeout_s: float) -> dict[str, Any]:
    """Start a job, print its progress until it ends; the succeeded job, or Failed with its error."""
    job = client.post("/api/v1/jobs", spec, 201)
    print(describe(job), flush=True)
    deadline = time.monotonic() + timeout_s
    try:
        follow_events(client, job["id"], deadline=deadline)
    except (httpx.TransportError, ValueError) as error:  # a proxy cutting long streams, say: poll instead
        print(f"  progress stream interrupted ({error}); polling", flush=True)
    job = poll_until_final(client, job["id"], deadline=deadline)
    if job["state"] != "succeeded":
        raise Failed(f"{job['kind']} job {job['id']} {job['state']}: {job['error'] or 'no reason given'}")
    return job


def follow_events(client: Client, job_id: str, *, deadline: float) -> None:
    """Print the job's progress from its Server-Sent Events until the `end` event (or the deadline)."""
    last = ""
    timeout = httpx.Timeout(30.0, read=max(1.0, deadline - time.monotonic()))
    with client.http.stream(
        "GET", f"/api/v1/jobs/{job_id}/events", headers={"Accept": "text/event-stream"}, timeout=timeout
    ) as response:
        if response.status_code != 200:
            response.read()
            raise api_error(response)
        for event, data in server_sent_events(response.iter_lines()):
            if event == "job":
                line = describe(json.loads(data))
                if line != last:
                    print(f"  {line}", flush=True)
                    last = line
            elif event == "end" or time.monotonic() > deadline:
                return


def server_sent_events(lines: Iterator[str]) -> Iterator[tuple[str, str]]:
    """(event, data) of a text/event-stream, per the HTML standard's parsing rules (comments skipped)."""
    event, data = "message", []
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


def poll_until_final(client: Client, job_id: str, *, deadline: float) -> dict[str, Any]:
    last = ""
    while True:
        job = client.get(f"/api/v1/jobs/{job_id}")
        if job["state"] in FINAL_STATES and not job.get("stopping"):
            return job
        if time.monotonic() > deadline:
            raise Failed(f"{job['kind']} job {job_id} did not end in time ({describe(job)}); it keeps running")
        if (line := describe(job)) != last:
            print(f"  {line}", flush=True)
            last = line
        time.sleep(1.0)


def download_files(client: Client, job: dict[str, Any], out_dir: Path) -> list[dict[str, Any]]:
    """Every file of the job into out_dir/<kind>/, streamed and checked against the listed SHA-256."""
    target_dir = out_dir / job["kind"]
    target_dir.mkdir(parents=True, exist_ok=True)
    saved = []
    for entry in job["files"]:
        target = target_dir / Path(entry["name"]).name
        digest = hashlib.sha256()
        with client.http.stream("GET", entry["url"]) as response:
            if response.status_code != 200:
                response.read()
                raise api_error(response)
            with target.open("wb") as file:
                for block in response.iter_bytes():
                    digest.update(block)
                    file.write(block)
        if digest.hexdigest() != entry["sha256"]:
            raise Failed(f"{entry['url']}: the download's SHA-256 differs from the server's; download it again")
        print(f"  saved {target} ({entry['size_bytes']} bytes)", flush=True)
        saved.append({**entry, "path": str(target)})
    return saved


# ---------------------------------------------------------------------------------------------- the round trip


def run(args: argparse.Namespace) -> dict[str, Any]:
    client = Client(args.server, args.token)
    me = client.get("/api/v1/auth/me")
    print(f"fringelab at {args.server} as {me['username']} ({me['role']})", flush=True)
    camera = camera_from_truth(args.recordings)
    for name in ("image_width_px", "image_height_px", "pixel_pitch_um", "scale_on"):
        if getattr(args, name) is not None:
            camera[name] = getattr(args, name)
    missing = [name for name in ("image_width_px", "image_height_px", "pixel_pitch_um") if name not in camera]
    if missing:
        raise Failed(f"no {', '.join(missing)}: give --image-size and --pixel-pitch-um (no truth/experiment.json)")

    experiment = client.post("/api/v1/experiments", {"name": args.experiment_name}, 201)
    camera_row = client.post(
        f"/api/v1/experiments/{experiment['id']}/cameras",
        {"name": args.camera_name, **{k: camera[k] for k in ("image_width_px", "image_height_px", "pixel_pitch_um")}},
        201,
    )
    print(f"experiment {experiment['id']}, camera {camera_row['id']} ({args.camera_name})", flush=True)

    uploader = Uploader(client, chunk_bytes=args.chunk_bytes, drop_after_bytes=args.simulate_drop_after_bytes)
    recordings: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="fringelab-upload-") as work:
        for kind in KINDS:
            path = recording_file(args.recordings, kind, Path(work))
            print(f"uploading {path.name} ({path.stat().st_size} bytes) as {kind}", flush=True)
            recording_id = uploader.upload(path, camera_id=camera_row["id"], kind=kind)
            recordings[kind] = wait_ready(client, recording_id, timeout_s=args.job_timeout_s)
            print(f"  recording {recording_id} ready: {recordings[kind]['frame_count']} frames", flush=True)

    timeout = args.job_timeout_s
    camera_spec = {"kind": "camera_calibration", "recording_id": recordings["camera_calibration"]["id"]}
    if camera.get("scale_on"):
        camera_spec["scale_on"] = camera["scale_on"]
    camera_job = run_job(client, camera_spec, timeout_s=timeout)
    camera_calibration_id = camera_job["result"]["calibration_id"]
    projector_job = run_job(
        client,
        {
            "kind": "projector_calibration",
            "camera_calibration_id": camera_calibration_id,
            "recording_id": recordings["projector_calibration"]["id"],
        },
        timeout_s=timeout,
    )
    projector_calibration_id = projector_job["result"]["calibration_id"]
    topography_job = run_job(
        client,
        {
            "kind": "topography",
            "recording_id": recordings["test"]["id"],
            "camera_calibration_id": camera_calibration_id,
            "projector_calibration_id": projector_calibration_id,
        },
        timeout_s=timeout,
    )
    exports = [
        run_job(client, {"kind": "export", "job_id": topography_job["id"], "format": name}, timeout_s=timeout)
        for name in args.export
    ]
    overview = client.get(f"/api/v1/jobs/{topography_job['id']}/topography")

    args.out.mkdir(parents=True, exist_ok=True)
    jobs = [camera_job, projector_job, topography_job, *exports]
    files = {job["id"]: download_files(client, job, args.out) for job in jobs}
    summary = {
        "server": args.server,
        "experiment_id": experiment["id"],
        "camera_id": camera_row["id"],
        "recordings": {kind: recording["id"] for kind, recording in recordings.items()},
        "upload_resumes": uploader.resumes,
        "calibrations": {"camera": camera_calibration_id, "projector": projector_calibration_id},
        "jobs": [
            {"id": job["id"], "kind": job["kind"], "spec": job["spec"], "files": files[job["id"]]} for job in jobs
        ],
        "peak_w_mm": overview["peak_w_mm"],
        "frames": overview["frames"],
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    peak = max((w for w in overview["peak_w_mm"] if w is not None), default=None)
    print(f"done: {len(overview['frames'])} frames, peak deflection {peak} mm; results in {args.out}", flush=True)
    return summary


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--server", required=True, help="base URL, e.g. http://lab-server:8000 (with any proxy prefix)")
    parser.add_argument(
        "--token",
        default=os.environ.get("FRINGELAB_TOKEN"),
        help="API token (flb_...); default: $FRINGELAB_TOKEN; none for a laptop with accounts off",
    )
    parser.add_argument(
        "--recordings",
        type=Path,
        required=True,
        help="folder with camera_calibration, projector_calibration and test (folders or .zip), "
        "e.g. written by `fringelab simulate`",
    )
    parser.add_argument("--out", type=Path, required=True, help="folder for the downloaded results")
    parser.add_argument("--experiment-name", default="automated run")
    parser.add_argument("--camera-name", default="camera")
    parser.add_argument(
        "--image-size", metavar="WxH", help="image size in pixels (default: from truth/experiment.json)"
    )
    parser.add_argument("--pixel-pitch-um", type=float, help="pixel pitch in µm (default: from truth/experiment.json)")
    parser.add_argument("--scale-on", choices=("u", "v"), help="axis of the camera model's scale factor")
    parser.add_argument(
        "--export",
        action="append",
        choices=EXPORT_FORMATS,
        help="export format of the topography (repeatable; default grid-npz)",
    )
    parser.add_argument("--chunk-bytes", type=int, default=8 << 20, help="bytes per tus PATCH (default 8 MiB)")
    parser.add_argument("--job-timeout-s", type=float, default=6 * 3600, help="longest wait for one job or ingest")
    parser.add_argument(
        "--simulate-drop-after-bytes",
        type=int,
        metavar="N",
        help="testing aid: cut the upload connection once after N bytes, to exercise the resume",
    )
    args = parser.parse_args(argv)
    args.export = args.export or ["grid-npz"]
    args.image_width_px = args.image_height_px = None
    if args.image_size:
        try:
            args.image_width_px, args.image_height_px = (int(v) for v in args.image_size.lower().split("x"))
        except ValueError:
            parser.error(f"--image-size: expected WxH such as 1280x800, got {args.image_size!r}")
    if args.chunk_bytes < 1:
        parser.error("--chunk-bytes: expected a positive number")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        run(args)
    except Failed as error:
        print(f"automate: error: {error}", file=sys.stderr)
        return 1
    except httpx.HTTPError as error:
        print(f"automate: error: no answer from {args.server}: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

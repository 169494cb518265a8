#!/usr/bin/env python3
"""The whole fringelab round trip from a script, on the Python client (`fringelab.client.Client`, HTTP API only).

    python examples/automate.py --server http://lab-server:8000 --token flb_... \\
        --recordings virtual/ --out results/

1. checks the token (`GET /api/v1/auth/me`);
2. creates an experiment and a camera (image size and pixel pitch from RECORDINGS/truth/experiment.json, as
   `fringelab virtual-test` writes it, or from --image-size and --pixel-pitch-um);
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
import json
import os
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import httpx

from fringelab.client import Client, ClientError

KINDS = ("camera_calibration", "projector_calibration", "test")
EXPORT_FORMATS = ("points-csv", "grid-npz", "mat", "vtk", "profile-csv")


class Failed(Exception):
    """Something the user must act on; the message says what."""


# ---------------------------------------------------------------------------------------------- inputs


def camera_from_truth(recordings: Path) -> dict[str, Any]:
    """Image size, pixel pitch and scale axis of the virtual camera, from `fringelab virtual-test`'s ground truth."""
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


# ---------------------------------------------------------------------------------------------- the round trip


def say(line: str) -> None:
    print(line, flush=True)


def run(args: argparse.Namespace) -> dict[str, Any]:
    with Client(args.server, args.token, log=say) as client:
        return round_trip(client, args)


def round_trip(client: Client, args: argparse.Namespace) -> dict[str, Any]:
    me = client.get_me()
    say(f"fringelab at {args.server} as {me['username']} ({me['role']})")
    camera = camera_from_truth(args.recordings)
    for name in ("image_width_px", "image_height_px", "pixel_pitch_um", "scale_on"):
        if getattr(args, name) is not None:
            camera[name] = getattr(args, name)
    missing = [name for name in ("image_width_px", "image_height_px", "pixel_pitch_um") if name not in camera]
    if missing:
        raise Failed(f"no {', '.join(missing)}: give --image-size and --pixel-pitch-um (no truth/experiment.json)")

    experiment = client.create_experiment(args.experiment_name)
    fields = {k: camera[k] for k in ("image_width_px", "image_height_px", "pixel_pitch_um")}
    camera_row = client.create_camera(experiment["id"], args.camera_name, **fields)
    say(f"experiment {experiment['id']}, camera {camera_row['id']} ({args.camera_name})")

    if args.simulate_drop_after_bytes is not None:
        client.simulate_upload_drop(args.simulate_drop_after_bytes)
    recordings: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="fringelab-upload-") as work:
        for kind in KINDS:
            path = recording_file(args.recordings, kind, Path(work))
            say(f"uploading {path.name} ({path.stat().st_size} bytes) as {kind}")
            recording_id = client.upload_recording(
                path, camera_id=camera_row["id"], kind=kind, chunk_bytes=args.chunk_bytes
            )
            recordings[kind] = client.wait_recording(recording_id, timeout_s=args.job_timeout_s)
            say(f"  recording {recording_id} ready: {recordings[kind]['frame_count']} frames")

    timeout = args.job_timeout_s
    camera_spec = {"kind": "camera_calibration", "recording_id": recordings["camera_calibration"]["id"]}
    if camera.get("scale_on"):
        camera_spec["scale_on"] = camera["scale_on"]
    camera_job = client.run_job(camera_spec, timeout_s=timeout)
    camera_calibration_id = camera_job["result"]["calibration_id"]
    projector_job = client.run_job(
        {
            "kind": "projector_calibration",
            "camera_calibration_id": camera_calibration_id,
            "recording_id": recordings["projector_calibration"]["id"],
        },
        timeout_s=timeout,
    )
    projector_calibration_id = projector_job["result"]["calibration_id"]
    topography_job = client.run_job(
        {
            "kind": "topography",
            "recording_id": recordings["test"]["id"],
            "camera_calibration_id": camera_calibration_id,
            "projector_calibration_id": projector_calibration_id,
        },
        timeout_s=timeout,
    )
    exports = [
        client.run_job({"kind": "export", "job_id": topography_job["id"], "format": name}, timeout_s=timeout)
        for name in args.export
    ]
    overview = client.get_topography(topography_job["id"])

    args.out.mkdir(parents=True, exist_ok=True)
    jobs = [camera_job, projector_job, topography_job, *exports]
    files = {}
    for job in jobs:
        paths = client.download_job_files(job, args.out / job["kind"])
        files[job["id"]] = [{**entry, "path": str(path)} for entry, path in zip(job["files"], paths, strict=True)]
    summary = {
        "server": args.server,
        "experiment_id": experiment["id"],
        "camera_id": camera_row["id"],
        "recordings": {kind: recording["id"] for kind, recording in recordings.items()},
        "upload_resumes": client.upload_resumes,
        "calibrations": {"camera": camera_calibration_id, "projector": projector_calibration_id},
        "jobs": [
            {"id": job["id"], "kind": job["kind"], "spec": job["spec"], "files": files[job["id"]]} for job in jobs
        ],
        "peak_w_mm": overview["peak_w_mm"],
        "frames": overview["frames"],
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    peak = max((w for w in overview["peak_w_mm"] if w is not None), default=None)
    say(f"done: {len(overview['frames'])} frames, peak deflection {peak} mm; results in {args.out}")
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
        "e.g. written by `fringelab virtual-test`",
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
    except (Failed, ClientError) as error:
        print(f"automate: error: {error}", file=sys.stderr)
        return 1
    except httpx.HTTPError as error:
        print(f"automate: error: no answer from {args.server}: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

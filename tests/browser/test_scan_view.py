"""The scan view in real Chromium against a real `fringelab up`: a scan of the virtual digital-projector rig (a
sphere in front of a screen), registered as a succeeded scan job, shown as a 3-D point cloud coloured by z or σ with
the decoding's QA (valid share, reasons, code map, shading)."""

from __future__ import annotations

import uuid
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, utcnow
from fringelab.core.settings import Settings
from fringelab.formats.scan import write_scan
from fringelab.science.graycode import PatternSequence, WhiteBlack
from fringelab.science.scan import scan, scan_qa
from fringelab.science.virtual_procam import (
    Plane,
    ProcamImaging,
    ProcamRenderer,
    Sphere,
    gray_code_patterns,
    in_frame_order,
    virtual_procam_rig,
)
from tests.browser.conftest import screenshot

pytestmark = [pytest.mark.browser, pytest.mark.integration]


def register_scan(data_dir: Path, experiment_id: int) -> tuple[str, int]:
    """A succeeded scan job of the experiment holding a scan of the virtual rig (as the worker writes one)."""
    rig = virtual_procam_rig()
    sequence = PatternSequence(axis="columns", projector_size_wh_px=(320, 200), gray_frames=tuple(range(2, 10)),
                               band_px=2.0, threshold=WhiteBlack(0, 1))  # fmt: skip
    frames = ProcamRenderer(rig, imaging=ProcamImaging(supersample=1)).render(
        [Sphere((0.0, 0.0, 300.0), 20.0), Plane((0.0, 0.0, -1.0), -340.0)],
        in_frame_order(gray_code_patterns(sequence)), rng=np.random.default_rng(5),
    )  # fmt: skip
    result = scan(frames, sequence, rig)
    job_id = str(uuid.uuid4())
    target = data_dir / "results" / "jobs" / job_id / "scan.h5"
    target.parent.mkdir(parents=True)
    write_scan(target, result, qa=scan_qa(result))
    entry = {"name": "scan.h5", "path": str(target.relative_to(data_dir)), "size_bytes": target.stat().st_size,
             "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
    settings = Settings(_env_file=None, data_dir=data_dir)  # type: ignore[call-arg]
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id=job_id, kind="scan", state="succeeded", experiment_id=experiment_id, files=[entry],
                        spec={"kind": "scan"}, result={"n_points": len(result)}, finished_at=utcnow()))  # fmt: skip
        session.commit()
    engine.dispose()
    return job_id, len(result)


def test_the_scan_view_shows_the_points_and_the_decoding(page, live_server) -> None:  # type: ignore[no-untyped-def]
    base = f"{live_server.base_url}/api/v1"
    experiment = httpx.post(f"{base}/experiments", json={"name": "ball scan"}, timeout=30).json()
    job_id, n_points = register_scan(live_server.data_dir, experiment["id"])

    page.goto(f"/#/jobs/{job_id}")
    page.get_by_role("link", name="Scan view").click()
    expect(page.get_by_role("heading", name=f"Scan: Scan {job_id[:8]}")).to_be_visible(timeout=30_000)
    quality = page.get_by_label("Decoding quality")
    expect(quality).to_contain_text("Pixels decoded")
    expect(quality).to_contain_text("stripe edge")
    expect(quality).to_contain_text("Calibration in σ")  # the rig's truth carries no RMS: said, not hidden
    for name in ("Scan points (camera frame)", "Decoded code", "Shading (white − black)", "Why pixels have no code"):
        expect(page.get_by_role("img", name=name)).to_be_visible()
    page.wait_for_function("() => window.fringelab.scan && window.fringelab.scan.colouredBy === 'z'", timeout=60_000)
    expect(page.locator(".scatterlayer, .gl-container").first).to_be_attached(timeout=60_000)
    page.get_by_label("Colour by").select_option("sigma")
    page.wait_for_function("() => window.fringelab.scan.colouredBy === 'sigma'", timeout=30_000)
    shown = page.evaluate("() => window.fringelab.scan.scan.points.n_total")
    assert shown == n_points
    with page.expect_download() as download:
        page.get_by_role("button", name="Download Scan points (camera frame) CSV").click()
    header = Path(download.value.path()).read_text().splitlines()[0]
    assert header.startswith("x_mm,y_mm,z_mm,sigma_mm")
    screenshot(page, "scan-view")

"""The selftest job: synthetic frames computed on some workers and verified on others through the shared data
directory."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from typing import Any

import h5py
import numpy as np
from sqlalchemy import select

from fringelab.core.jobs import as_utc
from fringelab.core.models import Job, utcnow
from fringelab.core.specs import SelftestSpec
from worker.chunks import InOrder, handed_over, planned_frame_ranges
from worker.context import Chunked, JobContext, this_worker
from worker.handover import load_arrays, save_arrays


def selftest_frame(frame: int, *, size_px: int) -> tuple[float, str]:
    """The work of one selftest frame: a seeded random image and its spectrum. Returns (mean spectral amplitude,
    SHA-256 of the image), the same on every machine for the same frame, so the merge can check each one."""
    image = np.random.default_rng(frame).random((size_px, size_px), dtype=np.float32)
    spectrum = np.abs(np.fft.rfft2(image))
    return float(spectrum[1:, 1:].mean()), hashlib.sha256(image.tobytes()).hexdigest()


def selftest_entry(context: JobContext[SelftestSpec]) -> Chunked:
    spec = context.spec
    context.log(f"selftest of {spec.frames} frames of {spec.frame_size_px} px")
    return Chunked(planned_frame_ranges(spec.frames, spec.chunk_frames, context.settings), stage="computing frames")


def selftest_compute(context: JobContext[SelftestSpec], first: int, stop: int) -> None:
    """Phase 0, any worker: compute frames [first, stop)."""
    size_px = context.spec.frame_size_px
    values, digests = [], []
    for done, frame in enumerate(range(first, stop)):
        value, digest = selftest_frame(frame, size_px=size_px)
        values.append(value)
        digests.append(digest)
        context.progress(done + 1, stop - first, "computing frames")
    save_arrays(context, f"chunks/p0-{first:07d}.arrays", frame=np.arange(first, stop), value=np.asarray(values),
          digest=np.asarray(digests, dtype="S64"), worker=np.asarray([this_worker()], dtype="S200"))  # fmt: skip


def selftest_chain(context: JobContext[SelftestSpec], turns: Iterator[InOrder]) -> Chunked:
    """Merge of phase 0, in frame order: check that every frame came back once, and chain the digests (each link
    depends on all frames before it, as edge identity does in a topography), then verify in parallel."""
    ranges = handed_over(turns, selftest_compute)  # every chunk: the chain starts once all are done
    chunks = [load_arrays(context, f"chunks/p0-{first:07d}.arrays") for first, _stop in ranges]
    frame = np.concatenate([c["frame"] for c in chunks])
    expected = context.spec.frames
    if not np.array_equal(frame, np.arange(expected)):
        raise RuntimeError(f"the chunks hold {frame.size} frames, not each of 0..{expected - 1} once")
    digest = np.concatenate([c["digest"] for c in chunks])
    chain, link = [], hashlib.sha256()
    for done, value in enumerate(digest.tolist()):
        link.update(value)
        chain.append(link.hexdigest())
        context.progress(done + 1, expected, "chaining")
    computed_by = np.concatenate([np.repeat(c["worker"], c["frame"].size) for c in chunks])
    save_arrays(context, "chunks/sequence.arrays", frame=frame, value=np.concatenate([c["value"] for c in chunks]),
          digest=digest, chain=np.asarray(chain, dtype="S64"), computed_by=computed_by)  # fmt: skip
    return Chunked(ranges, stage="verifying frames")


def selftest_verify(context: JobContext[SelftestSpec], first: int, stop: int) -> None:
    """Phase 1, any worker: compute frames [first, stop) again and compare with what phase 0 stored."""
    size_px = context.spec.frame_size_px
    stored = load_arrays(context, "chunks/sequence.arrays")["digest"][first:stop]
    matches = []
    for done, frame in enumerate(range(first, stop)):
        matches.append(selftest_frame(frame, size_px=size_px)[1].encode() == stored[done])
        context.progress(done + 1, stop - first, "verifying frames")
    save_arrays(context, f"chunks/p1-{first:07d}.arrays", matches=np.asarray(matches),
          worker=np.asarray([this_worker()], dtype="S200"))  # fmt: skip


def selftest_write(context: JobContext[SelftestSpec], turns: Iterator[InOrder]) -> dict[str, Any]:
    """Merge of phase 1: the result file, and a failure naming the workers if any frame came out differently."""
    ranges = handed_over(turns, selftest_verify)
    context.progress(0, 1, "writing")
    sequence = load_arrays(context, "chunks/sequence.arrays")
    checks = [load_arrays(context, f"chunks/p1-{first:07d}.arrays") for first, _stop in ranges]
    matches = np.concatenate([c["matches"] for c in checks])
    verified_by = np.concatenate([np.repeat(c["worker"], c["matches"].size) for c in checks])
    differing = np.flatnonzero(~matches)
    if differing.size:
        pairs = sorted({(sequence["computed_by"][i].decode(), verified_by[i].decode()) for i in differing})
        raise ValueError(
            f"{differing.size} frames (first: {int(differing[0])}) came out differently on "
            + "; ".join(f"{a} and {b}" for a, b in pairs)
            + ": the workers do not compute alike; give every machine the same fringelab and numpy versions"
        )
    with context.output("selftest.h5", media_type="application/x-hdf5") as path, h5py.File(path, "w") as out:
        for name in ("frame", "value", "digest", "chain", "computed_by"):
            out[name] = sequence[name]
        out["verified_by"] = verified_by
        out.attrs["frame_size_px"] = context.spec.frame_size_px
    with context.sessions() as session:
        started = session.scalar(select(Job.started_at).where(Job.id == context.job_id))
    elapsed_s = (utcnow() - as_utc(started)).total_seconds() if started is not None else None
    frames = int(sequence["frame"].size)
    return {
        "frames": frames,
        "chunks": len(ranges),
        "workers": {"computing": _tally(sequence["computed_by"]), "verifying": _tally(verified_by)},
        "digest": sequence["chain"][-1].decode(),
        "elapsed_s": elapsed_s,
        "frames_per_s": frames / elapsed_s if elapsed_s else None,
    }


def _tally(names: np.ndarray) -> dict[str, int]:
    found, counts = np.unique(names, return_counts=True)
    return {name.decode(): int(count) for name, count in zip(found, counts, strict=True)}

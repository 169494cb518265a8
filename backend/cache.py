"""Rendered answers of immutable results, kept in memory: the same grid, overview or profile asked by many
viewers (or by a dashboard polling) is cut and serialised once.

A result file never changes once its job succeeded; the key holds its path, size and modification time, so a
job run again (a new file) is never answered from the old one. Bounded by bytes (least recently used first out),
so the cache cannot grow the API process by more than `max_bytes`.
"""

from __future__ import annotations

import gzip
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Mapping
from pathlib import Path

from starlette.responses import Response


class AnswerCache:
    def __init__(self, *, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._answers: OrderedDict[Hashable, bytes] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def clear(self) -> None:
        with self._lock:
            self._answers.clear()
            self._bytes = 0

    def get_or_render(self, path: Path, key: Hashable, render: Callable[[], bytes]) -> bytes:
        """The answer for `key` about the file at `path`, rendered by `render()` when not kept."""
        stat = path.stat()
        full_key = (str(path), stat.st_size, stat.st_mtime_ns, key)
        with self._lock:
            kept = self._answers.get(full_key)
            if kept is not None:
                self._answers.move_to_end(full_key)
                return kept
        answer = render()
        if len(answer) <= self.max_bytes // 8:  # one huge answer must not flush everything else
            with self._lock:
                if full_key not in self._answers:
                    self._answers[full_key] = answer
                    self._bytes += len(answer)
                while self._bytes > self.max_bytes:
                    _, dropped = self._answers.popitem(last=False)
                    self._bytes -= len(dropped)
        return answer


GZIP_MIN_BYTES = 1024
GZIP_LEVEL = 1  # a 201 x 201 grid's JSON: 300 kB -> 134 kB in 6 ms (level 5: 111 kB in 17 ms, the most costly step)


def cached_json(
    cache: AnswerCache, headers: Mapping[str, str], path: Path, key: tuple[Hashable, ...], render: Callable[[], bytes]
) -> Response:
    """The JSON answer for `key` from `cache`, gzip-compressed on the wire when the client accepts it (a grid or
    profile is mostly digits: compressed once, kept in the cache beside the plain answer). Each answer carries an
    ETag made of the result file's identity and `key` (the file never changes once its job succeeded: a job run
    again writes a new one), so a client that sends it back in If-None-Match gets 304 without a body, and nothing
    is read or rendered for it. The caller has checked access before."""
    stat = path.stat()
    packed = "gzip" in headers.get("accept-encoding", "").lower()
    identity = repr((str(path), stat.st_size, stat.st_mtime_ns, key)).encode()
    etag = f'"{hashlib.blake2b(identity, digest_size=16).hexdigest()}{"-gz" if packed else ""}"'
    kept = {"Vary": "Accept-Encoding", "ETag": etag, "Cache-Control": "private, no-cache"}
    if etag in _tags(headers.get("if-none-match", "")):
        return Response(status_code=304, headers=kept)
    body = cache.get_or_render(path, key, render)
    if len(body) >= GZIP_MIN_BYTES and packed:
        zipped = cache.get_or_render(path, (*key, "gzip"), lambda: gzip.compress(body, compresslevel=GZIP_LEVEL))
        return Response(zipped, media_type="application/json", headers={**kept, "Content-Encoding": "gzip"})
    return Response(body, media_type="application/json", headers=kept)


def _tags(if_none_match: str) -> set[str]:
    """The entity tags of an If-None-Match header (weak ones compared as strong: the answers are byte-exact)."""
    return {tag.strip().removeprefix("W/") for tag in if_none_match.split(",") if tag.strip()}

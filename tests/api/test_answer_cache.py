"""Cached JSON answers of immutable results, gzip-compressed on the wire when the client accepts it."""

from __future__ import annotations

import gzip

from backend.cache import AnswerCache, cached_json


def test_a_large_answer_is_compressed_once_for_clients_that_accept_gzip(tmp_path):
    result = tmp_path / "topography.h5"
    result.write_bytes(b"result")
    renders: list[int] = []
    body = b'{"w_mm": [' + b"1.2345," * 2000 + b"0]}"

    def render() -> bytes:
        renders.append(1)
        return body

    cache = AnswerCache(max_bytes=1 << 24)
    packed = cached_json(cache, {"accept-encoding": "gzip, deflate, br"}, result, ("grid", 3), render)
    assert packed.headers["content-encoding"] == "gzip" and "Accept-Encoding" in packed.headers["vary"]
    assert gzip.decompress(packed.body) == body and len(packed.body) < len(body) / 5
    plain = cached_json(cache, {}, result, ("grid", 3), render)
    assert plain.body == body and "content-encoding" not in plain.headers
    assert len(renders) == 1  # rendered once, compressed once, both kept

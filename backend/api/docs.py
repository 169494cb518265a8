"""`/api/v1/docs`: the method documentation of `docs/` (Markdown) rendered to HTML for the dashboard's help pages.

Rendered on the server with markdown-it-py (CommonMark with tables; raw HTML in a document is shown as text, not
run). Headings get ids (`3-1-calibration` for "### 3.1 Calibration") so that reports can link to the section that
explains a number. Thin: reading a file and rendering it.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter
from fastapi import Path as PathParam
from markdown_it import MarkdownIt
from pydantic import BaseModel, Field

from backend.errors import error_responses
from fringelab.core.errors import NotFound

DOCS_DIR = Path(__file__).resolve().parents[2] / "docs"
router = APIRouter(tags=["help"])
DocName = Annotated[str, PathParam(pattern=r"^[a-z0-9][a-z0-9-]{0,63}$", description="A document of docs/, no .md")]


class DocSummary(BaseModel):
    name: str = Field(description="The file name without .md: method, file-formats, ...")
    title: str


class DocOut(DocSummary):
    html: str = Field(description="The document as HTML; links to other documents point to #/help/<name>.")
    sections: list[dict[str, str]] = Field(description="[{id, title}] of its headings, in order.")


def slug(text: str) -> str:
    """'3.1 Calibration' → '3-1-calibration': the id of a heading."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def _title(path: Path) -> str:
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("# "):
            return line[2:].strip()
    return path.stem


@lru_cache(maxsize=32)
def _render(path: Path, mtime_ns: int) -> tuple[str, tuple[tuple[str, str], ...]]:
    markdown = MarkdownIt("commonmark", {"html": False}).enable("table")
    tokens = markdown.parse(path.read_text(encoding="utf-8"))
    sections = []
    for index, token in enumerate(tokens):
        if token.type == "heading_open":
            text = tokens[index + 1].content
            token.attrSet("id", slug(text))
            sections.append((slug(text), text))
        if token.type == "inline":
            for child in token.children or []:
                href = child.attrGet("href") if child.type == "link_open" else None
                if isinstance(href, str):
                    local = re.fullmatch(r"([a-z0-9-]+)\.md(#.*)?", href)
                    if local:
                        child.attrSet("href", f"#/help/{local.group(1)}")
    return markdown.renderer.render(tokens, markdown.options, {}), tuple(sections)


def _path(name: str) -> Path:
    path = DOCS_DIR / f"{name}.md"
    if not path.is_file():
        raise NotFound(f"there is no document {name!r} in docs/", code="not_found")
    return path


@router.get("/docs", response_model=list[DocSummary], responses=error_responses())
def list_docs() -> list[DocSummary]:
    """The documents of docs/, the method first."""
    paths = sorted(DOCS_DIR.glob("*.md"), key=lambda p: (p.stem != "method", p.stem != "index", p.stem))
    return [DocSummary(name=p.stem, title=_title(p)) for p in paths]


@router.get("/docs/{name}", response_model=DocOut, responses=error_responses(404, 422))
def read_doc(name: DocName) -> DocOut:
    """One document of docs/ rendered to HTML, with the ids of its sections."""
    path = _path(name)
    html, sections = _render(path, path.stat().st_mtime_ns)
    return DocOut(name=name, title=_title(path), html=html, sections=[{"id": i, "title": t} for i, t in sections])

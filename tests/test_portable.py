"""The science path (library, file formats, pipelines, CLI commands) must run on Windows lab PCs: no POSIX-only
calls there. The server (fringelab/core, backend, worker) may stay Linux-only."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PORTABLE = ("fringelab/science", "fringelab/formats", "fringelab/pipelines", "fringelab/commands")
POSIX_MODULES = {"fcntl", "termios", "pwd", "grp", "resource", "posix"}
POSIX_OS_CALLS = {"pread", "pwrite", "preadv", "pwritev", "writev", "readv", "fork", "getuid", "setsid", "killpg",
                  "sched_getaffinity", "posix_fadvise", "statvfs"}  # fmt: skip


def test_no_posix_only_calls_on_the_science_path():
    found = []
    for folder in PORTABLE:
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [alias.name.split(".")[0] for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    names = [node.module.split(".")[0]]
                else:
                    names = []
                found += [f"{path.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names if n in POSIX_MODULES]
                if (
                    isinstance(node, ast.Attribute)
                    and isinstance(node.value, ast.Name)
                    and node.value.id == "os"
                    and node.attr in POSIX_OS_CALLS
                ):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} calls os.{node.attr}")
    assert not found, "POSIX-only calls on the science path (must run on Windows):\n" + "\n".join(found)

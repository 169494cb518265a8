"""The layers keep their one-way imports: read every import of the code (ast) and check who imports whom.

    fringelab.science                       pure numpy/OpenCV/SciPy
    fringelab.formats                       file formats           (may import science)
    fringelab.pipelines, fringelab.core     whole runs; core        (may import formats and science; not each other)
    fringelab.commands, fringelab.client    the command line's science commands; the Python client
    backend (the API), worker               the applications        (may import fringelab; never each other)

An import inside a function counts like one at the top of a module (it runs as soon as the function is called);
one under `if TYPE_CHECKING:` does not (it never runs).

Within the layers: no module import cycle (Python, and the dashboard's ES modules), no route module of the API
(`backend/api/*.py` but `deps`) importing another one (what routes share goes to `backend/api/deps.py`, schemas to
`backend/schemas/`), and nothing of the backend below the routes importing `backend.api`.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable, Mapping
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("fringelab", "backend", "worker")

# layer name -> the layers it may import (itself included)
ALLOWED = {
    "science": {"science"},
    "formats": {"science", "formats"},
    "pipelines": {"science", "formats", "pipelines"},
    "core": {"science", "formats", "core"},
    "commands": {"science", "formats", "pipelines", "commands"},
    "client": {"client"},
    "backend": {"science", "formats", "core", "commands", "backend"},
    "worker": {"science", "formats", "pipelines", "core", "worker"},
}


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] == "fringelab":
        return parts[1] if len(parts) > 1 and parts[1] in ALLOWED else ("science" if len(parts) == 1 else None)
    return parts[0] if parts[0] in ("backend", "worker") else None


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            if "migrations" in path.parts:
                continue
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


MODULES = _modules()


def _type_checking_only(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    while node in parents:
        node = parents[node]
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return True
    return False


def _parse(path: Path) -> ast.Module:
    """`ast.parse`, once more if CPython 3.11's AST depth counter, shared by all threads, was disturbed by another
    thread parsing at the same time (Python 3.11 formats a traceback with `ast`: a thread a test left behind,
    logging its lost Redis, did so): "SystemError: AST constructor recursion depth mismatch"."""
    try:
        return ast.parse(path.read_text(), str(path))
    except SystemError:
        return ast.parse(path.read_text(), str(path))


@cache
def imports_of(module: str) -> frozenset[str]:
    """Every module `module` imports when it runs (resolved to project modules where it names one)."""
    path = MODULES[module]
    tree = _parse(path)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and not _type_checking_only(node, parents):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not _type_checking_only(node, parents):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in MODULES)
    return frozenset(found)


def closure(module: str) -> set[str]:
    """`module` and everything it imports, transitively (third-party modules as named, not followed)."""
    seen, todo = set(), [module]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        if name in MODULES:
            todo.extend(imports_of(name))
    return seen


def test_every_import_points_down_or_sideways_within_its_layer() -> None:
    wrong = []
    for module in sorted(MODULES):
        layer = layer_of(module)
        for target in imports_of(module):
            target_layer = layer_of(target)
            if layer and target_layer and target_layer not in ALLOWED[layer]:
                wrong.append(f"{module} ({layer}) imports {target} ({target_layer})")
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_no_two_top_level_packages_import_each_other() -> None:
    edges = {(m.split(".")[0], t.split(".")[0]) for m in MODULES for t in imports_of(m) if t.split(".")[0] in PACKAGES}
    cycles = sorted({tuple(sorted(edge)) for edge in edges if edge[0] != edge[1] and edge[::-1] in edges})
    assert not cycles, f"top-level packages importing each other: {cycles}"


@pytest.mark.parametrize("entry", ["backend.app"])
def test_the_api_imports_no_opencv_no_numba_and_no_task_code(entry: str) -> None:
    """The API process stays light: no OpenCV, no compiler (numba) of the science's loops, no task code."""
    modules = closure(entry)
    for heavy in ("cv2", "numba"):
        assert not {m for m in modules if m.split(".")[0] == heavy}, sorted(
            m for m in modules if m in MODULES and heavy in imports_of(m)
        )
    assert not {m for m in modules if m.split(".")[0] == "worker"}
    assert "celery" not in {m.split(".")[0] for m in modules if m in MODULES and m.startswith("worker")}


def test_the_checker_sees_a_wrong_import() -> None:
    """The rules above can fail: a science module importing the API would be caught."""
    assert "backend" not in ALLOWED["science"] and layer_of("backend.app") == "backend"
    assert layer_of("fringelab.science.fringes") == "science" and layer_of("fringelab.core.jobs") == "core"
    assert "cv2" in closure("fringelab.science.fringes")
    assert "numba" in closure("fringelab.science.fringes")


# ---------------------------------------------------------------------------------------------- cycles and routes


def cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The import cycles of `graph` (module -> the modules it imports): its strongly connected components of more
    than one module, and modules that import themselves (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, targets = work[-1]
            target = next(targets, None)
            if target is not None:
                if target not in index:
                    index[target] = low[target] = len(index)
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(graph.get(target, ())))))
                elif target in on_stack:
                    low[node] = min(low[node], index[target])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in graph.get(node, ()):
                    found.append(sorted(component))
    return found


def python_graph() -> dict[str, set[str]]:
    return {m: {t for t in imports_of(m) if t in MODULES and t != m} for m in MODULES}


FRONTEND = ROOT / "frontend"
_JS_IMPORT = re.compile(
    r"""^\s*(?:import|export)\b[^;'"]*?\bfrom\s*["'](\.{1,2}/[^"']+)["']"""  # import { x } from "./x.js"
    r"""|\bimport\s*\(\s*["'](\.{1,2}/[^"']+)["']""",  # import("./x.js")
    re.M,
)


def js_imports(path: Path) -> set[str]:
    """The project modules an ES module imports (static `import ... from "./x.js"`, and `import("./x.js")`), as
    paths relative to frontend/."""
    found = set()
    for match in _JS_IMPORT.finditer(path.read_text(encoding="utf-8")):
        target = (path.parent / (match.group(1) or match.group(2))).resolve()
        found.add(target.relative_to(FRONTEND.resolve()).as_posix())
    return found


def frontend_graph() -> dict[str, set[str]]:
    modules = [p for p in FRONTEND.rglob("*.js") if "vendor" not in p.relative_to(FRONTEND).parts]
    return {p.relative_to(FRONTEND).as_posix(): js_imports(p) for p in modules}


ROUTE_PACKAGE = "backend.api"
SHARED_BY_ROUTES = {"backend.api", "backend.api.deps"}  # the package, and the dependencies routes share


def route_modules() -> set[str]:
    return {m for m in MODULES if m.startswith(f"{ROUTE_PACKAGE}.") and m not in SHARED_BY_ROUTES}


def test_no_python_module_import_cycle() -> None:
    found = cycles(python_graph())
    assert not found, "modules importing each other (directly or through others): " + "; ".join(
        " -> ".join(cycle) for cycle in found
    )


def test_no_frontend_module_import_cycle() -> None:
    graph = frontend_graph()
    assert "views/viewer.js" in graph and "views/viewer/map.js" in graph["views/viewer.js"]  # the reader works
    found = cycles(graph)
    assert not found, "ES modules importing each other: " + "; ".join(" -> ".join(cycle) for cycle in found)


def test_no_route_module_imports_another() -> None:
    routes = route_modules()
    wrong = sorted(f"{m} imports {t}" for m in routes for t in imports_of(m) if t in routes and t != m)
    assert not wrong, "route modules importing route modules (share through backend/api/deps.py or schemas/):\n" + (
        "\n".join(wrong)
    )


def test_nothing_below_the_routes_imports_them() -> None:
    """The backend's own floors (uploads storage, result files, errors, schemas, ...) never reach up into
    `backend.api`; only the application that assembles the routes does."""
    above = {"backend.app"} | {m for m in MODULES if m == ROUTE_PACKAGE or m.startswith(f"{ROUTE_PACKAGE}.")}
    wrong = sorted(
        f"{m} imports {t}"
        for m in MODULES
        if m.startswith("backend") and m not in above
        for t in imports_of(m)
        if t == ROUTE_PACKAGE or t.startswith(f"{ROUTE_PACKAGE}.")
    )
    assert not wrong, "below the routes, importing them:\n" + "\n".join(wrong)


def test_the_cycle_and_route_checks_can_fail() -> None:
    """The checks above see what they are for: a cycle of two and of three, a self-import, in Python names and in
    frontend paths; a route importing a route."""
    assert cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]
    assert cycles({"a": {"a"}}) == [["a"]] and cycles({"a": {"b"}, "b": set()}) == []
    assert cycles({"views/jobs.js": {"views/exports.js"}, "views/exports.js": {"views/jobs.js"}})
    assert {"backend.api.jobs", "backend.api.results"} <= route_modules()
    assert "backend.api.deps" not in route_modules()

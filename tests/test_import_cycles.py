"""No import circles among the project's modules (facegeo and its folders texturing/, export/, eval/).

The graph is read from the source (``ast``), not by importing, so optional extras need not be
installed. An edge A -> B is an import of project module B that runs when A is imported: the
module-level ``import``/``from`` statements, including those under module-level ``if``/``try``
blocks, but not those under ``if TYPE_CHECKING:`` (never run). Function-local imports are left
out on purpose: they run when the function is called, after both modules have finished
initialising, so they cannot meet a half-initialised module; they are the sanctioned way to defer
heavy or optional imports (the diffusion extra). A second test forbids circles through them too
(a circle is a layering smell either way). ``from package import name`` counts as an import of ``package.name`` when that is a
module, else of ``package``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]
#: Import package -> source folder (pyproject's package-dir mapping).
PACKAGE_DIRS = {"facegeo": "facegeo", "facegeo.texturing": "texturing", "facegeo.export": "export",
                "facegeo.eval": "eval", "facegeo.assets": "assets"}


def _modules() -> dict[str, Path]:
    """Module name -> file, for every .py file of the installed packages."""
    out: dict[str, Path] = {}
    for package, folder in PACKAGE_DIRS.items():
        base = ROOT / folder
        for path in base.rglob("*.py"):
            rel = path.relative_to(base).with_suffix("")
            parts = [] if rel.parts == ("__init__",) else list(rel.parts)
            if parts and parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([package, *parts])] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
           (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module, name: str, is_package: bool, local: bool) -> list[tuple[str, str | None]]:
    """(module, imported name or None) of the imports that run when the module is imported, and
    with ``local`` also those inside functions and classes."""
    found: list[tuple[str, str | None]] = []

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if local and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                visit(node.body)
            if isinstance(node, ast.Import):
                found.extend((alias.name, None) for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:  # relative: resolve against this module's package
                    base = name.split(".") if is_package else name.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                found.extend((module, alias.name) for alias in node.names)
            elif isinstance(node, ast.If):
                if not _is_type_checking(node.test):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                for handler in node.handlers:
                    visit(handler.body)
                visit(node.orelse)
                visit(node.finalbody)
            elif isinstance(node, (ast.With, ast.For, ast.While)):
                visit(node.body)

    visit(tree.body)
    return found


def import_graph(local: bool = False) -> dict[str, set[str]]:
    """Project module -> the project modules its module-level imports load (with ``local``, its
    function-local imports too)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        edges: set[str] = set()
        for module, imported in _imports(ast.parse(path.read_text()), name, is_package, local):
            if imported is not None and f"{module}.{imported}" in modules:
                edges.add(f"{module}.{imported}")
            elif module in modules:
                edges.add(module)
        graph[name] = edges - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components with more than one module (each holds a cycle)."""
    names = sorted(graph)
    index = {n: i for i, n in enumerate(names)}
    rows = [index[a] for a in names for b in graph[a]]
    cols = [index[b] for a in names for b in graph[a]]
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    count, labels = connected_components(adjacency, directed=True, connection="strong")
    groups = [{names[i] for i in np.flatnonzero(labels == k)} for k in range(count)]
    return [g for g in groups if len(g) > 1]


def test_the_graph_sees_the_packages_and_known_edges():
    graph = import_graph()
    for package in ("facegeo", "facegeo.texturing", "facegeo.export", "facegeo.eval", "facegeo.uv", "facegeo.regressor",
                    "facegeo.landmarks", "facegeo.texturing.diffusion"):
        assert package in graph
    assert "facegeo.normals" in graph["facegeo.export.displacement"]  # from facegeo.normals import ...
    assert "facegeo.landmarks.scheme" in graph["facegeo.landmarks.mediapipe_mesh"]
    assert "facegeo.morphable_model" not in graph["facegeo.skin_mask"]  # under TYPE_CHECKING only
    # a circle is found where there is one
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]


def test_no_import_cycles():
    found = cycles(import_graph())
    assert found == [], f"import circles among project modules: {found}"


def test_no_import_cycles_through_function_local_imports():
    found = cycles(import_graph(local=True))
    assert found == [], f"import circles through function-local imports: {found}"

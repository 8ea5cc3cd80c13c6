"""The architecture's rules, checked on the source: the import direction between the four layers,
no import cycle between modules, and no dataset named by a stage."""

from __future__ import annotations

import ast
import re
from itertools import pairwise
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LAYERS = ("dsnet_core", "storage", "tasks", "flows")
FORBIDDEN = {
    "dsnet_core": {"storage", "tasks", "flows", "prefect", "zarr", "pyarrow"},
    "storage": {"tasks", "flows", "prefect"},
    "tasks": {"flows"},
    "flows": set(),
}


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, typing: bool = True) -> set[str]:
    """Every module an import statement names (at any depth of the file, lazy imports included;
    with ``typing=False`` not those under ``if TYPE_CHECKING:``, which never run)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    if not typing:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
                node.body = []
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names)
    return out


def _graph() -> dict[str, set[str]]:
    files = [p for layer in LAYERS for p in (REPO / layer).rglob("*.py")]
    modules = {_module(p): p for p in files}
    graph = {}
    for name, path in modules.items():
        graph[name] = {m for m in _imports(path, typing=False) if m in modules and m != name}
    return graph


def test_layers_import_only_downwards():
    bad = []
    for layer in LAYERS:
        for path in (REPO / layer).rglob("*.py"):
            for imported in _imports(path):
                if imported.split(".")[0] in FORBIDDEN[layer]:
                    bad.append(f"{path.relative_to(REPO)} imports {imported}")
    assert bad == []


def test_no_import_cycle_between_modules():
    """Module-level and lazy imports alike (annotations-only imports aside): a cycle means two
    modules that cannot be read apart."""
    graph = _graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*stack[stack.index(nxt) :], nxt]))
            elif nxt not in state:
                visit(nxt, [*stack, nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    cycles = [c for c in cycles if not _init_reexport(c)]
    assert cycles == []


REEXPORT_WAIVED = ("dsnet_core.synth",)
"""Packages whose ``__init__`` re-exports a submodule that imports the package back (not a cycle of
meaning, but waived by name: any other package's, e.g. a registry's, fails the test). Left:
``dsnet_core.synth.layout`` imports ``dsnet_core.synth``, whose ``__init__`` imports ``.log``."""


def _init_reexport(cycle: str) -> bool:
    names = cycle.split(" -> ")
    return any(
        (b.startswith(a + ".") and a in REEXPORT_WAIVED) or (a.startswith(b + ".") and b in REEXPORT_WAIVED)
        for a, b in pairwise(names)
    )


def test_no_stage_names_a_dataset():
    """Dataset knowledge comes from the run (model card, reader), never from a stage module."""
    hits = [
        f"{p.relative_to(REPO)}:{i}"
        for p in (REPO / "tasks").rglob("*.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if re.search(r"kitti|nuscenes", line, re.IGNORECASE)
    ]
    assert hits == []


def method_homes() -> dict[str, tuple[str, ...]]:
    """Where each registered method may be named: its method module and the modules it declares
    (:attr:`tasks.methods.base.Method.homes`: its trainer, its own stages), from the registry."""
    import inspect

    from tasks.methods import METHODS

    return {
        name: (str(Path(inspect.getfile(type(m))).relative_to(REPO)), *m.homes) for name, m in METHODS.items()
    }


def test_no_method_named_outside_its_module():
    """Flows and stages ask the registry (``tasks.methods``) for a method, and stages check what
    their source stage declares: no string literal names a method anywhere else."""
    homes = method_homes()
    assert homes["most"] == ("tasks/methods/most.py", "tasks/most.py")  # the registry says it
    hits = []
    for layer in ("flows", "tasks"):
        for path in (REPO / layer).rglob("*.py"):
            rel = str(path.relative_to(REPO))
            tree = ast.parse(path.read_text(), filename=rel)
            program = (
                {  # the command line's own name (``Typer(name="dsnet")``) is not the method
                    id(k.value)
                    for n in ast.walk(tree)
                    if isinstance(n, ast.Call)
                    for k in n.keywords
                    if k.arg == "name"
                }
                if rel == "flows/cli.py"
                else set()
            )
            docstrings = {
                id(n.body[0].value)
                for n in ast.walk(tree)
                if isinstance(n, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
                and n.body
                and isinstance(n.body[0], ast.Expr)
                and isinstance(n.body[0].value, ast.Constant)
            }
            for node in ast.walk(tree):
                if (
                    isinstance(node, ast.Constant)
                    and node.value in homes
                    and id(node) not in docstrings | program
                    and rel not in homes[node.value]
                ):
                    hits.append(f"{rel}:{node.lineno} {node.value!r}")
    assert hits == []


def test_model_and_method_packages_do_not_import_upwards():
    """``dsnet_core.model`` (the shared network) never imports a method package built on it."""
    bad = [
        f"{p.relative_to(REPO)} imports {m}"
        for p in (REPO / "dsnet_core" / "model").rglob("*.py")
        for m in _imports(p)
        if m.startswith(("dsnet_core.most", "dsnet_core.dpls"))
    ]
    assert bad == []

"""The package layout: one ``roadtruth`` namespace, harness grouped by stage, no import cycles."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {"roadtruth": ROOT / "roadtruth", "roadtruth.harness": ROOT / "harness",
           "roadtruth.observers": ROOT / "observers", "roadtruth.mjcf": ROOT / "mjcf"}
STAGES = ("truth", "sensors", "evaluation", "jobs", "report", "files")


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for pkg, folder in SOURCES.items():
        for p in folder.rglob("*.py"):
            if "__pycache__" in p.parts or "template" in p.parent.name:
                continue
            rel = p.relative_to(folder).with_suffix("").parts
            name = ".".join((pkg, *rel))
            out[name.removesuffix(".__init__")] = p
    return out


def _imports(path: Path, *, module_level_only: bool) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    found: set[str] = set()
    stack = list(nodes)
    while stack:
        node = stack.pop()
        if module_level_only and isinstance(node, ast.If):  # TYPE_CHECKING blocks count
            stack.extend(node.body)
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
    return found


def test_no_module_imports_a_top_level_harness_or_observers() -> None:
    for name, path in _modules().items():
        bad = {m for m in _imports(path, module_level_only=False) if m.split(".")[0] in ("harness", "observers", "mjcf")}
        assert not bad, f"{name} imports {sorted(bad)}: use roadtruth.harness / roadtruth.observers"


def test_harness_is_grouped_by_stage() -> None:
    top = sorted(p.stem for p in (ROOT / "harness").glob("*.py") if p.stem != "__init__")
    assert top == ["cli", "errors", "progress", "signals"]
    for stage in STAGES:
        assert (ROOT / "harness" / stage / "__init__.py").is_file()


def test_design_modules_never_import_their_observers() -> None:
    mods = _modules()
    for name, path in mods.items():
        if not name.endswith("_design"):
            continue
        observer = name.removesuffix("_design")
        imported = _imports(path, module_level_only=False)
        assert not any(m == observer or m.startswith(observer + ".") for m in imported), f"{name} imports {observer}"


def test_module_level_imports_have_no_cycle() -> None:
    mods = _modules()
    graph = {n: {m for m in _imports(p, module_level_only=True) if m in mods and m != n} for n, p in mods.items()}
    # A package's __init__ importing its own submodule is not a cycle of two modules.
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(n: str) -> None:
        state[n] = 1
        path.append(n)
        for m in sorted(graph[n]):
            if n.startswith(m + "."):
                continue  # a submodule importing its own package's names
            if state.get(m) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(m):] + [m]))
            if m not in state:
                visit(m)
        path.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n)

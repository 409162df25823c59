"""The dependency rules of docs/architecture.md, read from the source: svss_daq imports
neither svss_proc nor sim_device; svss_proc never imports sim_device (the imager never
knows the truth it is tested against); the kernels are not given sound-speed defaults."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imported_packages(path: Path) -> set[str]:
    """Top-level packages a module imports (absolute imports, anywhere in the file)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package, forbidden", [
    ("svss_daq", {"svss_proc", "sim_device", "svss"}),
    ("svss_proc", {"sim_device", "svss"}),
    ("sim_device", {"svss"}),
])
def test_dependencies_run_one_way(package, forbidden):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files
    offenders = {str(f.relative_to(ROOT)): sorted(imported_packages(f) & forbidden)
                 for f in files if imported_packages(f) & forbidden}
    assert not offenders, offenders


def test_the_rule_checker_sees_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import numpy as np\nfrom sim_device.scene import x\n"
                 "def f():\n    from svss_proc import tiles\n")
    assert imported_packages(f) == {"numpy", "sim_device", "svss_proc"}


def test_no_sound_speed_defaults_in_the_imager():
    for f in sorted((ROOT / "svss_proc").rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.Lambda)):
                args = node.args
                named = args.args[len(args.args) - len(args.defaults):] + [
                    a for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None]
                speeds = [a.arg for a in named if a.arg in ("c", "cw", "cs")
                          or "sound_speed" in a.arg]
                assert not speeds, f"{f.relative_to(ROOT)}: default for {speeds}"


# ------------------------------------------------------------------- import circles

PACKAGES = ("svss", "svss_daq", "svss_proc", "sim_device")


def module_files(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """Module name -> file for every module of ``packages`` under ``root`` (a package is
    its ``__init__.py``)."""
    out = {}
    for package in packages:
        for f in sorted((root / package).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = f
    return out


def import_graph(root: Path, packages=PACKAGES) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports, anywhere in its file (inside
    functions and ``if TYPE_CHECKING`` too), relative imports resolved; ``from P import m``
    names the submodule ``P.m`` when there is one, and the package ``P`` (its
    ``__init__``, whose own imports are its edges) unless ``P`` holds the importing
    module (Python has initialised it before the module)."""
    files = module_files(root, packages)
    graph: dict[str, set[str]] = {}
    for name, f in files.items():
        is_package = f.name == "__init__.py"
        here = name.split(".") if is_package else name.split(".")[:-1]
        edges = set()
        for node in ast.walk(ast.parse(f.read_text(), filename=str(f))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here[:len(here) - node.level + 1]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                targets = [module] + [f"{module}.{a.name}" for a in node.names]
            else:
                continue
            edges |= {t for t in targets if t in files and t != name
                      and not name.startswith(t + ".")}
        graph[name] = edges
    return graph


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                circles.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return circles


def test_no_import_circles():
    graph = import_graph(ROOT)
    assert len(graph) > 50
    assert not import_circles(graph), import_circles(graph)


def test_the_circle_checker_sees_a_planted_circle(tmp_path):
    pkg = tmp_path / "svss_proc"
    (pkg / "products").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "tiles.py").write_text("from typing import TYPE_CHECKING\n"
                                  "if TYPE_CHECKING:\n    from .products import chain\n")
    (pkg / "products" / "__init__.py").write_text("from .chain import save\n")
    (pkg / "products" / "chain.py").write_text("def save():\n"
                                               "    from ..tiles import write\n")
    (pkg / "worker.py").write_text("import svss_proc.tiles\n")
    graph = import_graph(tmp_path, ("svss_proc",))
    assert import_circles(graph) == [["svss_proc.products", "svss_proc.products.chain",
                                      "svss_proc.tiles"]]

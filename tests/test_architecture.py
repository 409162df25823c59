"""The dependency rules of docs/architecture.md, read from the source (never by importing
it): svss_daq is the base and imports none of the other three; svss_proc imports svss_daq
only (the imager never knows the truth it is tested against); sim_device imports
svss_daq only (the simulator never reuses the processing: what both need sits in
svss_daq); svss sits on top. No import circle among the packages' modules and the
benchmarks. No sound speed has a default in code (function parameters, command-line
options): it comes from the configuration. Omitted configuration keys get their
defaults from the schema, not from code."""

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


#: what each package may not import (docs/architecture.md, "Dependency rules"); svss
#: may import all three
FORBIDDEN = {
    "svss_daq": {"svss_proc", "sim_device", "svss"},
    "svss_proc": {"sim_device", "svss"},
    "sim_device": {"svss_proc", "svss"},
}


@pytest.mark.parametrize("package, forbidden", sorted(FORBIDDEN.items()))
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


def test_the_rules_are_the_documented_ones():
    """FORBIDDEN says what docs/architecture.md's "Dependency rules" say."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    rules = " ".join(text[text.index("## Dependency rules"):].split())
    assert ("`svss_daq` is the base: it imports neither `svss_proc` nor `sim_device` nor "
            "`svss`") in rules
    assert "`svss_proc` imports `svss_daq` only" in rules
    assert "`sim_device` imports `svss_daq` only" in rules
    assert set(FORBIDDEN) | {"svss"} == set(PACKAGES)


#: packages and script folders whose code may hold no sound-speed default
SPEED_CODE = ("svss", "svss_daq", "svss_proc", "sim_device", "benchmarks")

#: reviewed: file -> (findings, why they are not a sound speed the chain computes with)
NOT_SPEED_DEFAULTS = {
    "svss_daq/protocols/pd0_encoder.py": (1, "encode_ensemble's sound_speed_m_s: the "
                                          "value a DVL reports in its PD0 record (the "
                                          "emulators' wire field), not one the chain uses"),
}


def sound_speed_defaults(path: Path) -> list[str]:
    """Sound speeds given a default in ``path``: parameters named c, cw, cs or
    ``*sound_speed*`` with a default, and command-line options (``add_argument``) named
    ``--c``, ``--cw``, ``--cs`` or ``*sound-speed*``/``*sound_speed*`` with a default
    other than None. Returns "line: name" for each."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            args = node.args
            positional = args.posonlyargs + args.args
            named = positional[len(positional) - len(args.defaults):] + [
                a for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None]
            out += [f"{node.lineno}: {a.arg}" for a in named
                    if a.arg in ("c", "cw", "cs") or "sound_speed" in a.arg]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr == "add_argument"):
            names = [a.value for a in node.args
                     if isinstance(a, ast.Constant) and isinstance(a.value, str)]
            default = next((k.value for k in node.keywords if k.arg == "default"), None)
            if (any(n in ("--c", "--cw", "--cs") or "sound-speed" in n
                    or "sound_speed" in n for n in names)
                    and default is not None
                    and not (isinstance(default, ast.Constant) and default.value is None)):
                out.append(f"{node.lineno}: {names[0]}")
    return out


def unreviewed(folders, finder, reviewed: dict) -> dict:
    """The files under ``folders`` whose findings (``finder(path)``, a list) are not the
    number ``reviewed`` gives them (file -> (count, why); none when not named)."""
    found = {str(f.relative_to(ROOT)): finder(f)
             for folder in folders for f in sorted((ROOT / folder).rglob("*.py"))}
    return {f: hits for f, hits in found.items() if len(hits) != reviewed.get(f, (0,))[0]}


def test_no_sound_speed_defaults_in_code():
    assert not unreviewed(SPEED_CODE, sound_speed_defaults, NOT_SPEED_DEFAULTS)


def test_the_speed_checker_sees_planted_defaults(tmp_path):
    f = tmp_path / "m.py"
    f.write_text(
        "import argparse\n"
        "def delay(r, c=1500.0, *, cs=None, water_sound_speed=1480.0):\n"
        "    return r / c\n"
        "def main():\n"
        "    p = argparse.ArgumentParser()\n"
        "    p.add_argument('--sound-speed', type=float, default=1500.0)\n"
        "    p.add_argument('--cw', type=float, default=None)\n"          # from the config
        "    p.add_argument('--speed', type=float, default=1.0)\n"        # the boat's
        "    p.add_argument('--sediment-sound-speed', type=float)\n")
    assert sound_speed_defaults(f) == ["2: c", "2: cs", "2: water_sound_speed",
                                       "6: --sound-speed"]


# ------------------------------------------------------------------- import circles

PACKAGES = ("svss", "svss_daq", "svss_proc", "sim_device")
#: folders of scripts (not packages) run with their folder on sys.path, so that they
#: import each other by file name (``import bench_focus``)
SCRIPT_FOLDERS = ("benchmarks",)


def module_files(root: Path, packages=PACKAGES, scripts=()) -> dict[str, Path]:
    """Module name -> file for every module of ``packages`` under ``root`` (a package is
    its ``__init__.py``) and every script of the folders ``scripts`` (named by its file
    name, as its neighbours import it)."""
    out = {}
    for package in packages:
        for f in sorted((root / package).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = f
    for folder in scripts:
        for f in sorted((root / folder).glob("*.py")):
            assert f.stem not in out, f"{f}: its name is also a module's"
            out[f.stem] = f
    return out


def import_graph(root: Path, packages=PACKAGES, scripts=()) -> dict[str, set[str]]:
    """Module -> the modules of ``packages`` it imports, anywhere in its file (inside
    functions and ``if TYPE_CHECKING`` too), relative imports resolved; ``from P import m``
    names the submodule ``P.m`` when there is one, and the package ``P`` (its
    ``__init__``, whose own imports are its edges) unless ``P`` holds the importing
    module (Python has initialised it before the module). ``scripts``: script folders, as
    :func:`module_files`."""
    files = module_files(root, packages, scripts)
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
    """None among the packages' modules and the benchmarks (which import the packages
    and each other)."""
    graph = import_graph(ROOT, PACKAGES, SCRIPT_FOLDERS)
    assert len(graph) > 50 and "bench_focus" in graph and "sim_device.synthesis" in graph
    assert "bench_isa" in graph["bench_sim_pass2"]            # scripts' imports are seen
    assert not import_circles(graph), import_circles(graph)


def test_the_circle_checker_sees_a_circle_of_scripts(tmp_path):
    (tmp_path / "svss_daq").mkdir()
    (tmp_path / "svss_daq" / "__init__.py").write_text("")
    bench = tmp_path / "benchmarks"
    bench.mkdir()
    (bench / "bench_a.py").write_text("import svss_daq\ndef main():\n"
                                      "    import helper_b as hb\n")
    (bench / "helper_b.py").write_text("def main():\n    import bench_a\n")
    (bench / "bench_c.py").write_text("from helper_b import main\n")
    graph = import_graph(tmp_path, ("svss_daq",), ("benchmarks",))
    assert graph["bench_a"] == {"svss_daq", "helper_b"}
    assert import_circles(graph) == [["bench_a", "helper_b"]]


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


# ------------------------------------------------------------------ defaults in code

#: names that hold configuration objects (a loaded file's value, one of its tables)
CONFIG_ROOTS = {"cfg", "pcfg", "hcfg", "config", "processing", "hardware", "daq", "sub",
                "scene"}


def _config_chain(node: ast.AST) -> bool:
    """An attribute chain rooted at a configuration object (``cfg.x``, ``daq.a.b``,
    ``self.processing.value.x``)."""
    if not isinstance(node, ast.Attribute):
        return False
    names = []
    while isinstance(node, ast.Attribute):
        names.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        names.append(node.id)
    return (bool(CONFIG_ROOTS & set(names[1:]))
            or "value" in names[1:] and not isinstance(node, ast.Call))


def _literal(node: ast.AST) -> bool:
    """A literal or a module constant (an upper-case name) other than None."""
    return ((isinstance(node, ast.Constant) and node.value is not None)
            or (isinstance(node, ast.Name) and node.id.isupper()))


def defaults_in_code(path: Path) -> list[int]:
    """Lines of ``path`` that give an omitted configuration key a value: ``cfg.x if
    cfg.x is not None else 5``, ``DEFAULT if cfg.x is None else cfg.x``, ``cfg.x or 5``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.IfExp):
            t = node.test
            if (isinstance(t, ast.Compare) and len(t.ops) == 1
                    and isinstance(t.ops[0], (ast.Is, ast.IsNot))
                    and isinstance(t.comparators[0], ast.Constant)
                    and t.comparators[0].value is None and _config_chain(t.left)):
                fallback = node.body if isinstance(t.ops[0], ast.Is) else node.orelse
                if _literal(fallback):
                    out.append(node.lineno)
        elif isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or):
            if _config_chain(node.values[0]) and any(map(_literal, node.values[1:])):
                out.append(node.lineno)
    return out


#: reviewed: file -> how many findings, and why they are not a default of an omitted key
NOT_DEFAULTS = {
    "svss_daq/nav/fusion.py": (1, "origin_height_m or 0.0: with the origin's latitude and "
                               "longitude given, an omitted height is 0; omitted with "
                               "them, the first fix's (depends on other keys)"),
    "svss_daq/nav/navigator.py": (1, "the same origin rule as svss_daq/nav/fusion.py"),
}


def test_no_defaults_in_code():
    """Defaults of omitted configuration keys are the loader's (``spec(default=...)``)."""
    assert not unreviewed(("svss", "svss_daq", "svss_proc"), defaults_in_code, NOT_DEFAULTS)


def test_the_defaults_checker_sees_a_planted_default(tmp_path):
    f = tmp_path / "m.py"
    f.write_text(
        "def f(cfg, daq, processing, x, self):\n"
        "    a = cfg.products.max_labels if cfg.products.max_labels is not None else 12\n"
        "    b = GAP_WAIT_S if daq.subscriber.gap_wait_s is None else daq.subscriber.gap_wait_s\n"
        "    c = processing.value.tile.close_after_pings or 20\n"
        "    d = x.start if x.start is not None else 0\n"                 # not configuration
        "    e = self.resume_sequence if self.resume_sequence is not None else 0\n"
        "    g = None if cfg.products is None else cfg.products.dpi\n"  # no default given
        "    return a, b, c, d, e, g\n")
    assert defaults_in_code(f) == [2, 3, 4]


#: what the imaging core (its kernels, their scheduling and the tile it forms) may import
#: of svss_proc besides itself: the conditioning of pings and the preflight of a
#: configuration; never the files, the products or the workers (docs/architecture.md)
IMAGING_MAY_USE = ("svss_proc.conditioning", "svss_proc.preflight")


def test_the_imaging_core_knows_no_files_and_no_products():
    graph = import_graph(ROOT)
    bad = {m: sorted(t for t in ts if t.startswith("svss_proc.")
                     and not t.startswith("svss_proc.imaging")
                     and t not in IMAGING_MAY_USE and t != "svss_proc")
           for m, ts in graph.items() if m.startswith("svss_proc.imaging")}
    assert not {m: v for m, v in bad.items() if v}, bad
    # and the checker sees such an import: the tile file module imports the products
    assert "svss_proc.products.detect" in graph["svss_proc.tiles"]

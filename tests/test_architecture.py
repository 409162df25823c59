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

"""The layers import downwards only: ``envs`` (the simulator and its faces) imports neither ``zoo``
nor ``benchmark``; ``zoo`` (the deciders and their trainers) imports ``envs`` only, never
``benchmark``; ``benchmark`` may import both. Every import counts: at module level or inside a
function, absolute or relative, and ``importlib.import_module`` / ``__import__`` with a literal name."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = {"envs": "overtakezoo.envs", "zoo": "overtakezoo.zoo", "benchmark": "overtakezoo.benchmark"}
FORBIDDEN = {"envs": ("overtakezoo.zoo", "overtakezoo.benchmark"), "zoo": ("overtakezoo.benchmark",)}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [PACKAGE[rel.parts[0]], *rel.parts[1:]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path``, function bodies included."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            # `from overtakezoo import benchmark` imports a module too: count each imported name.
            found += [(node.lineno, target)] + [(node.lineno, f"{target}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if called in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                found.append((node.lineno, node.args[0].value))
    return found


def violations(layer: str) -> list[str]:
    out = []
    for path in sorted((ROOT / layer).rglob("*.py")):
        for line, target in imports(path):
            if any(target == f or target.startswith(f + ".") for f in FORBIDDEN[layer]):
                out.append(f"{path.relative_to(ROOT)}:{line} imports {target}")
    return out


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_a_layer_imports_no_layer_above_it(layer):
    assert violations(layer) == [], f"{layer}/ imports {' or '.join(FORBIDDEN[layer])}"


def test_the_import_scan_sees_every_form_of_import(tmp_path, monkeypatch):
    fake = tmp_path / "zoo" / "train"
    fake.mkdir(parents=True)
    (fake / "x.py").write_text(
        "import importlib\n"
        "def f():\n"
        "    from ...benchmark import runner\n"
        "    from overtakezoo import benchmark\n"
        "    import overtakezoo.benchmark.results.metrics\n"
        "    importlib.import_module('overtakezoo.benchmark.datasets.store')\n"
        "from ..members import learned\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert violations("zoo") == [
        "zoo/train/x.py:3 imports overtakezoo.benchmark",
        "zoo/train/x.py:3 imports overtakezoo.benchmark.runner",
        "zoo/train/x.py:4 imports overtakezoo.benchmark",
        "zoo/train/x.py:5 imports overtakezoo.benchmark.results.metrics",
        "zoo/train/x.py:6 imports overtakezoo.benchmark.datasets.store",
    ]


def test_every_import_of_the_project_resolves():
    """Every ``from overtakezoo... import name`` in the package, lazy ones inside functions included,
    names a module that exists and a name it defines: a moved module leaves no import behind that
    only fails when its code path runs (the performance report's hook once did)."""
    import importlib
    import importlib.util

    broken = []
    for folder in PACKAGE:
        for path in sorted((ROOT / folder).rglob("*.py")):
            name = module_name(path)
            package = name if path.name == "__init__.py" else name.rpartition(".")[0]
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if not isinstance(node, ast.ImportFrom):
                    continue
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target.startswith("overtakezoo"):
                    continue
                where = f"{path.relative_to(ROOT)}:{node.lineno}"
                if _spec(target) is None:
                    broken.append(f"{where}: no module {target}")
                    continue
                module = importlib.import_module(target)
                for alias in node.names:
                    if not (hasattr(module, alias.name) or _spec(f"{target}.{alias.name}")):
                        broken.append(f"{where}: {target} has no {alias.name}")
    assert broken == []


def _spec(name: str):
    import importlib.util

    try:
        return importlib.util.find_spec(name)
    except ModuleNotFoundError:  # a parent package that does not exist
        return None

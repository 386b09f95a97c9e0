"""The package reads as a pipeline: imports run one way, and the deployed runtime needs no torch.

core -> geometry -> cues -> formats -> metrics -> datasets -> models -> inference -> training
-> export -> viz -> evaluation -> CLI (the ``xvmatch`` root): each folder may import only the
folders before it (``viz`` needs only ``core``). Every import statement of every module is read
from the source (lazy imports inside functions included), so a rule cannot be broken by importing
late.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = ("core", "geometry", "cues", "formats", "metrics", "datasets", "models", "inference",
            "training", "export", "viz", "evaluation", "xvmatch")
"""The subpackages in pipeline order."""
SUBPACKAGES = PIPELINE

ALLOWED: dict[str, set[str]] = {p: set(PIPELINE[:k + 1]) for k, p in enumerate(PIPELINE)}
"""Which subpackages each subpackage may import: itself and those before it, no exceptions
(``models`` and ``inference`` do not import each other: the matcher file format is in
``models``, the deployed runtime in ``inference``)."""
ALLOWED["inference"] -= {"models", "metrics"}
ALLOWED["viz"] = {"core", "geometry", "cues", "formats", "viz"}

TORCH_FREE = ("core", "geometry", "cues", "formats", "metrics", "datasets", "inference", "viz")
"""Subpackages that never import torch, lightning or onnx (the base install runs them)."""
HEAVY = {"torch", "torchvision", "lightning", "onnx"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every import in a file (``from x import y`` gives ``x.y``
    for package-level names, so ``from xvmatch.metrics import cross_view_metrics`` counts)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return out


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).glob("*.py"))


@pytest.mark.slow
@pytest.mark.parametrize("package", SUBPACKAGES)
def test_imports_run_one_way(package: str) -> None:
    bad = []
    for path in _modules(package):
        for line, name in _imports(path):
            parts = name.split(".")
            if parts[0] != "xvmatch" or len(parts) < 2:
                continue
            target = "xvmatch" if parts[1] not in SUBPACKAGES else parts[1]
            if target in ALLOWED[package]:
                continue
            # `from xvmatch.evaluation import x` lists both the package and x: judge by x.
            if len(parts) == 2 and any(
                other.startswith(name + ".") for _, other in _imports(path)
            ):
                continue
            bad.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not bad, "imports against the pipeline:\n" + "\n".join(bad)


@pytest.mark.slow
@pytest.mark.parametrize("package", TORCH_FREE)
def test_torch_free_subpackages_import_no_torch(package: str) -> None:
    bad = [
        f"{path.relative_to(ROOT)}:{line}: imports {name}"
        for path in _modules(package)
        for line, name in _imports(path)
        if name.split(".")[0] in HEAVY
    ]
    assert not bad, "\n".join(bad)


LAZY_TORCH = ("evaluation",)
"""Subpackages that may use torch, but only inside the functions that need it: importing them
(the CLI's evaluate, ablate and baseline do) must not load torch."""


def _module_level_imports(path: Path) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of the imports run when the module is imported (not those inside
    functions or under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in tree.body:
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
    return out


@pytest.mark.parametrize("package", LAZY_TORCH)
def test_lazy_torch_subpackages_import_torch_only_inside_functions(package: str) -> None:
    heavy_packages = {"models", "training", "export"}  # their modules import torch
    bad = [
        f"{path.relative_to(ROOT)}:{line}: imports {name} when the module is imported"
        for path in _modules(package)
        for line, name in _module_level_imports(path)
        if name.split(".")[0] in HEAVY
        or (name.startswith("xvmatch.") and name.split(".")[1] in heavy_packages)
    ]
    assert not bad, "\n".join(bad)


def test_the_rules_cover_every_subpackage() -> None:
    on_disk = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"tests", "benchmarks"}
    assert on_disk <= set(SUBPACKAGES)

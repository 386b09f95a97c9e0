"""The package reads as a pipeline: imports run one way, and the deployed runtime needs no torch.

core -> geometry -> cues -> formats -> metrics -> datasets -> models -> inference -> training
-> export -> viz -> evaluation -> CLI (the ``xvmatch`` root): each folder may import only the
folders before it (``viz`` needs only ``core``). Inside ``inference`` the stages run the same way,
linking -> adaptation -> matching -> tracks -> views: each may import only the stages before it.
Every import statement of every module is read from the source (lazy imports inside functions
included), so a rule cannot be broken by importing late. No folder holds more than
:data:`MAX_MODULES` modules.
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
    """Every module of a subpackage, its own subpackages' included (``inference``'s stages)."""
    return sorted((ROOT / package).rglob("*.py"))


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


INFERENCE_STAGES = ("linking", "adaptation", "matching", "tracks", "views")
"""The stages of ``inference`` in pipeline order: what every stage shares (one frame's assignment,
tracklets) -> site adaptation (mined pairs, the adaptation map) -> matching one frame (bundles,
learned association, the checks) -> tracking over time -> several views. Each may import only
itself and the stages before it, no exceptions."""
MAX_MODULES = 15
"""The most modules (``__init__.py`` aside) one folder may hold."""


def _stage_of(name: str) -> str | None:
    """The inference stage a dotted ``xvmatch.inference.<stage>...`` name falls in, else None."""
    parts = name.split(".")
    if parts[:2] != ["xvmatch", "inference"] or len(parts) < 3:
        return None
    return parts[2]


@pytest.mark.parametrize("stage", INFERENCE_STAGES)
def test_inference_stages_import_only_earlier_stages(stage: str) -> None:
    allowed = set(INFERENCE_STAGES[:INFERENCE_STAGES.index(stage) + 1])
    bad = []
    for path in sorted((ROOT / "inference" / stage).glob("*.py")):
        names = _imports(path)
        for line, name in names:
            target = _stage_of(name)
            if target is None or target in allowed:
                continue
            # `from xvmatch.inference import tracks` lists both the package and the stage
            if target not in INFERENCE_STAGES and any(
                other.startswith(name + ".") for _, other in names
            ):
                continue
            bad.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not bad, "imports against the inference stages:\n" + "\n".join(bad)


def test_inference_modules_live_in_stages() -> None:
    """``inference/`` holds only its stages (and the shipped bundle's data): no loose module, and
    every stage folder is named in :data:`INFERENCE_STAGES`."""
    loose = [p.name for p in (ROOT / "inference").glob("*.py") if p.name != "__init__.py"]
    assert not loose, f"modules outside the inference stages: {loose}"
    stages = {p.parent.name for p in (ROOT / "inference").glob("*/__init__.py")}
    assert stages == set(INFERENCE_STAGES)


def test_stage_folders_say_their_job() -> None:
    """Each stage's ``__init__.py`` has a docstring saying its job and what it may import."""
    missing = [stage for stage in INFERENCE_STAGES
               if "import" not in (ast.get_docstring(ast.parse(
                   (ROOT / "inference" / stage / "__init__.py").read_text())) or "")]
    assert not missing, f"stages without a docstring saying what they may import: {missing}"


def _package_folders() -> list[Path]:
    """Every folder of the package (each holding an ``__init__.py``), outside hidden folders."""
    return [init.parent for init in sorted(ROOT.rglob("__init__.py"))
            if not any(part.startswith(".") or part == "build"
                       for part in init.parent.relative_to(ROOT).parts)]


CROWDED: dict[str, str] = {}
"""Folders known to be over :data:`MAX_MODULES`, each with the change that brings it under: the
mark is strict, so the test fails once the folder is under the bar and the entry must go."""


@pytest.mark.parametrize("folder", [
    pytest.param(f, marks=pytest.mark.xfail(
        strict=True, reason=CROWDED[f.relative_to(ROOT).as_posix()]))
    if f.relative_to(ROOT).as_posix() in CROWDED else f
    for f in _package_folders()], ids=lambda f: f.relative_to(ROOT).as_posix() or "root")
def test_no_folder_holds_more_than_max_modules(folder: Path) -> None:
    count = sum(1 for p in folder.glob("*.py") if p.name != "__init__.py")
    assert count <= MAX_MODULES, f"{folder.relative_to(ROOT)}: {count} modules"


COMMAND_FOLDERS = ("xvmatch/commands", "xvmatch/commands/lab")
"""The command line's package (checked as the ``xvmatch`` root is: its import rules, the bar of
:data:`MAX_MODULES` modules): one module per command, the shared options beside them."""
MAX_COMMAND_LINES = 250
"""The most lines one command module may hold: a command parses, checks, builds its options and
calls a library run (issue 66)."""
LONG_COMMANDS = {
}
"""Command modules known to be over :data:`MAX_COMMAND_LINES`, each with the change that brings it
under (strict marks, as :data:`CROWDED`)."""


def test_command_folders_say_their_job() -> None:
    """The command package lies under the ``xvmatch`` root (so the root's import rules cover it),
    and each of its folders' ``__init__.py`` says its job and what it may import."""
    missing = [folder for folder in COMMAND_FOLDERS
               if "import" not in (ast.get_docstring(ast.parse(
                   (ROOT / folder / "__init__.py").read_text())) or "")]
    assert not missing, f"command folders not saying what they may import: {missing}"
    on_disk = {init.parent.relative_to(ROOT).as_posix()
               for init in (ROOT / "xvmatch").rglob("__init__.py")} - {"xvmatch"}
    assert on_disk == set(COMMAND_FOLDERS)


def _command_modules() -> list[Path]:
    return sorted(p for folder in COMMAND_FOLDERS for p in (ROOT / folder).glob("*.py"))


@pytest.mark.parametrize("path", [
    pytest.param(p, marks=pytest.mark.xfail(strict=True, reason=LONG_COMMANDS[key]))
    if (key := p.relative_to(ROOT).as_posix()) in LONG_COMMANDS else p
    for p in _command_modules()], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_command_module_is_long(path: Path) -> None:
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_COMMAND_LINES, f"{path.relative_to(ROOT)}: {lines} lines"

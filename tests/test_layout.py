"""The layout rule of ``common/``: dependencies between its subpackages point one way.

``LAYERS`` is the rule written down: each part of ``ovis.common`` may import only the
parts listed for it (and itself). Nothing in ``common`` imports ``ovis.services``. A new
subpackage or top-level module must be added here, so that the rule covers it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

COMMON = Path(__file__).resolve().parents[1] / "common"

#: What the parts on top (the running pipeline, the offline analysis) build on.
FOUNDATION = {
    "config",
    "atomic",
    "camera",
    "vision",
    "solids",
    "world",
    "calibration",
    "sim",
    "physical",
    "capture",
    "messages",
}

#: part of ovis.common → the parts it may import (besides itself).
LAYERS: dict[str, set[str]] = {
    "config": {"presets"},
    "atomic": set(),
    "presets": set(),
    "camera": {"config", "atomic"},
    "vision": {"config"},
    "solids": {"config", "camera", "vision"},
    "world": {"config", "camera", "vision", "solids"},
    "calibration": {"config", "atomic", "camera", "vision"},
    "sim": {"config", "atomic", "camera", "vision"},
    "physical": {"config", "atomic", "camera", "vision", "sim", "calibration"},
    "capture": {"config", "atomic", "camera", "sim", "vision", "physical", "navigation", "world"},
    "messages": {"config", "camera", "vision", "solids", "world", "calibration", "sim"},
    "pipeline": FOUNDATION | {"trust"},
    "analysis": FOUNDATION | {"fusion"},
    "view": {"config", "camera", "calibration", "messages"},
    "fusion": {"config", "camera"},
    "trust": {"atomic", "config"},
    "ros2": {"config", "camera", "calibration", "messages", "fusion", "vision"},
    "navigation": FOUNDATION - {"capture", "messages"},
}

#: Recording stores and replays messages: what they may import, plus them and atomic files.
LAYERS["recording"] = LAYERS["messages"] | {"messages", "atomic"}


def part_of(path: Path) -> str:
    """The part of ``ovis.common`` a source file belongs to (subpackage or module)."""
    rel = path.relative_to(COMMON)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """Every absolute module a file imports, with its line (``from a import b`` gives
    ``a.b`` too, so ``from ovis.common import camera`` is seen as importing camera)."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return found


def violations(path: Path) -> list[str]:
    """The imports of one file that break :data:`LAYERS`, as readable lines."""
    part = part_of(path)
    allowed = LAYERS[part] | {part}
    bad: list[str] = []
    seen: set[tuple[int, str]] = set()
    for line, module in imported_modules(path):
        key = (line, ".".join(module.split(".")[:3]))  # one report per line and part
        if key in seen:
            continue
        seen.add(key)
        where = f"{path.relative_to(COMMON.parent)}:{line}"
        if module.startswith("ovis.services"):
            bad.append(f"{where} imports {module}: common never imports services")
        elif module.startswith("ovis.common."):
            target = module.split(".")[2]
            if target in LAYERS and target not in allowed:
                bad.append(f"{where} ({part}) imports {module}: {part} may import {allowed}")
    return bad


SOURCES = sorted(p for p in COMMON.rglob("*.py") if p.name != "__init__.py" or p.parent != COMMON)


def test_every_part_has_a_rule() -> None:
    parts = {part_of(p) for p in SOURCES}
    assert parts <= set(LAYERS), f"add {parts - set(LAYERS)} to LAYERS"


def test_every_subpackage_says_what_it_holds_and_may_import() -> None:
    for init in COMMON.glob("*/__init__.py"):
        if init.parent.name == "presets":
            continue
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert "May import" in doc, f"{init}: its docstring must say what it may import"


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(COMMON)))
def test_imports_follow_the_layers(path: Path) -> None:
    assert violations(path) == []


def test_the_rule_catches_a_wrong_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The checker itself: vision importing calibration, or common importing services,
    is reported."""
    fake = tmp_path / "common"
    (fake / "vision").mkdir(parents=True)
    bad = fake / "vision" / "bad.py"
    bad.write_text(
        "from ovis.common.calibration.dipe import dipe\n"
        "from ovis.common import world\n"
        "import ovis.services.bus\n"
        "from ovis.common.config import OvisConfig\n"
    )
    monkeypatch.setattr(f"{__name__}.COMMON", fake)
    found = violations(bad)
    assert len(found) == 3, found
    assert "common never imports services" in found[2]


CLI = COMMON.parent / "services" / "cli"
CLI_PACKAGE = "ovis.services.cli"


def cli_imports(path: Path) -> list[tuple[int, str, str]]:
    """(line, module, name) of every ``from ovis.services.cli.X import name`` in a file."""
    found: list[tuple[int, str, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(CLI_PACKAGE + "."):
            module = node.module.removeprefix(CLI_PACKAGE + ".")
            found += [(node.lineno, module, alias.name) for alias in node.names]
    return found


def cli_problems(folder: Path) -> list[str]:
    """Command modules that import another's private names, or import each other
    (directly or round a longer loop): shared options live in ``options.py``."""
    graph: dict[str, set[str]] = {}
    bad: list[str] = []
    for path in sorted(folder.glob("*.py")):
        graph[path.stem] = set()
        for line, module, name in cli_imports(path):
            graph[path.stem].add(module)
            if name.startswith("_"):
                bad.append(f"{path.name}:{line} imports the private {module}.{name}")

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        for nxt in graph.get(start, set()) - seen:
            if nxt == goal or reaches(nxt, goal, seen | {nxt}):
                return True
        return False

    bad += [f"{m} is in an import loop" for m in sorted(graph) if reaches(m, m, set())]
    return bad


def test_command_modules_share_options_and_never_import_each_other() -> None:
    assert cli_problems(CLI) == []


def test_the_command_rule_catches_private_names_and_loops(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text(f"from {CLI_PACKAGE}.b import _config\n")
    (tmp_path / "b.py").write_text(f"def f():\n    from {CLI_PACKAGE}.c import run\n")
    (tmp_path / "c.py").write_text(f"from {CLI_PACKAGE}.a import thing\n")
    (tmp_path / "d.py").write_text(f"from {CLI_PACKAGE}.options import JsonOpt\n")
    found = cli_problems(tmp_path)
    assert found == [
        "a.py:1 imports the private b._config",
        "a is in an import loop",
        "b is in an import loop",
        "c is in an import loop",
    ]


def module_of(path: Path, root: Path = COMMON) -> str:
    """The dotted name of a source file under ``root`` (``ovis.common`` …)."""
    parts = path.relative_to(root.parent).with_suffix("").parts
    name = "ovis." + ".".join(parts)
    return name.removesuffix(".__init__")


def import_circles(paths: list[Path], root: Path = COMMON) -> list[list[str]]:
    """The groups of modules that import each other round a circle, imports inside
    functions included (Tarjan's strongly connected components of the import graph)."""
    names = {module_of(p, root): p for p in paths}
    graph = {
        name: {m for _, m in imported_modules(p) if m in names and m != name}
        for name, p in names.items()
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while (w := stack.pop()) != v:
                group.append(w)
            if group:
                circles.append(sorted([v, *group]))

    for name in graph:
        if name not in index:
            visit(name)
    return circles


def test_no_modules_import_each_other_round_a_circle() -> None:
    assert import_circles(SOURCES) == []


def test_the_circle_rule_catches_a_lazy_import_back(tmp_path: Path) -> None:
    pkg = tmp_path / "common" / "calib"
    pkg.mkdir(parents=True)
    (pkg / "problem.py").write_text(
        "def solve():\n    from ovis.common.calib.refine import polish\n    return polish\n"
    )
    (pkg / "refine.py").write_text("from ovis.common.calib.problem import solve\n")
    (pkg / "file.py").write_text("from ovis.common.calib.problem import solve\n")
    found = import_circles(sorted(pkg.glob("*.py")), tmp_path / "common")
    assert found == [["ovis.common.calib.problem", "ovis.common.calib.refine"]]


def _heavy_modules_after(*modules: str) -> set[str]:
    """The scipy and rosbags modules a fresh interpreter holds after importing
    ``modules``."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in modules)
        + "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('scipy', 'rosbags')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_stages_load_scipy_and_rosbags_only_where_they_use_them() -> None:
    """The CLI's entry point, the capture, preprocess and label stages start without
    scipy or ROS 2's type store (slow to import; they never match tracks, fit edges or
    read a ROS 2 message unless a ``ros2:`` source asks); the pose stage loads the
    matcher and the edge model with the process, not on the frame that first needs them
    (a stall there skips frames)."""
    light = _heavy_modules_after(
        "ovis.services.cli",
        "ovis.services.capture",
        "ovis.services.preprocess",
        "ovis.services.label",
    )
    assert light == set(), sorted(light)
    assert {"scipy.optimize", "scipy.spatial", "scipy.special"} <= _heavy_modules_after(
        "ovis.services.pose"
    )

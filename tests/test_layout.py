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
    "world": {"config", "camera", "vision"},
    "calibration": {"config", "atomic", "camera", "vision"},
    "sim": {"config", "atomic", "camera", "vision"},
    "physical": {"config", "atomic", "camera", "vision", "sim", "calibration"},
    "capture": {"config", "atomic", "camera", "sim", "vision", "physical"},
    "messages": {"config", "camera", "vision", "world", "calibration", "sim"},
    "pipeline": FOUNDATION | {"trust"},
    "analysis": FOUNDATION | {"fusion"},
    "view": {"config", "camera", "calibration", "messages"},
    "fusion": {"config", "camera"},
    "trust": {"atomic", "config"},
    "ros2": {"config", "camera", "calibration", "messages", "fusion", "vision"},
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

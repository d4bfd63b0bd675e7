"""The documentation holds together: every relative link in the repository's Markdown
resolves (to a file, and to a heading where it names one), the README stays short and
opens with the two commands CI and users rely on, and the benchmark tables are the ones
``benchmarks/run.py`` renders from ``results.json``, not hand-edited figures."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: The first command of the README: run ovis on the simulated arena (users copy it).
RUN_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install -q -e . && .venv/bin/ovis up --duration 20"
)

SKIPPED_DIRS = {".venv", ".git", "node_modules", "build", "dist"}
FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.MULTILINE)


def markdown_files() -> list[Path]:
    """Every Markdown file of the repository (not of the venv, caches or build output)."""
    return sorted(
        p
        for p in ROOT.rglob("*.md")
        if not any(
            part in SKIPPED_DIRS or part.startswith(".") or part.endswith(".egg-info")
            for part in p.relative_to(ROOT).parts[:-1]
        )
    )


def prose(text: str) -> str:
    """The text without code blocks and inline code, where a ``[x](y)`` is no link."""
    return INLINE_CODE.sub("", FENCE.sub("", text))


def links(text: str) -> list[str]:
    """The targets of the inline links and images of a Markdown text."""
    return LINK.findall(prose(text))


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: a link's text only, lower case, punctuation but
    '-' and '_' dropped, spaces → '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings (a repeated one gets -1, -2 …)."""
    found: set[str] = set()
    for heading in HEADING.findall(FENCE.sub("", path.read_text("utf-8"))):
        base = slug(heading)
        name, n = base, 0
        while name in found:
            n += 1
            name = f"{base}-{n}"
        found.add(name)
    return found


def broken_links(path: Path) -> list[str]:
    """The relative links of one Markdown file that do not resolve, as readable lines."""
    bad: list[str] = []
    for target in links(path.read_text("utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):
            continue  # http:, https:, mailto: … are not checked here
        file_part, _, anchor = target.partition("#")
        resolved = (path.parent / file_part).resolve() if file_part else path
        where = f"{path.relative_to(ROOT)}: [{target}]"
        if not resolved.exists():
            bad.append(f"{where} → {resolved} does not exist")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            bad.append(f"{where} → no heading #{anchor} in {resolved.name}")
    return bad


def readme_commands() -> list[str]:
    """The commands of the README's code blocks, in order."""
    blocks = re.findall(r"^```(?:bash|sh)?\n(.*?)^```", README.read_text("utf-8"), re.M | re.S)
    return [line for block in blocks for line in block.splitlines() if line.strip()]


def ci_test_command() -> str:
    """The line of ``.ci/run`` between its "README test command" markers."""
    text = (ROOT / ".ci" / "run").read_text("utf-8")
    match = re.search(r"# --- README test command.*?\n(.*?)\n# ---\n", text, re.S)
    assert match, ".ci/run has no '# --- README test command' … '# ---' block"
    return match.group(1).strip()


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path: Path) -> None:
    assert broken_links(path) == []


def test_the_link_checker_catches_a_broken_link(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The checker itself: a missing file, a missing heading and a missing image are
    reported; links in code, absolute URLs and a good anchor are not."""
    monkeypatch.setattr(f"{__name__}.ROOT", tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# Title\n\n## One machine: many cores\n")
    page = tmp_path / "README.md"
    page.write_text(
        "[ok](docs/a.md#one-machine-many-cores) [gone](docs/b.md) [bad](docs/a.md#two)\n"
        "![pic](docs/images/x.png) [web](https://example.org/x.md) `[code](nowhere.md)`\n"
        "[self](#top)\n\n# Top\n\n```\n[fenced](nowhere.md)\n```\n"
    )
    found = broken_links(page)
    assert len(found) == 3, found
    assert "docs/b.md" in found[0] and "#two" in found[1] and "x.png" in found[2]


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {(ROOT / t.partition("#")[0]).resolve() for t in links(README.read_text("utf-8"))}
    pages = {p.resolve() for p in (ROOT / "docs").glob("*.md")}
    assert pages - linked == set(), "link these pages from README.md's documentation table"


def test_readme_is_short() -> None:
    lines = README.read_text("utf-8").splitlines()
    assert len(lines) < 150, f"README.md has {len(lines)} lines; move reference to docs/"


def test_readme_opens_with_the_run_and_the_ci_test_command() -> None:
    first, second = readme_commands()[:2]
    assert first == RUN_COMMAND
    assert second == ci_test_command()


def test_benchmark_tables_are_rendered_from_the_results(monkeypatch: pytest.MonkeyPatch) -> None:
    """The tables between the markers are exactly what ``python -m benchmarks.run
    --render`` writes from results.json and machine.json: no figure edited by hand."""
    monkeypatch.syspath_prepend(str(ROOT))
    from benchmarks import run

    rows = json.loads(run.RESULTS.read_text("utf-8"))
    machine = json.loads(run.MACHINE.read_text("utf-8"))
    for page in run.PAGES:
        text = page.read_text("utf-8")
        assert text.count(run.START) == 1 and text.count(run.END) == 1, page
        between = text.split(run.START, 1)[1].split(run.END, 1)[0].strip()
        expected = run.page_table(page, rows, machine)
        assert between == expected, f"{page.name}: rerun python -m benchmarks.run --render"


def test_ci_installs_what_the_physical_world_names_and_requires_it() -> None:
    """`.ci/run` installs the Debian packages the physical world's one-line error names
    (so the two cannot drift apart) and makes its tests fail instead of skipping."""
    from ovis.common.physical.availability import DEBIAN_PACKAGES

    text = (ROOT / ".ci" / "run").read_text("utf-8")
    listed = re.search(r'^gl="([^"]*)"$', text, re.M)
    assert listed and listed.group(1).split() == list(DEBIAN_PACKAGES)
    assert re.search(r"^export OVIS_REQUIRE_PHYSICAL=1$", text, re.M)

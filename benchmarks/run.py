"""Run the benchmarks: ``python -m benchmarks.run [--quick] [--only NAME...] [--long]``
from the repository root.

Writes ``benchmarks/results.json`` (a JSON list of rows: ``name``, ``unit``, ``value``,
``floor``, ``ratio``, ``target``, ``met``), ``benchmarks/machine.json`` (CPU, cores,
versions, date) and the tables between ``<!-- benchmarks:start -->`` and
``<!-- benchmarks:end -->`` in ``README.md`` (the rows that have a target) and
``docs/benchmarks.md`` (every row). With ``--only``, the rows of the other benchmarks are
kept from the previous results; otherwise all rows are replaced. ``--render`` measures
nothing and rewrites both tables from the two JSON files.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.core import CpuMeter, Row, machine_info

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results.json"
MACHINE = ROOT / "benchmarks" / "machine.json"
START, END = "<!-- benchmarks:start -->", "<!-- benchmarks:end -->"

#: Pages whose table this rewrites, and how: the README (read in five minutes) one line
#: per benchmark with its targets met and the rows that miss one, the benchmarks page
#: every row.
PAGES: dict[Path, Callable[[list[dict[str, Any]]], list[str]]] = {
    ROOT / "README.md": lambda rows: summary_lines(rows),
    ROOT / "docs" / "benchmarks.md": lambda rows: row_lines(rows),
}

#: Benchmark names, in report order, and the prefix of their rows' names.
GROUPS = {
    "pipeline": "Frame pipeline",
    "scaling": "Scaling",
    "calibration": "GA calibration",
    "e2e": "End to end",
    "view": "Live view",
    "robots": "Marked robots",
    "fusion": "Fusion",
    "budget": "CPU budget",
    "memory": "Memory",
    "recording": "Recording",
    "recovery": "Recovery",
    "trust": "Proof of origin",
    "ros2": "ROS 2 output",
    "heights": "Measured heights",
    "physical": "Physical world",
}
DEFAULT = (
    "pipeline",
    "scaling",
    "calibration",
    "e2e",
    "view",
    "recording",
    "robots",
    "recovery",
    "fusion",
    "trust",
    "ros2",
    "heights",
    "budget",
    "physical",
)


def log(message: str) -> None:
    print(message, flush=True)


#: Benchmarks measured by one ``rows(quick, log)`` function: name → (module, function).
TIMED = {
    "calibration": ("benchmarks.calibration", "calibration_rows"),
    "e2e": ("benchmarks.bus", "e2e_rows"),
    "view": ("benchmarks.view", "view_rows"),
    "recording": ("benchmarks.recording", "recording_rows"),
    "robots": ("benchmarks.robots", "robots_rows"),
    "recovery": ("benchmarks.recovery", "recovery_rows"),
    "fusion": ("benchmarks.fusion", "fusion_rows"),
    "trust": ("benchmarks.trust", "trust_rows"),
    "ros2": ("benchmarks.ros2", "ros2_rows"),
    "budget": ("benchmarks.budget", "budget_rows"),
    "heights": ("benchmarks.heights", "heights_rows"),
    "physical": ("benchmarks.physical", "physical_rows"),
}


def run_groups(names: list[str], quick: bool, memory_s: float) -> list[Row]:
    rows: list[Row] = []
    pipeline = None
    for name in names:
        t0 = time.perf_counter()
        log(f"[{name}]")
        if name in ("pipeline", "scaling") and pipeline is None:
            from benchmarks.pipeline import measure_pipeline

            pipeline = measure_pipeline(quick, log)
        if name == "pipeline":
            from benchmarks.pipeline import pipeline_rows

            rows += pipeline_rows(pipeline)
        elif name == "scaling":
            from benchmarks.pipeline import scaling_rows

            rows += scaling_rows(pipeline, quick, log)
        elif name in TIMED:
            module, function = TIMED[name]
            rows += getattr(importlib.import_module(module), function)(quick, log)
        elif name == "memory":
            from benchmarks.bus import memory_rows

            rows += memory_rows(memory_s, log=log)
        log(f"[{name}] {time.perf_counter() - t0:.0f} s")
    return rows


def group_of(row_name: str) -> str | None:
    for name, prefix in GROUPS.items():
        if row_name.startswith(prefix):
            return name
    return None


def merge(new: list[dict[str, Any]], ran: list[str]) -> list[dict[str, Any]]:
    """The new rows, plus the previous results' rows of the benchmarks not run now."""
    old: list[dict[str, Any]] = []
    if RESULTS.is_file():
        try:
            previous = json.loads(RESULTS.read_text("utf-8"))
            old = [r for r in previous if group_of(r["name"]) not in ran]
        except (ValueError, KeyError, TypeError):
            old = []
    order = list(GROUPS)
    rows = old + new
    rows.sort(key=lambda r: order.index(group_of(r["name"]) or "memory"))
    return rows


def _num(v: float | None, unit: str = "") -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    a = abs(v)
    digits = 0 if a >= 100 or a == 0 else 1 if a >= 10 else 2 if a >= 0.1 else 3
    text = f"{v:.{digits}f}"
    if unit == "×":
        return f"{text}×"
    return f"{text} {unit}".strip()


def row_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Every row: value, floor, ratio, target, met."""
    lines = [
        "| benchmark | value | floor | ratio | target | met |",
        "| --- | ---: | ---: | ---: | --- | :---: |",
    ]
    for r in rows:
        met = {True: "yes", False: "**no**", None: ""}[r["met"]]
        ratio = "" if r["ratio"] is None else f"{r['ratio']:.2f}×"
        floor = "" if r["floor"] is None else _num(r["floor"], r["unit"])
        lines.append(
            f"| {r['name']} | {_num(r['value'], r['unit'])} | {floor} | {ratio} | "
            f"{r['target'] or ''} | {met} |"
        )
    return lines


def summary_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per benchmark: how many of its targets are met, and the rows that miss."""
    lines = ["| benchmark | targets met | missed |", "| --- | ---: | --- |"]
    for name, prefix in GROUPS.items():
        targeted = [r for r in rows if group_of(r["name"]) == name and r.get("target")]
        if not targeted:
            continue
        missed = [
            f"{r['name'][len(prefix) :].lstrip(':, ')}: {_num(r['value'], r['unit'])}"
            + ("" if r["ratio"] is None else f" ({r['ratio']:.2f}×)")
            + f", target {r['target']}"
            for r in targeted
            if r["met"] is False
        ]
        met = sum(r["met"] is True for r in targeted)
        lines.append(f"| {prefix} | {met} of {len(targeted)} | {'; '.join(missed)} |")
    return lines


#: What says how a group's rows were measured (the rest of machine.json is the machine).
RUN_KEYS = ("date", "quick", "load_average_start", "load_average_end", "other_programs_cores")


def group_runs(machine: dict[str, Any], names: list[str], partial: bool) -> dict[str, Any]:
    """When and under what load each group's rows were measured: this run for ``names``,
    the previous machine.json's record for the groups a partial run (``--only``) kept."""
    runs: dict[str, Any] = {}
    if partial and MACHINE.exists():
        runs = dict(json.loads(MACHINE.read_text("utf-8")).get("groups", {}))
    this = {k: machine.get(k) for k in RUN_KEYS}
    runs.update({name: this for name in names})
    return runs


def _run_text(run: dict[str, Any]) -> str:
    """``2026-11-26T01:08:26+00:00 (quick run), load average … at start …``."""
    text = run["date"] + (" (quick run)" if run.get("quick") else "")
    for when in ("start", "end"):
        la = run.get(f"load_average_{when}")
        if la:
            text += f"; load average (1/5/15 min) at {when} {' / '.join(f'{x:.1f}' for x in la)}"
    other = run.get("other_programs_cores")
    if other is not None:
        text += f"; other programs used {other:.1f} of the cores on average meanwhile"
    return text


def table(
    rows: list[dict[str, Any]],
    machine: dict[str, Any],
    render: Callable[[list[dict[str, Any]]], list[str]] = row_lines,
    *,
    runs_page: str | None = None,
) -> str:
    """The rows as ``render`` shows them, the machine, and when and under what load each
    group ran (on ``runs_page``, a link to the page that lists them, when given)."""
    lines = render(rows)
    runs = machine.get("groups") or {}
    shown = [g for g in GROUPS if g in runs and any(group_of(r["name"]) == g for r in rows)]
    # a machine.json from before groups were recorded: one run for all
    when = "Measured on" if shown else f"Measured {_run_text(machine)} on"
    lines += [
        "",
        f"{when} {machine['cpu']} ({machine['cores']} cores), "
        f"{machine['os']}, Python {machine['python']}, numpy {machine['numpy']}, "
        f"OpenCV {machine['opencv']}, eclipse-zenoh {machine['zenoh']}. "
        "Floors are measured in the same run; ratio = value / floor.",
    ]
    if shown and runs_page is not None:
        lines += ["", f"When and under what load each group ran: [{runs_page}]({runs_page})."]
    elif shown:
        unknown = [
            g for g in GROUPS if g not in runs and any(group_of(r["name"]) == g for r in rows)
        ]
        lines += ["", "Each group's run:", ""]
        same: dict[str, list[str]] = {}  # groups measured in one run share a line
        for g in shown:
            same.setdefault(_run_text(runs[g]), []).append(GROUPS[g])
        lines += [f"- {', '.join(names)}: {text}" for text, names in same.items()]
        if unknown:
            lines.append(
                f"- {', '.join(GROUPS[g] for g in unknown)}: before this record was kept "
                "(date and load not recorded)"
            )
    return "\n".join(lines)


def page_table(page: Path, rows: list[dict[str, Any]], machine: dict[str, Any]) -> str:
    """What goes between the markers of ``page`` (one of :data:`PAGES`): the README
    links to the benchmarks page for when each group ran."""
    runs_page = "docs/benchmarks.md" if page == ROOT / "README.md" else None
    return table(rows, machine, PAGES[page], runs_page=runs_page)


def update_page(page: Path, rows: list[dict[str, Any]], machine: dict[str, Any]) -> bool:
    """Rewrite the table between the markers of one page of :data:`PAGES` with ``rows``."""
    text = page.read_text("utf-8")
    if START not in text or END not in text:
        log(f"{page.relative_to(ROOT)} has no {START} … {END} markers; table not written")
        return False
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    text = f"{head}{START}\n{page_table(page, rows, machine)}\n{END}{tail}"
    page.write_text(text, encoding="utf-8")
    return True


def update_pages(rows: list[dict[str, Any]], machine: dict[str, Any]) -> None:
    """Rewrite the table of every page in :data:`PAGES` with the rows it shows."""
    for page in PAGES:
        update_page(page, rows, machine)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.run",
        description="Measure ovis against floors measured in the same run; write "
        "benchmarks/results.json, benchmarks/machine.json and the tables of README.md "
        "and docs/benchmarks.md.",
    )
    parser.add_argument("--quick", action="store_true", help="fewer repetitions, 8 s bus runs")
    parser.add_argument(
        "--only",
        nargs="+",
        choices=list(GROUPS),
        metavar="NAME",
        help=f"run only these ({', '.join(GROUPS)}); other rows are kept from the last run",
    )
    parser.add_argument("--long", action="store_true", help="also the 5-minute bounded-memory run")
    parser.add_argument(
        "--memory-seconds",
        type=float,
        default=300.0,
        help="length of the memory run (default 300)",
    )
    parser.add_argument(
        "--no-readme",
        action="store_true",
        help="do not rewrite the tables of README.md and docs/benchmarks.md",
    )
    parser.add_argument(
        "--render",
        action="store_true",
        help="measure nothing: rewrite the tables from results.json and machine.json",
    )
    args = parser.parse_args(argv)
    if os.getcwd() != str(ROOT):
        os.chdir(ROOT)
    if args.render:
        rows = json.loads(RESULTS.read_text("utf-8"))
        machine = json.loads(MACHINE.read_text("utf-8"))
        update_pages(rows, machine)
        log(table(rows, machine))
        return 0
    names = list(args.only) if args.only else [*DEFAULT, *(["memory"] if args.long else [])]
    names = [n for n in GROUPS if n in names]
    machine = machine_info()
    machine["quick"] = args.quick
    machine["benchmarks"] = names
    t0 = time.perf_counter()
    meter = CpuMeter()
    new = [r.as_dict() for r in run_groups(names, args.quick, args.memory_seconds)]
    machine["load_average_end"] = list(os.getloadavg())
    other = meter.other_cores()
    machine["other_programs_cores"] = None if other is None else round(other, 2)
    machine["elapsed_s"] = round(time.perf_counter() - t0, 1)
    rows = merge(new, names) if args.only else new
    machine["groups"] = group_runs(machine, names, args.only is not None)
    RESULTS.write_text(json.dumps(rows, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    MACHINE.write_text(json.dumps(machine, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    if not args.no_readme:
        update_pages(rows, machine)
    log(table(rows, machine))
    log(f"wrote {RESULTS.name}, {MACHINE.name} in {machine['elapsed_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

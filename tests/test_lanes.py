"""The lanes that let test files run on two workers (tests/lanes.py): an alone lane is
held by one file at a time, not waited for forever, and handed over in turn; the alone
files go first, then the long ones; a file that is not alone gives way (a lower CPU
priority, inherited by what it starts)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from lanes import (
    ALONE,
    LONG,
    SHARED_NICE,
    alone_files,
    lane,
    pytest_collection_modifyitems,
)

TESTS = Path(__file__).parent


def test_an_alone_lane_excludes_another_and_is_not_waited_for_forever(tmp_path: Path) -> None:
    with lane(tmp_path) as had:
        assert had
        with lane(tmp_path, wait_s=0.5) as other:
            assert not other  # held: not had within its wait, said by the fixture
    with lane(tmp_path, wait_s=0.5) as again:
        assert again


def test_a_worker_that_gives_back_an_alone_lane_lets_a_waiting_one_go_first(
    tmp_path: Path,
) -> None:
    order: list[str] = []

    def other() -> None:
        with lane(tmp_path, wait_s=10):
            order.append("other")

    with lane(tmp_path):
        waiting = threading.Thread(target=other)
        waiting.start()
        time.sleep(0.3)
    with lane(tmp_path, wait_s=10):  # the same worker's next alone file
        order.append("next")
    waiting.join(10)
    assert order == ["other", "next"]


def test_giving_way_lowers_the_priority_once_and_what_it_starts_inherits_it() -> None:
    code = (
        "import os, subprocess, sys; from lanes import give_way; give_way(); give_way(); "
        "print(os.getpriority(os.PRIO_PROCESS, 0)); sys.stdout.flush(); "
        "subprocess.run([sys.executable, '-c', "
        "'import os; print(os.getpriority(os.PRIO_PROCESS, 0))'])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=TESTS, check=True
    ).stdout.split()
    start = os.getpriority(os.PRIO_PROCESS, 0)
    assert out == [str(max(start, SHARED_NICE))] * 2


class _Item:
    def __init__(self, name: str) -> None:
        self.name = name

    def get_closest_marker(self, name: str) -> object | None:
        return object() if {"a": ALONE, "l": LONG}.get(self.name[0]) == name else None


def test_alone_files_first_then_long_ones_each_kept_in_its_order() -> None:
    items = [_Item(n) for n in ("s1", "l1", "a1", "s2", "a2", "l2", "a3", "s3")]
    pytest_collection_modifyitems(items)  # type: ignore[arg-type]
    assert [i.name for i in items] == ["a1", "a2", "a3", "l1", "l2", "s1", "s2", "s3"]


def test_the_scheduler_finds_the_alone_files_by_their_marker_line() -> None:
    found = alone_files(TESTS)
    assert {"tests/test_soak.py", "tests/test_drive_live.py", "tests/test_up_cameras.py"} <= found
    assert "tests/test_config.py" not in found and "tests/test_lanes.py" not in found

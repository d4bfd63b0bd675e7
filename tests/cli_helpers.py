"""The `ovis` command as a user runs it, and what a failed command must look like (one
line on stderr, no traceback), for every test that runs the command line."""

from __future__ import annotations

import subprocess
import sys


def ovis(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        [sys.executable, "-m", "ovis.services.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"ovis {' '.join(args)} failed:\n{proc.stdout}\n{proc.stderr}")
    return proc


def assert_one_line_error(
    proc: subprocess.CompletedProcess[str], *needles: str, code: int | None = None
) -> str:
    """The one line ``error: ...`` a failed command wrote on stderr (with each of
    ``needles``, and exit ``code`` when given)."""
    assert proc.returncode != 0 and code in (None, proc.returncode), (
        proc.returncode,
        proc.stdout,
        proc.stderr,
    )
    assert "Traceback" not in proc.stderr + proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]

"""The leak guard (tests/leak_guard.py) itself, run by a pytest of its own on test files
whose tests each leave one thing behind: it fails each of them naming what it left,
leaves the tests that clean up alone, kills what was left running and restores the test
process for the tests after."""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import pytest
from leak_guard import _signal_mask, _signal_names

TESTS = Path(__file__).resolve().parent

CONFTEST = """
pytest_plugins = ["leak_guard"]


def pytest_configure(config):
    import leak_guard

    leak_guard.GRACE_S = 0.5  # what is left is left: no need to wait long here
"""

LEAKY = """
import os, signal, socket, subprocess, sys, threading, time
from pathlib import Path

import pytest
import zenoh

SLEEPER = [sys.executable, "-c", "import time; time.sleep(60)"]
KEPT = []


def note(name, pid):
    with open("pids.txt", "a") as fh:
        fh.write(f"{name} {pid}\\n")


def quiet():
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def test_child_left_running():
    note("child", subprocess.Popen(SLEEPER).pid)


def test_orphan_left_running():
    # its parent, the shell, exits at once: the sleeper is adopted by init
    cmd = " ".join(SLEEPER[:2]) + ' "import time; time.sleep(60)" >/dev/null 2>&1 & echo $!'
    done = subprocess.run(["sh", "-c", cmd], capture_output=True, text=True, check=True)
    note("orphan", int(done.stdout))


def test_session_left_open():
    KEPT.append(zenoh.open(quiet()))


def test_thread_left_running():
    threading.Thread(target=time.sleep, args=(60,), name="left-behind", daemon=True).start()


def test_port_left_listening():
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen()
    KEPT.append(sock)
    note("port", sock.getsockname()[1])


def test_environment_changed():
    os.environ["LEFT_BEHIND"] = "1"


def test_cores_changed():
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def test_ctrl_c_ignored():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def test_cleans_up():
    subprocess.run(SLEEPER[:2] + ["pass"], check=True)
    with zenoh.open(quiet()):
        pass
    worker = threading.Thread(target=time.sleep, args=(0.1,))
    worker.start()
    worker.join()


def test_the_process_is_as_before():
    # as the outer test's own process is (its cores and ignored signals are inherited:
    # a cpuset container, or nohup ignoring SIGHUP, changes both alike)
    assert "LEFT_BEHIND" not in os.environ
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert sorted(os.sched_getaffinity(0)) == [int(c) for c in os.environ["OUTER_CORES"].split()]
    status = Path("/proc/self/status").read_text()
    assert f"SigIgn:\\t{os.environ['OUTER_SIGIGN']}\\n" in status
"""

MODULE_FIXTURES = """
import subprocess, sys

import pytest

SLEEPER = [sys.executable, "-c", "import time; time.sleep(60)"]


@pytest.fixture(scope="module")
def stopped():
    proc = subprocess.Popen(SLEEPER)
    yield proc
    proc.kill()
    proc.wait()


@pytest.fixture(scope="module")
def never_stopped():
    proc = subprocess.Popen(SLEEPER)
    with open("pids.txt", "a") as fh:
        fh.write(f"module {proc.pid}\\n")
    return proc


@pytest.fixture(scope="module")
def fleet():
    procs = []
    yield procs
    for proc in procs:
        proc.kill()
        proc.wait()


def test_one(stopped, never_stopped):
    assert stopped.poll() is None


@pytest.mark.processes_kept_by_the_module
def test_two(stopped, never_stopped, fleet):
    fleet.append(subprocess.Popen(SLEEPER))  # stopped with the fleet
    assert stopped.poll() is None
"""


def test_each_leak_fails_its_test_and_is_undone(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PYTHONPATH", str(TESTS))
    # the outer process's own cores and ignored signals: the inner one inherits them
    monkeypatch.setenv("OUTER_CORES", " ".join(map(str, sorted(os.sched_getaffinity(0)))))
    status = Path("/proc/self/status").read_text()
    monkeypatch.setenv("OUTER_SIGIGN", re.search(r"^SigIgn:\t(\w+)$", status, re.M)[1])
    ignored = _signal_mask("SigIgn")
    pytester.makeconftest(CONFTEST)
    pytester.makepyfile(test_leaky=LEAKY, test_module_fixtures=MODULE_FIXTURES)
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-p", "no:randomly")
    pids = dict(line.split() for line in (pytester.path / "pids.txt").read_text().splitlines())
    out = result.stdout.str()
    # every test passed its own assertions; each leaky one then fails at its teardown
    cores = len(os.sched_getaffinity(0)) > 1
    result.assert_outcomes(passed=12, errors=8 + cores)
    result.stdout.fnmatch_lines(
        [
            "*ERROR at teardown of test_child_left_running*",
            f"*process left running: pid {pids['child']} (parent *): *time.sleep(60)*",
            "*ERROR at teardown of test_orphan_left_running*",
            f"*process left running: pid {pids['orphan']} (*): *time.sleep(60)*",
            "*ERROR at teardown of test_session_left_open*",
            "*Zenoh session left open in the test process: zid *",
            "*ERROR at teardown of test_thread_left_running*",
            "*thread left running: <Thread(left-behind, started daemon *",
            "*ERROR at teardown of test_port_left_listening*",
            f"*port left listening by the test process: {pids['port']}",
            "*ERROR at teardown of test_environment_changed*",
            "*environment variable LEFT_BEHIND None -> '1'",
            "*ERROR at teardown of test_ctrl_c_ignored*",
            "*signal handlers {'SIGINT': 'default_int_handler'} -> {'SIGINT': 'SIG_IGN'}*",
            "*ERROR at teardown of test_two*",
            "*module test_module_fixtures (its module-scoped fixtures) left behind:",
            f"*process left running: pid {pids['module']} (parent *): *time.sleep(60)*",
        ]
    )
    before, after = _signal_names(ignored), _signal_names(ignored | {signal.SIGINT})
    assert f"ignored signals {before} -> {after}" in out
    if cores:
        assert "cores (sched affinity) of its threads" in out
    for name in ("test_cleans_up", "test_the_process_is_as_before", "test_one "):
        assert f"teardown of {name}" not in out
    # the fleet's process, started by test_two, is not said to be left (only the module's)
    # (counted in the errors' own section: the short summary may repeat their lines)
    assert out.split("short test summary info")[0].count("process left running") == 3
    # what was left running is gone: killed by the guard
    for name in ("child", "orphan", "module"):
        stat = Path(f"/proc/{pids[name]}/stat")
        assert not stat.exists() or stat.read_text().rpartition(")")[2].split()[0] == "Z", name

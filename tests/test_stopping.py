"""A stop set from a signal handler while the main thread waits on it: Ctrl-C always
stops (``threading.Event`` can deadlock there, see ovis.services.stopping)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

from ovis.services.stopping import Stop

#: Main thread spinning in ``wait(0)`` (the most time inside the wait) while a thread
#: sends it a signal whose handler sets the stop; a new stop each round.
SPIN = """
import signal, threading, time
from ovis.services.stopping import Stop
for _ in range({rounds}):
    stop = Stop()
    signal.signal(signal.SIGUSR1, lambda *_: stop.set())
    main = threading.main_thread().ident
    def kick():
        time.sleep(0.0002)
        signal.pthread_kill(main, signal.SIGUSR1)
    t = threading.Thread(target=kick)
    t.start()
    while not stop.wait(0):
        pass
    t.join()
print("stopped every time")
"""


def test_a_signal_handler_setting_the_stop_never_deadlocks_the_waiting_main_thread() -> None:
    run = subprocess.run([sys.executable, "-c", SPIN.format(rounds=1500)],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert run.returncode == 0 and run.stdout.strip() == "stopped every time", run.stderr


def test_wait_returns_when_set_from_another_thread_and_times_out_otherwise() -> None:
    stop = Stop()
    t0 = time.monotonic()
    assert stop.wait(0.05) is False and time.monotonic() - t0 >= 0.05
    threading.Timer(0.05, stop.set).start()
    waiters = [threading.Thread(target=stop.wait) for _ in range(3)]
    for w in waiters:
        w.start()
    for w in waiters:
        w.join(5)
    assert not any(w.is_alive() for w in waiters) and stop.is_set()
    assert stop.wait(0) is True and stop.wait() is True
    for _ in range(100_000):  # setting again never blocks on a full pipe
        stop.set()

"""Where the CPU of ``ovis up --cameras 2x2`` goes, per world frame (issue 31), in its
default layout: one process per stage serving the four cameras (issue 38).

Two runs of the same four chains plus fusion at 30 frames/s per camera: ``ovis up
--cameras 2x2`` itself and the empty topology of :mod:`benchmarks.topology` (the same
processes, placement and message sizes, every stage a relay: the floor). In each, every
process's threads are read from ``/proc`` at the start and the end of a window while all
cameras run: the CPU time of the main thread (decode, compute, encode, publish), of the
other Python threads (the fusion loop, calibration followers) and of Zenoh's threads
(network receive and send, shared-memory handling, and the subscriber callbacks that
copy each payload out and drop it in the inbox), and the voluntary context switches
(wake-ups). The rows are per world frame, by stage (all cameras' processes of a stage
together), each against the same stage of the empty topology.

The main thread of one camera's stages and of the fusion is also sampled with py-spy
(when it is installed: ``pip install py-spy``), and its time split by the Python function
it was in: msgspec decode, msgspec encode, the Zenoh put, the copy out of Zenoh, and the
rest of the stage (compute).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.core import Row, ratio

__all__ = ["budget_rows", "process_cpu"]

PREFIX = "CPU budget"
FPS = 30.0
#: Stages in the order of a frame's path; the rows come in this order.
ROLES = ("capture", "preprocess", "label", "pose", "fusion", "router", "ovis up")
KINDS = ("main", "python", "zenoh")
#: py-spy's samples per second.
RATE = 250
#: A sample's innermost ovis frame → the step it counts for (first match wins).
STEPS = (
    ("msgspec decode", "decode (", "messages.py"),
    ("msgspec encode", "encode (", "messages.py"),
    ("Zenoh put", "<lambda> (", "service.py"),
    ("copy out of Zenoh (subscriber callback)", "take (", "service.py"),
    ("copy into shared memory", "payload (", "shm.py"),
    ("waiting for the inbox", "get (", "inbox.py"),
)


@dataclass
class Usage:
    """CPU seconds by thread kind, and wake-ups, of one stage's processes."""

    cpu: dict[str, float] = field(default_factory=lambda: dict.fromkeys(KINDS, 0.0))
    switches: int = 0
    processes: int = 0


def _role(cmdline: list[str]) -> str | None:
    """The stage a process runs, from its command line (ovis or the empty topology)."""
    if "benchmarks.topology" in cmdline:
        return cmdline[cmdline.index("benchmarks.topology") + 2]
    if "ovis.services.cli" in cmdline:
        args = cmdline[cmdline.index("ovis.services.cli") + 1 :]
        if args[:1] == ["run"]:
            rest = [a for a in args[1:] if not a.startswith("--")]
            return rest[0] if rest and "--standby" not in args else None
        return {"router": "router", "up": "ovis up"}.get(args[0] if args else "")
    return None


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text()
    except OSError:
        return None  # ended meanwhile


def process_cpu(root: int) -> dict[int, tuple[str, dict[str, float], int]]:
    """Every process under ``root`` (itself included) with a stage: pid → (stage, CPU
    seconds by thread kind, voluntary context switches)."""
    from ovis.services.cpu import tree_cpu

    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for pid in tree_cpu(root):
        cmdline = (_read(f"/proc/{pid}/cmdline") or "").split("\0")
        role = _role(cmdline)
        if role is None:
            continue
        cpu, switches = dict.fromkeys(KINDS, 0.0), 0
        main_comm = (_read(f"/proc/{pid}/comm") or "").strip()
        for tid in os.listdir(f"/proc/{pid}/task") if os.path.isdir(f"/proc/{pid}/task") else []:
            stat = _read(f"/proc/{pid}/task/{tid}/stat")
            status = _read(f"/proc/{pid}/task/{tid}/status") or ""
            if stat is None:
                continue
            fields = stat.rsplit(")", 1)[1].split()
            comm = stat[stat.index("(") + 1 : stat.rindex(")")]
            kind = "main" if int(tid) == pid else "python" if comm == main_comm else "zenoh"
            cpu[kind] += (int(fields[11]) + int(fields[12])) / tick
            for line in status.splitlines():
                if line.startswith("voluntary_ctxt_switches:"):
                    switches += int(line.split()[1])
        out[pid] = (role, cpu, switches)
    return out


def _usage(before: dict, after: dict) -> dict[str, Usage]:
    """Per stage: what its processes (alive at both reads) used between the two reads."""
    by_role: dict[str, Usage] = defaultdict(Usage)
    for pid, (role, cpu, switches) in after.items():
        if pid not in before:
            continue
        _, cpu0, switches0 = before[pid]
        u = by_role[role]
        u.processes += 1
        u.switches += switches - switches0
        for kind in KINDS:
            u.cpu[kind] += cpu[kind] - cpu0[kind]
    return by_role


class Window:
    """Reads every process at two moments; the second read also collects py-spy's."""

    def __init__(self, sample_for: float = 0.0, workdir: Path | None = None) -> None:
        self.reads: list[tuple[float, dict]] = []
        self.sample_for = sample_for
        self.workdir = workdir
        self.spies: list[tuple[str, Path, subprocess.Popen[bytes]]] = []

    def __call__(self, root: int) -> None:
        self.reads.append((time.monotonic(), process_cpu(root)))
        if len(self.reads) == 1 and self.sample_for > 0 and self.workdir is not None:
            self._spy(self.reads[0][1])

    def _spy(self, procs: dict) -> None:
        """py-spy on camera 0's stages (the first process of each) and the fusion."""
        spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
        if not Path(spy).exists():
            return
        taken: set[str] = set()
        for pid, (role, _, _) in sorted(procs.items()):
            if role in taken or role in ("router", "ovis up"):
                continue
            taken.add(role)
            out = self.workdir / f"{role}.txt"
            seconds = str(int(self.sample_for))
            args = [spy, "record", "--nonblocking", "-r", str(RATE), "-d", seconds,
                    "--format", "raw", "-o", str(out), "-p", str(pid)]  # fmt: skip
            proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            self.spies.append((role, out, proc))

    def usage(self) -> tuple[dict[str, Usage], float]:
        """Per stage usage between the two reads, and the seconds between them."""
        (t0, a), (t1, b) = self.reads
        return _usage(a, b), t1 - t0

    def steps(self) -> dict[str, Counter[str]]:
        """Per stage: py-spy's samples of its main thread by step."""
        found: dict[str, Counter[str]] = {}
        for role, out, proc in self.spies:
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if out.is_file():
                found[role] = _steps(out.read_text())
        return found


def _steps(raw: str) -> Counter[str]:
    """Samples by step of py-spy's raw output (``frame;frame;… count``, every thread
    while it runs Python), by the innermost frame that names a step."""
    counts: Counter[str] = Counter()
    for line in raw.splitlines():
        stack, _, n = line.rpartition(" ")
        if not n.isdigit():
            continue
        step = "compute and the rest"
        for frame in reversed(stack.split(";")):
            hit = [s for s, fn, where in STEPS if frame.startswith(fn) and where in frame]
            if hit:
                step = hit[0]
                break
        counts[step] += int(n)
    return counts


def _run_ovis(seconds: float, window: Window) -> None:
    from benchmarks.fusion import up_cameras

    up_cameras(2.0)  # prerenders (and caches) every camera's period: not timed
    up_cameras(seconds, probe=window)


def budget_rows(quick: bool, log=print) -> list[Row]:
    from benchmarks.topology import empty_chains

    seconds = 12.0 if quick else 30.0
    sampled = seconds - 10.0
    with tempfile.TemporaryDirectory(prefix="ovis-bench-budget-") as tmp:
        ours = Window(sample_for=sampled, workdir=Path(tmp))
        _run_ovis(seconds, ours)
        used, span = ours.usage()
        steps = ours.steps()
    empty = Window()
    empty_chains(int(seconds * FPS), probe=empty, layout="per-stage")
    floor_used, floor_span = empty.usage()
    frames, floor_frames = span * FPS, floor_span * FPS
    rows: list[Row] = []
    total = sum(sum(u.cpu.values()) for u in used.values()) * 1e3 / frames
    floor_total = sum(sum(u.cpu.values()) for u in floor_used.values()) * 1e3 / floor_frames
    for role in ROLES:
        u, f = used.get(role), floor_used.get(role)
        if u is None:
            continue
        log(f"  {role}: {u.processes} processes, CPU s {u.cpu}, wake-ups {u.switches}")
        what = f"{PREFIX} {role} ({u.processes} process{'es' * (u.processes > 1)})"
        for kind, label in (
            ("main", "main thread (decode, compute, encode, publish)"),
            ("python", "other Python threads"),
            ("zenoh", "Zenoh's threads (receive, send, subscriber callbacks: copy out)"),
        ):
            value = u.cpu[kind] * 1e3 / frames
            floor = None if f is None else f.cpu[kind] * 1e3 / floor_frames
            rows.append(Row(f"{what}: {label} per world frame (floor: the empty stage)",
                            "ms", value, floor, ratio(value, floor)))  # fmt: skip
        wakes = u.switches / frames
        floor_wakes = None if f is None else f.switches / floor_frames
        rows.append(Row(f"{what}: wake-ups (voluntary context switches) per world frame "
                        "(floor: the empty stage)", "", wakes, floor_wakes,
                        ratio(wakes, floor_wakes)))  # fmt: skip
        for step, n in sorted(steps.get(role, Counter()).items(), key=lambda kv: -kv[1]):
            value = n * 1e3 / RATE / (sampled * FPS)
            floor = None if f is None else sum(f.cpu.values()) * 1e3 / floor_frames / f.processes
            rows.append(Row(f"{what}: one camera's Python code, {step} per frame (py-spy, "
                            f"{n} samples; floor: one empty stage's process, every thread)",
                            "ms", value, floor, ratio(value, floor)))  # fmt: skip
    rows += _stage_work_rows(used, frames, quick, log)
    rows.append(Row(f"{PREFIX}: all processes per world frame (floor: the empty topology's)",
                    "ms", total, floor_total, ratio(total, floor_total)))  # fmt: skip
    log(f"  total {total:.2f} ms per world frame, empty topology {floor_total:.2f} ms")
    return rows


#: The stages whose handlers are timed: in the per-stage layout every camera's handler
#: runs on the process's shared loop, a thread of its own (not the main one).
WORKS_ON = ("preprocess", "label", "pose")
#: Cameras of the run (2×2): each stage process handles a frame of each per world frame.
CAMERAS = 4
#: Memory written between the stages in the eviction run (more than the caches hold).
EVICT_MB = 32.0


def _stage_work_rows(used: dict[str, Usage], frames: float, quick: bool, log) -> list[Row]:
    """Each stage's thread per camera frame in the run (decode, compute, encode, publish)
    against the same compute in one process on camera cam00's frames, warm; and that
    compute with :data:`EVICT_MB` written between the stages, against warm."""
    from benchmarks.fusion import SEED
    from benchmarks.stage_work import stage_work_ms

    reps = 150 if quick else 600
    warm = stage_work_ms(SEED % 1000, reps)
    evicted = stage_work_ms(SEED % 1000, reps, EVICT_MB)
    log(f"  stages in one process, warm {warm}, {EVICT_MB:g} MB evicted between: {evicted}")
    rows = []
    for stage in WORKS_ON:
        u = used.get(stage)
        if u is None:
            continue
        value = u.cpu["python"] * 1e3 / frames / CAMERAS
        rows.append(Row(f"{PREFIX} {stage}: its Python threads per camera frame in the run "
                        "(the shared loop's decode, compute, encode, publish, and its few "
                        "other threads; floor: the compute alone in one process, warm, on "
                        "cam00's frames)", "ms", value, warm[stage],
                        ratio(value, warm[stage])))  # fmt: skip
        rows.append(Row(f"{PREFIX} {stage}: the compute alone in one process with "
                        f"{EVICT_MB:g} MB written between the stages, as other processes "
                        "do between a stage's frames (floor: warm)", "ms", evicted[stage],
                        warm[stage], ratio(evicted[stage], warm[stage])))  # fmt: skip
    return rows


if __name__ == "__main__":
    for r in budget_rows("--quick" in sys.argv):
        print(f"{r.name}: {r.value} (floor {r.floor})")

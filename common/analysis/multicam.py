"""The simulated multi-camera arena scored end to end, without the network: a grid of
cameras (:mod:`ovis.common.sim.multiview`) measures the ground truth each frame, their
detections are fused (:mod:`ovis.common.fusion`) and the world is scored against the
truth (``ovis cameras simulate``, tests)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import msgspec
import numpy as np

from ovis.common.config import CameraModel, FusionConfig
from ovis.common.fusion.accuracy import AccuracyMap, detection_columns
from ovis.common.fusion.scoring import WorldScore, WorldScorer
from ovis.common.fusion.world import WorldFuser
from ovis.common.messages import ObstacleFrame, TruthFrame, WorldFrame
from ovis.common.sim.arena import SimObject
from ovis.common.sim.multiview import (
    GridScene,
    camera_grid,
    grid_arena,
    measure,
    whole_in_view,
)
from ovis.common.world.detection import DetectedObject
from ovis.common.world.robots import RobotState

__all__ = [
    "CameraCounts",
    "CameraRun",
    "GridRun",
    "WorldWatch",
    "as_detections",
    "detections_frame",
    "percentiles",
    "simulate_grid",
]

MS = 1_000_000
FRAME_NS = 33_333_333  # 30 frames/s


class CameraCounts(msgspec.Struct, kw_only=True):
    """One camera's frames: measured (captured), fused into a world frame (processed),
    and those that came too late or were not sent (dropped)."""

    captured: int
    processed: int
    dropped: int


class GridRun(msgspec.Struct, kw_only=True):
    """What ``ovis cameras simulate`` reports."""

    grid: str
    seed: int
    frames: int
    cameras: dict[str, CameraCounts]
    world: WorldScore
    fuse_ms_p50: float  # in-process merging of one world frame (no network, no chains)
    fuse_ms_p99: float


def simulate_grid(
    nx: int,
    ny: int,
    *,
    frames: int,
    seed: int,
    robots: int = 4,
    obstacles: int = 10,
    cell_cm: tuple[float, float] = (100.0, 75.0),
    cfg: FusionConfig | None = None,
    dead: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> GridRun:
    """Fuse ``frames`` frames of an ``nx × ny`` simulated grid and score the world;
    ``dead`` names a camera that stops half-way."""
    cfg = cfg or FusionConfig()
    specs = camera_grid(nx, ny, cell_cm=cell_cm, seed=seed)
    if dead is not None and dead not in {s.name for s in specs}:
        raise ValueError(f"no camera {dead!r} in a {nx}x{ny} grid")
    scene = GridScene(*grid_arena(nx, ny, cell_cm), robots=robots, obstacles=obstacles, seed=seed)
    maps = {s.name: AccuracyMap(s.camera, cfg.pixel_sigma_px) for s in specs}
    for m in maps.values():  # built before the clock runs, as the service does at start
        m.prepare(scene.robot_z, scene.obstacle_z)
    radius = max(o.radius_cm for o in scene.objects(0) if o.kind == "robot") if robots else 0.0
    fuser = WorldFuser([s.name for s in specs], cfg, stale_ns=200 * MS, views=maps,
                       robot_radius_cm=radius)  # fmt: skip
    rng = np.random.default_rng(seed)
    scorer = WorldScorer()
    counts = {s.name: CameraCounts(captured=0, processed=0, dropped=0) for s in specs}
    truths: dict[int, tuple] = {}
    cost_ms: list[float] = []
    for f in range(frames):
        truth = scene.objects(f)
        stamp = f * FRAME_NS
        truths[stamp] = (truth, set())
        ready = []
        frame_ms = 0.0
        for k, spec in enumerate(specs):
            if spec.name == dead and f >= frames // 2:
                continue
            measured = measure(spec.camera, truth, cfg.pixel_sigma_px, rng)
            counts[spec.name].captured += 1
            truths[stamp][1].update(o.id for o in measured)
            dets = as_detections(measured)
            t0 = time.perf_counter()
            found = detection_columns(spec.name, dets)
            ready += fuser.add(spec.name, stamp, found, now_ns=stamp + (k + 1) * MS)
            frame_ms += (time.perf_counter() - t0) * 1e3
        cost_ms.append(frame_ms)
        ready += fuser.due(stamp + 30 * MS)
        for world in ready:
            for name in world.cameras:
                counts[name].processed += 1
            truth_objects, seen = truths.pop(world.stamp_ns)
            scorer.add(
                [(o.id, o.obj.x_cm, o.obj.y_cm, tuple(o.obj.cameras)) for o in world.objects],
                [(o.id, o.x_cm, o.y_cm) for o in truth_objects],
                seen,
            )
        if progress is not None:
            progress(f + 1)
    for c in counts.values():
        c.dropped = c.captured - c.processed
    per_frame = np.array(cost_ms)
    return GridRun(
        grid=f"{nx}x{ny}",
        seed=seed,
        frames=frames,
        cameras=counts,
        world=scorer.score(),
        fuse_ms_p50=float(np.percentile(per_frame, 50)) if per_frame.size else 0.0,
        fuse_ms_p99=float(np.percentile(per_frame, 99)) if per_frame.size else 0.0,
    )


def as_detections(measured: list[SimObject]) -> list[dict]:
    """Measured objects as the detections fusion takes (mappings; only robots carry
    their marker)."""
    dets = [msgspec.structs.asdict(o) for o in measured]
    for d in dets:
        d["marker_id"] = d["marker_id"] if d["kind"] == "robot" else None
    return dets


def detections_frame(seq: int, stamp_ns: int, seen: list[SimObject]) -> ObstacleFrame:
    """What a camera's pose service publishes for ``seen`` (measured objects)."""
    robots = [
        RobotState(id=o.id, name=f"robot{o.id}", marker_id=o.marker_id or 0, x_cm=o.x_cm,
                   y_cm=o.y_cm, z_cm=o.z_cm, heading_deg=o.heading_deg, vx_cm_s=o.vx_cm_s,
                   vy_cm_s=o.vy_cm_s, yaw_rate_deg_s=0.0, age_s=0.0, radius_cm=o.radius_cm)
        for o in seen if o.kind == "robot"
    ]  # fmt: skip
    obstacles = [
        DetectedObject(o.id, "obstacle", 0.0, 0.0, 0.0, 0.0, 1.0, o.x_cm, o.y_cm, o.z_cm,
                       o.radius_cm, np.pi * o.radius_cm**2)
        for o in seen if o.kind == "obstacle"
    ]  # fmt: skip
    return ObstacleFrame(seq=seq, stamp_ns=stamp_ns, published_ns=time.time_ns(),
                         frame_age_ms=0.0, calibration_version=0, robot=None,
                         obstacles=obstacles, planner=[], robots=robots)  # fmt: skip


class CameraRun(msgspec.Struct, kw_only=True):
    """One camera's frames in a live run (``ovis up --cameras``): captured (its capture
    published), processed (its pose published), fused (in a world frame), late (came
    after its world frame left) and dropped (captured, never in the world)."""

    captured: int
    processed: int
    fused: int
    late: int
    dropped: int
    restarts: int = 0


class WorldWatch:
    """Scores a live fused world against the simulated truth (``ovis up --cameras``): the
    cameras' truth messages (each frame's stamp and the whole floor's objects) and the
    world frames with their receipt times are kept as they arrive (any thread), and
    :meth:`score` matches them by stamp, in order, with :class:`WorldScorer`. An object
    counts as seen when its whole footprint is in some camera's view."""

    def __init__(self, cameras: dict[str, CameraModel]) -> None:
        self.cameras = cameras
        self._truth: dict[int, list[SimObject]] = {}
        self._world: list[tuple[WorldFrame, int]] = []
        self._lock = threading.Lock()

    def add_truth(self, msg: TruthFrame) -> None:
        if msg.stamp_ns is not None:
            with self._lock:
                self._truth.setdefault(msg.stamp_ns, msg.objects)

    def has_truth(self, stamp_ns: int) -> bool:
        """Whether a camera's truth of this stamp came already (the others' are alike)."""
        return stamp_ns in self._truth

    def add_world(self, msg: WorldFrame, receipt_ns: int) -> None:
        with self._lock:
            self._world.append((msg, receipt_ns))

    def fused(self, since_ns: int = 0) -> dict[str, int]:
        """World frames stamped from ``since_ns`` on that each camera has a frame in."""
        with self._lock:
            out = dict.fromkeys(self.cameras, 0)
            for w, _ in self._world:
                if w.stamp_ns >= since_ns:
                    for name in w.cameras:
                        out[name] = out.get(name, 0) + 1
            return out

    def frames(self) -> int:
        with self._lock:
            return len(self._world)

    def published_ms(self, since_ns: int = 0) -> dict[str, float]:
        """Percentiles (``p50``, ``p99`` ms) of capture stamp → world frame published."""
        with self._lock:
            a = np.array([(w.published_ns - w.stamp_ns) / 1e6 for w, _ in self._world
                          if w.stamp_ns >= since_ns])  # fmt: skip
        return percentiles(a)

    def late(self, since_ns: int = 0) -> dict[str, int]:
        """Each camera's frames that came after their world frame left (fusion's newest
        count), less those counted by the last world frame stamped before ``since_ns``."""
        with self._lock:
            if not self._world:
                return {}
            newest = dict(self._world[-1][0].late_frames)
            before = [w for w, _ in self._world if w.stamp_ns < since_ns]
            old = before[-1].late_frames if before else {}
            return {name: max(0, n - old.get(name, 0)) for name, n in newest.items()}

    def score(self, since_ns: int = 0) -> tuple[WorldScore, dict[str, float], int]:
        """The score of the world frames stamped from ``since_ns`` on, their latency
        percentiles (``p50``, ``p99`` ms: capture stamp to receipt here) and how many
        had their truth (were scored)."""
        with self._lock:
            world = sorted(
                (item for item in self._world if item[0].stamp_ns >= since_ns),
                key=lambda item: item[0].seq,
            )
            truth = dict(self._truth)
        scorer = WorldScorer()
        latency = np.array([(r - w.stamp_ns) / 1e6 for w, r in world])
        scored = 0
        for w, _ in world:
            objects = truth.get(w.stamp_ns)
            if objects is None:
                continue
            seen = np.zeros(len(objects), bool)
            for cam in self.cameras.values():
                seen |= whole_in_view(cam, objects)
            scorer.add(
                [(o.id, o.x_cm, o.y_cm, tuple(o.cameras)) for o in w.objects],
                [(o.id, o.x_cm, o.y_cm) for o in objects],
                {o.id for o, s in zip(objects, seen, strict=True) if s},
                ([o.z_cm for o in w.objects], [o.z_cm for o in objects]),
                [o.z_source for o in w.objects],
            )
            scored += 1
        return scorer.score(), percentiles(latency), scored


def percentiles(a: np.ndarray) -> dict[str, float]:
    """``p50`` and ``p99`` of ``a`` (0 when empty)."""
    if not a.size:
        return {"p50": 0.0, "p99": 0.0}
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99))}

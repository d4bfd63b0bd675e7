"""One world from several cameras: frames matched by capture time
(:mod:`~ovis.common.fusion.matching`), the world frame's detections of every camera
resolved to sightings in one pass (:mod:`~ovis.common.fusion.tables`), blobs that a late
camera should judge held back (:mod:`~ovis.common.fusion.coverage`), merged
(:mod:`~ovis.common.fusion.merge`) and given world identities
(:mod:`~ovis.common.fusion.tracks`). What the fusion service runs, without the
network."""

from __future__ import annotations

from collections.abc import Mapping

import msgspec

from ovis.common.config import FusionConfig
from ovis.common.fusion.accuracy import CUT_MARGIN_PX, AccuracyMap
from ovis.common.fusion.coverage import reportable, without_suspects
from ovis.common.fusion.matching import FrameMatcher
from ovis.common.fusion.merge import fuse
from ovis.common.fusion.sightings import Sighting, Sightings
from ovis.common.fusion.tables import TableSet
from ovis.common.fusion.tracks import Covered, Tracked, WorldTracker

__all__ = ["WorldFrameResult", "WorldFuser"]


class WorldFrameResult(msgspec.Struct, kw_only=True):
    """One fused world frame: its capture stamp, its objects with world ids, the
    cameras that gave a frame to it and the live cameras that did not."""

    stamp_ns: int
    objects: list[Tracked]
    cameras: list[str]
    missing: list[str]


class WorldFuser:
    """Cameras' sightings in, world frames out (see the module docstring)."""

    def __init__(
        self,
        cameras: list[str],
        cfg: FusionConfig,
        *,
        stale_ns: int,
        views: Mapping[str, AccuracyMap] | None = None,
        robot_radius_cm: float = 0.0,
    ) -> None:
        self.cfg = cfg
        #: each camera's view (its accuracy map; the service's dict, so a recalibrated
        #: camera's new map is used) and the largest robot's radius, for
        #: :mod:`~ovis.common.fusion.coverage` (none: every camera's blobs are taken and
        #: every unseen obstacle ages)
        self.views, self.robot_radius_cm = views, float(robot_radius_cm)
        self._tables = TableSet()
        self.matcher: FrameMatcher[Sightings] = FrameMatcher(
            cameras,
            window_ns=int(cfg.match_window_ms * 1e6),
            wait_ns=int(cfg.wait_ms * 1e6),
            stale_ns=stale_ns,
        )
        self.tracker = WorldTracker(cfg)
        #: robots of the last frames: marker → where and when last seen, its velocity
        self._robots: dict[int, _Footprint] = {}

    def add(
        self, camera: str, stamp_ns: int, sightings: Sightings | list[Sighting], now_ns: int
    ) -> list[WorldFrameResult]:
        """One camera's sightings of one frame; the world frames that are now ready."""
        if not isinstance(sightings, Sightings):
            sightings = Sightings.of(sightings) if sightings else Sightings.empty(camera)
        return self._fused(self.matcher.add(camera, stamp_ns, sightings, now_ns), now_ns)

    def due(self, now_ns: int) -> list[WorldFrameResult]:
        """World frames whose wait for a late camera is over (call on a timer)."""
        return self._fused(self.matcher.due(now_ns), now_ns)

    def _fused(self, groups: list, now_ns: int) -> list[WorldFrameResult]:
        if not groups:
            return []
        live = set(self.matcher.live(now_ns))
        out = []
        for g in groups:
            missing = sorted(live - g.items.keys())
            footprints = [f.at(g.stamp_ns) for f in self._robots.values()]
            fused = fuse(self._sightings(list(g.items.values()), missing), self.cfg, footprints)
            objects = self.tracker.update(fused, self._covered(list(g.items), missing))
            self._remember_robots(objects, g.stamp_ns)
            out.append(
                WorldFrameResult(
                    stamp_ns=g.stamp_ns, objects=objects, cameras=sorted(g.items), missing=missing
                )
            )
        return out

    def _sightings(self, parts: list[Sightings], missing: list[str]) -> Sightings:
        """A world frame's sightings: detections still to resolve resolved together, and
        without the blobs that a ``missing`` camera should judge."""
        pending = [p for p in parts if not p.resolved]
        if pending:
            if self.views is None:
                raise ValueError("detections not resolved to sightings: give views")
            done = [p for p in parts if p.resolved]
            parts = [self._tables.resolve(pending, self.views, CUT_MARGIN_PX), *done]
        seen = Sightings.joined(parts)
        if self.views is not None and missing:
            seen = without_suspects(self.views, seen, missing, self.robot_radius_cm)
        return seen

    def _covered(self, present: list[str], missing: list[str]) -> Covered | None:
        """Which unseen obstacles this frame's cameras could have reported."""
        views, radius = self.views, self.robot_radius_cm
        if views is None:
            return None
        return lambda x, y, z, r: reportable(views, present, missing, radius, x, y, z, r)

    def _remember_robots(self, objects: list[Tracked], stamp_ns: int) -> None:
        """Keep each robot's last footprint for ``lost_frames`` world frames, moving on
        at its last velocity: a part of it that a camera sees while the camera that finds
        its marker is late is not taken for an obstacle (see
        :func:`~ovis.common.fusion.merge.fuse`)."""
        for f in self._robots.values():
            f.unseen += 1
        for t in objects:
            m = t.obj.marker_id
            if m is None:
                continue
            before = self._robots.get(m)
            v = (0.0, 0.0)
            if before is not None and stamp_ns > before.stamp_ns:
                dt = stamp_ns - before.stamp_ns
                v = ((t.obj.x_cm - before.x) / dt, (t.obj.y_cm - before.y) / dt)
            self._robots[m] = _Footprint(t.obj.x_cm, t.obj.y_cm, t.obj.radius_cm, stamp_ns, v)
        self._robots = {m: f for m, f in self._robots.items() if f.unseen < self.cfg.lost_frames}


class _Footprint:
    """A robot's last sighting: position, radius, stamp, velocity (cm/ns), frames since."""

    def __init__(self, x: float, y: float, r: float, stamp_ns: int, v: tuple[float, float]) -> None:
        self.x, self.y, self.r, self.stamp_ns, self.v, self.unseen = x, y, r, stamp_ns, v, 0

    def at(self, stamp_ns: int) -> tuple[float, float, float]:
        """(x, y, radius) where it has gone by ``stamp_ns`` at its last velocity."""
        dt = stamp_ns - self.stamp_ns
        return self.x + self.v[0] * dt, self.y + self.v[1] * dt, self.r

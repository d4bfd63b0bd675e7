"""One world from several cameras: frames matched by capture time
(:mod:`~ovis.common.fusion.matching`), merged (:mod:`~ovis.common.fusion.merge`) and
given world identities (:mod:`~ovis.common.fusion.tracks`). What the fusion service
runs, without the network."""

from __future__ import annotations

import msgspec

from ovis.common.config import FusionConfig
from ovis.common.fusion.matching import FrameMatcher
from ovis.common.fusion.merge import Sighting, fuse
from ovis.common.fusion.tracks import Tracked, WorldTracker

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

    def __init__(self, cameras: list[str], cfg: FusionConfig, *, stale_ns: int) -> None:
        self.cfg = cfg
        self.matcher: FrameMatcher[list[Sighting]] = FrameMatcher(
            cameras,
            window_ns=int(cfg.match_window_ms * 1e6),
            wait_ns=int(cfg.wait_ms * 1e6),
            stale_ns=stale_ns,
        )
        self.tracker = WorldTracker(cfg)
        #: robots of the last frames: marker → (x, y, radius, world frames since seen)
        self._robots: dict[int, tuple[float, float, float, int]] = {}

    def add(
        self, camera: str, stamp_ns: int, sightings: list[Sighting], now_ns: int
    ) -> list[WorldFrameResult]:
        """One camera's sightings of one frame; the world frames that are now ready."""
        return self._fused(self.matcher.add(camera, stamp_ns, sightings, now_ns), now_ns)

    def due(self, now_ns: int) -> list[WorldFrameResult]:
        """World frames whose wait for a late camera is over (call on a timer)."""
        return self._fused(self.matcher.due(now_ns), now_ns)

    def _fused(self, groups: list, now_ns: int) -> list[WorldFrameResult]:
        live = set(self.matcher.live(now_ns))
        out = []
        for g in groups:
            sightings = [s for items in g.items.values() for s in items]
            footprints = [(x, y, r) for x, y, r, _ in self._robots.values()]
            objects = self.tracker.update(fuse(sightings, self.cfg, footprints))
            self._remember_robots(objects)
            out.append(
                WorldFrameResult(
                    stamp_ns=g.stamp_ns,
                    objects=objects,
                    cameras=sorted(g.items),
                    missing=sorted(live - g.items.keys()),
                )
            )
        return out

    def _remember_robots(self, objects: list[Tracked]) -> None:
        """Keep each robot's last footprint for ``lost_frames`` world frames: a part of it
        that a camera sees while the camera that finds its marker is late is not taken
        for an obstacle (see :func:`~ovis.common.fusion.merge.fuse`)."""
        aged = {m: (x, y, r, n + 1) for m, (x, y, r, n) in self._robots.items()}
        for t in objects:
            if t.obj.marker_id is not None:
                aged[t.obj.marker_id] = (t.obj.x_cm, t.obj.y_cm, t.obj.radius_cm, 0)
        self._robots = {m: v for m, v in aged.items() if v[3] < self.cfg.lost_frames}

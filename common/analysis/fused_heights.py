"""Heights and footprints fused from several cameras, against MuJoCo's truth (issue 36).

:func:`evaluate_grid` builds the physical world of one seed on the floor of an
``nx × ny`` camera grid (:mod:`ovis.common.physical.grid`: the world ``ovis up --world
physical --cameras 2x2`` shows), and for each camera as ``ovis up`` runs it: its frame
at t = 0, the camera calibrated on the floor marks of its empty floor, that floor as its
background, :class:`~ovis.common.world.detection.Detector` with heights measured
(``[pose] heights``, the ``physical`` preset's), every blob fitted in the one frame.
The cameras' detections go through the fusion service's code
(:class:`~ovis.common.fusion.world.WorldFuser`, each camera's accuracy map from its
calibration) into one world frame, scored against the truth.

An obstacle counts as *seen whole* by a camera when the disks that bound its foot and
its top project inside that camera's image (:data:`MARGIN_PX` from the border) and
others hide at most :data:`HIDDEN_SHARE` of it there
(:meth:`~ovis.common.physical.world.PhysicalWorld.visible_px` against
:meth:`~ovis.common.physical.world.PhysicalWorld.alone_px`). Each true obstacle is
matched to the fused object nearest its footprint (within
:data:`~ovis.common.analysis.stated.GATE_CM`); a fused object whose position is not
measurable (its σ over :data:`~ovis.common.analysis.stated.POSITION_SIGMA_CM`: the solid's
foot hidden from every camera that saw it) is matched within the uncertainty it states
instead (:mod:`~ovis.common.analysis.stated`, its σ taken in every direction).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import cv2
import msgspec

from ovis.common.analysis.evaluation import match_objects
from ovis.common.analysis.stated import GATE_CM, leftovers_within_stated
from ovis.common.camera.projection import disks_in_image
from ovis.common.config import FusionConfig, OvisConfig, PinholeParams
from ovis.common.fusion.accuracy import AccuracyMap, detection_columns
from ovis.common.fusion.merge import Fused
from ovis.common.fusion.world import WorldFuser
from ovis.common.physical.grid import PhysicalGridCamera, calibrate_grid_camera
from ovis.common.sim.arena import SimObject
from ovis.common.sim.gridview import grid_specs
from ovis.common.world.detection import DetectedObject, Detector

__all__ = [
    "GridCameraView",
    "GridObstacle",
    "GridScene",
    "GridViews",
    "evaluate_grid",
    "grid_views",
    "score_fused",
    "score_grid",
]

#: The bounding disks of a solid seen whole lie this far (px) inside the image.
MARGIN_PX = 1.0
#: More of a solid's silhouette hidden by others than this share: not seen whole.
HIDDEN_SHARE = 0.2


class GridObstacle(msgspec.Struct, kw_only=True):
    """One true obstacle of a grid scene: the cameras that see it whole, the fused
    object matched to it (NaN / "" when none): its footprint error, reported height,
    the height's error, σ and source, the cameras fused into it and those whose height
    disagreed; whether it was matched within the position uncertainty it states (not
    measurable: the footprint error is then no measure of accuracy)."""

    seed: int
    true_height_cm: float
    seen_by: list[str]
    found: bool
    footprint_error_cm: float
    height_cm: float
    height_error_cm: float
    height_sigma_cm: float
    height_source: str
    cameras: list[str]
    disagreeing: list[str]
    within_stated: bool = False


class GridScene(msgspec.Struct, kw_only=True):
    """One seed's obstacles and the fused objects no true obstacle matched."""

    seed: int
    obstacles: list[GridObstacle]
    spurious: int


def _bound_cm(o: SimObject) -> float:
    """Radius of the disk round an object's footprint that holds it."""
    return 0.5 * math.hypot(o.length_cm, o.width_cm)


def _seen_whole(camera: PhysicalGridCamera, truth: Sequence[SimObject]) -> list[bool]:
    """Per true object: does ``camera`` see it whole (module docstring)."""
    visible, alone = camera.world.visible_px(), camera.world.alone_px()
    out = []
    for o in truth:
        inside = disks_in_image(
            [o.x_cm, o.x_cm], [o.y_cm, o.y_cm], [0.0, o.z_cm], [_bound_cm(o)] * 2,
            camera.cam, MARGIN_PX,
        )  # fmt: skip
        hidden = 1.0 - visible.get(o.id, 0) / alone[o.id] if alone.get(o.id) else 1.0
        out.append(bool(inside.all()) and hidden <= HIDDEN_SHARE)
    return out


def _one_camera(
    config: OvisConfig, nx: int, ny: int, name: str, seed: int, folder: Path
) -> tuple[list[DetectedObject], PinholeParams, list[SimObject], list[bool]]:
    """One camera of the grid as ``ovis up`` runs it: its detections at t = 0, its
    calibration's camera, the truth and which objects it sees whole."""
    camera = PhysicalGridCamera(config, nx, ny, name, seed)
    try:
        frame, truth = camera.render(0)
        calib, floor = calibrate_grid_camera(camera)
        seen = _seen_whole(camera, truth.objects)
    finally:
        camera.close()
    background = folder / f"{name}-{seed}.png"
    cv2.imwrite(str(background), floor)
    image = msgspec.structs.replace(camera.config.image, background=str(background))
    detector = Detector(calib.camera, image, camera.config.pose)
    try:
        found = detector.detect(frame, stamp_s=0.0, fit_all=True).objects
    finally:
        detector.close()
    assert isinstance(calib.camera, PinholeParams)
    return found, calib.camera, list(truth.objects), seen


def _fused(fusion: FusionConfig, cameras: dict[str, tuple[list[DetectedObject], PinholeParams]]
           ) -> list[Fused]:  # fmt: skip
    """The cameras' detections of one instant as one world frame, by the fusion
    service's code (each camera's accuracy map from its calibration)."""
    views = {name: AccuracyMap(cam, fusion.pixel_sigma_px) for name, (_, cam) in cameras.items()}
    fuser = WorldFuser(list(cameras), fusion, stale_ns=10**9, views=views)
    out = []
    for name, (objects, _) in cameras.items():
        columns = detection_columns(name, [msgspec.to_builtins(o) for o in objects])
        out += fuser.add(name, 0, columns, 0)
    (world,) = out
    return [t.obj for t in world.objects]


def score_fused(seed: int, fused: list[Fused], truth: list[SimObject],
                seen: dict[str, list[bool]]) -> GridScene:  # fmt: skip
    """One world frame's fused objects against the truth (``seen``: per camera, which
    true objects it sees whole): each true obstacle's match (module docstring) and the
    fused objects left unmatched."""
    obstacles = [k for k, o in enumerate(truth) if o.kind == "obstacle"]
    acc = match_objects(fused, truth, gate_cm=GATE_CM)
    matched = dict(zip(acc.truth_index.tolist(), acc.detection_index.tolist(), strict=True))
    stated = leftovers_within_stated([_Stated.of(f) for f in fused], truth, matched)
    matched |= stated
    out = []
    nan = math.nan
    for k in obstacles:
        t = truth[k]
        f = fused[matched[k]] if k in matched else None
        ok = f is not None and f.kind == "obstacle"
        out.append(
            GridObstacle(
                seed=seed,
                true_height_cm=t.z_cm,
                seen_by=sorted(n for n, s in seen.items() if s[k]),
                found=ok,
                footprint_error_cm=math.hypot(f.x_cm - t.x_cm, f.y_cm - t.y_cm) if f else nan,
                height_cm=f.z_cm if f else nan,
                height_error_cm=f.z_cm - t.z_cm if f else nan,
                height_sigma_cm=nan if f is None or f.z_sigma_cm is None else f.z_sigma_cm,
                height_source=f.z_source if f else "",
                cameras=f.cameras if f else [],
                disagreeing=f.disagreeing if f else [],
                within_stated=k in stated,
            )
        )
    return GridScene(seed=seed, obstacles=out, spurious=acc.spurious - len(stated))


class _Stated(NamedTuple):
    """A fused object as :func:`~ovis.common.analysis.stated.leftovers_within_stated`
    reads it: its footprint's σ (the merged covariance's longest axis) taken in every
    direction."""

    x_cm: float
    y_cm: float
    covariance_cm2: list[float]

    @classmethod
    def of(cls, f: Fused) -> _Stated:
        v = f.sigma_cm**2
        return cls(f.x_cm, f.y_cm, [v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, 0.0])


class GridCameraView(msgspec.Struct, kw_only=True):
    """What one camera of a grid scene gives fusion, and which objects it sees whole."""

    name: str
    objects: list[DetectedObject]
    camera: PinholeParams  # its calibration's
    seen_whole: list[bool]  # per true object


class GridViews(msgspec.Struct, kw_only=True):
    """One seed's cameras (:class:`GridCameraView`) and its truth at t = 0."""

    seed: int
    cameras: list[GridCameraView]
    truth: list[SimObject]


def grid_views(config: OvisConfig, seed: int, nx: int = 2, ny: int = 2) -> GridViews:
    """Every camera of the seed's grid world, as ``ovis up`` runs it (module docstring)."""
    cfg = msgspec.structs.replace(
        config, service=msgspec.structs.replace(config.service, seed=int(seed))
    )
    views = []
    truth: list[SimObject] = []
    with tempfile.TemporaryDirectory(prefix="ovis-fused-heights-") as tmp:
        for spec in grid_specs(nx, ny, cfg, int(seed)):
            found, camera, truth, whole = _one_camera(cfg, nx, ny, spec.name, int(seed),
                                                      Path(tmp))  # fmt: skip
            views.append(GridCameraView(name=spec.name, objects=found, camera=camera,
                                        seen_whole=whole))  # fmt: skip
    return GridViews(seed=int(seed), cameras=views, truth=truth)


def score_grid(views: GridViews, fusion: FusionConfig) -> GridScene:
    """The cameras' detections fused (by the fusion service's code) and scored."""
    fused = _fused(fusion, {c.name: (c.objects, c.camera) for c in views.cameras})
    seen = {c.name: c.seen_whole for c in views.cameras}
    return score_fused(views.seed, fused, views.truth, seen)


def evaluate_grid(
    config: OvisConfig,
    seeds: Sequence[int],
    nx: int = 2,
    ny: int = 2,
    *,
    on_scene: Callable[[GridScene], None] | None = None,
) -> list[GridScene]:
    """Every seed's world through the grid's cameras and fusion (module docstring);
    ``config`` as ``ovis up --world physical`` takes it (the ``physical`` preset)."""
    scenes = []
    for seed in seeds:
        scene = score_grid(grid_views(config, int(seed), nx, ny), config.fusion)
        scenes.append(scene)
        if on_scene is not None:
            on_scene(scene)
    return scenes

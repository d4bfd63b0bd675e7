"""Footprints and heights in the physical world, against MuJoCo's truth (issue 36).

:func:`evaluate_rig` draws one physical scene per seed (:mod:`ovis.common.physical`:
4–8 obstacles — cylinders, boxes, prisms 1–25 cm tall, one per seed's count
``4 + seed % 5`` — and one 16 × 10 × 5 cm robot, on an arena of
:data:`ARENA_X_CM` × :data:`ARENA_Y_CM`), renders it at t = 0 through one rig
(:mod:`ovis.common.physical.rigs`) with the empty floor beside it, and runs
:class:`~ovis.common.world.detection.Detector` on the frame with the rig's true camera
(the calibration is not what is measured here):

* ``"measured"``: heights measured (``[pose] heights``), the empty floor subtracted
  (``[image] background``), objects :data:`LEVEL` grey levels brighter than it, every
  blob fitted in the one frame;
* ``"configured"``: today's method on the same segmentation — each blob's centroid on
  its class's plane (obstacles 7 cm, the robot 5 cm), the robot the least compact blob,
  the size filter's old 30 cm² on the 7 cm plane.

Each true object is matched to the detection nearest its footprint centre (an optimal
assignment within :data:`~ovis.common.analysis.stated.GATE_CM`); a detection whose
position is not measurable is matched within its stated uncertainty instead
(:mod:`~ovis.common.analysis.stated`). Such detections are counted
in a row of their own, and their footprint errors are kept out of the footprint's. An
obstacle must be found unless most of its silhouette is hidden by others (more than
:data:`HIDDEN_SHARE` of the pixels it covers alone,
:meth:`~ovis.common.physical.world.PhysicalWorld.alone_px`, not seen,
:meth:`~ovis.common.physical.world.PhysicalWorld.visible_px`): those are counted apart.
Reported per rig and method (:class:`RigReport`): obstacles found, missed, taken for
the robot, spurious detections; footprint error; positions not measurable, how many
within their stated uncertainty, their largest error and stated σ; the errors of
obstacles about 7 cm and about 20 cm tall (within :data:`HEIGHT_BIN_CM`); the measured
heights' errors and how many were not measurable; in how many scenes the robot was
reported as the robot (unmarked, and with ``marked``, carrying a marker).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import cv2
import msgspec
import numpy as np

from ovis.common.analysis.evaluation import match_objects
from ovis.common.analysis.stated import (
    GATE_CM,
    POSITION_SIGMA_CM,
    leftovers_within_stated,
    position_sigma,
)
from ovis.common.config import OvisConfig, RobotSpec, config_from_dict
from ovis.common.physical.rigs import rig
from ovis.common.physical.scene import random_scene
from ovis.common.physical.world import PhysicalWorld
from ovis.common.sim.arena import SimObject
from ovis.common.world.detection import DetectedObject, Detector

__all__ = [
    "ARENA_X_CM",
    "ARENA_Y_CM",
    "RigReport",
    "SceneResult",
    "evaluate_rig",
    "physical_config",
    "summarise",
]

Method = Literal["measured", "configured"]

#: The arena of issue 36's scenes (cm).
ARENA_X_CM = (0.0, 150.0)
ARENA_Y_CM = (0.0, 120.0)
#: Objects are this many grey levels brighter than the empty floor (measured heights).
LEVEL = 3
#: An obstacle more hidden than this share of its silhouette need not be found.
HIDDEN_SHARE = 0.5
#: "About 7 cm" and "about 20 cm" tall: within this of it (cm).
HEIGHT_BIN_CM = 1.5
#: The marked robot of the marked scenes.
MARKED_ROBOT = RobotSpec(
    id=1,
    name="r1",
    marker_id=3,
    marker_side_cm=7.0,
    marker_height_cm=5.0,
    radius_cm=9.5,
)


class SceneResult(msgspec.Struct, kw_only=True):
    """One scene's numbers: per true obstacle (in scene order) whether it must be found
    (not mostly hidden), whether it was found, taken for the robot, its footprint error
    (cm; NaN: not found), true height, reported height and where it came from, and
    whether the detection's position is not measurable (:data:`POSITION_SIGMA_CM`) and
    its stated footprint 1σ (NaN: none stated); the spurious detections; the detections
    whose position is not measurable and how many of those lie within their stated
    uncertainty of a true object; whether the robot was reported as the robot."""

    seed: int
    must_find: list[bool]
    found: list[bool]
    as_robot: list[bool]
    footprint_error_cm: list[float]
    true_height_cm: list[float]
    height_cm: list[float]
    height_source: list[str]
    height_sigma_cm: list[float]
    hidden_share: list[float]
    position_unmeasurable: list[bool]
    position_sigma_cm: list[float]
    spurious: int
    unmeasurable: int
    unmeasurable_within: int
    robot_found: bool
    seconds: float


_SCALARS = ("seed", "spurious", "unmeasurable", "unmeasurable_within", "robot_found", "seconds")


class RigReport(msgspec.Struct, kw_only=True):
    """The table's column for one rig and method (see the module's docstring)."""

    rig: str
    method: str
    marked: bool
    seeds: list[int]
    obstacles: int
    found: int
    missed: int
    as_robot: int
    spurious: int
    hidden: int
    hidden_found: int
    footprint_mean_cm: float
    footprint_max_cm: float
    positions_unmeasurable: int
    positions_within_stated: int
    unmeasurable_error_max_cm: float
    unmeasurable_sigma_max_cm: float
    near_7cm: int
    near_7cm_mean_cm: float
    near_7cm_max_cm: float
    near_20cm: int
    near_20cm_mean_cm: float
    near_20cm_max_cm: float
    heights_measured: int
    height_mean_cm: float
    height_max_cm: float
    heights_within_1cm: int
    heights_not_measurable: int
    robot_scenes: int
    scenes: int
    seconds_per_scene: float


def physical_config(config: OvisConfig, seed: int, *, marked: bool = False) -> OvisConfig:
    """``config`` on issue 36's arena with the seed's number of obstacles and, with
    ``marked``, one marked robot."""
    data = msgspec.to_builtins(config)
    data["simulator"]["arena_x_cm"] = list(ARENA_X_CM)
    data["simulator"]["arena_y_cm"] = list(ARENA_Y_CM)
    data["physical"]["n_obstacles"] = 4 + int(seed) % 5
    data["pose"]["robots"] = [msgspec.to_builtins(MARKED_ROBOT)] if marked else []
    return config_from_dict(data, "physical scene")


def _detector_config(config: OvisConfig, background: Path, method: Method) -> OvisConfig:
    data = msgspec.to_builtins(config)
    image, pose = data["image"], data["pose"]
    image.update(background=str(background), threshold=128 + LEVEL, threshold_mode="fixed")
    image.update(median="ordinary", polarity="bright")
    if method == "measured":
        pose["heights"] = "measured"
        image["size_filter_cm2"] = 20.0
    else:
        pose["heights"] = "configured"
        image["size_filter_cm2"] = 30.0
    return config_from_dict(data, f"{method} heights")


def _one_scene(
    config: OvisConfig, rig_name: str, seed: int, method: Method, marked: bool, folder: Path
) -> SceneResult:
    import time

    cfg = physical_config(config, seed, marked=marked)
    camera = rig(rig_name, cfg)
    scene = random_scene(cfg, seed, [camera])
    world = PhysicalWorld(scene, cfg, [camera])
    try:
        world.set_time(0.0)
        frame = world.render(0)
        floor = world.clean(solids=False)
        truth = world.truth(0)
        visible, alone = world.visible_px(), world.alone_px()
    finally:
        world.close()
    background = folder / f"floor_{rig_name}_{seed}.png"
    cv2.imwrite(str(background), floor)
    dcfg = _detector_config(cfg, background, method)
    detector = Detector(camera, dcfg.image, dcfg.pose)
    t0 = time.perf_counter()
    det = detector.detect(frame, stamp_s=0.0, fit_all=True)
    seconds = time.perf_counter() - t0
    return _score(seed, det.objects, truth.objects, visible, alone, seconds)


def _score(
    seed: int,
    objects: Sequence[DetectedObject],
    truth: Sequence[SimObject],
    visible: dict[int, int],
    alone: dict[int, int],
    seconds: float,
) -> SceneResult:
    acc = match_objects(objects, truth, gate_cm=GATE_CM)
    matched = dict(zip(acc.truth_index.tolist(), acc.detection_index.tolist(), strict=True))
    sigma = [position_sigma(d) for d in objects]
    unmeasurable = [j for j, s in enumerate(sigma) if s > POSITION_SIGMA_CM]
    matched |= leftovers_within_stated(objects, truth, matched)
    out: dict[str, list] = {k: [] for k in SceneResult.__struct_fields__ if k not in _SCALARS}
    robot_found = False
    for i, o in enumerate(truth):
        d = objects[matched[i]] if i in matched else None
        if o.kind == "robot":
            robot_found = d is not None and d.kind == "robot"
            continue
        hidden = 1.0 - visible[o.id] / alone[o.id] if alone[o.id] else 1.0
        out["must_find"].append(hidden <= HIDDEN_SHARE)
        out["found"].append(d is not None and d.kind == "obstacle")
        out["as_robot"].append(d is not None and d.kind == "robot")
        out["footprint_error_cm"].append(
            math.hypot(d.x_cm - o.x_cm, d.y_cm - o.y_cm) if d is not None else math.nan
        )
        out["true_height_cm"].append(o.z_cm)
        out["height_cm"].append(d.z_cm if d is not None else math.nan)
        source = "" if d is None else (d.z_source if not d.z_unmeasured else d.z_unmeasured)
        out["height_source"].append(source)
        z_sigma = d.z_sigma_cm if d is not None and d.z_sigma_cm is not None else math.nan
        out["height_sigma_cm"].append(z_sigma)
        out["hidden_share"].append(hidden)
        xy_sigma = sigma[matched[i]] if i in matched else math.nan
        out["position_unmeasurable"].append(xy_sigma > POSITION_SIGMA_CM)
        out["position_sigma_cm"].append(xy_sigma)
    return SceneResult(
        seed=seed,
        spurious=len(objects) - len(matched),
        unmeasurable=len(unmeasurable),
        unmeasurable_within=sum(1 for j in matched.values() if sigma[j] > POSITION_SIGMA_CM),
        robot_found=robot_found,
        seconds=seconds,
        **out,
    )


def evaluate_rig(
    config: OvisConfig,
    rig_name: str,
    seeds: Sequence[int],
    method: Method,
    *,
    marked: bool = False,
    on_scene: Callable[[SceneResult], None] | None = None,
) -> list[SceneResult]:
    """Every seed's scene through ``rig_name`` by ``method`` (module docstring)."""
    out = []
    with tempfile.TemporaryDirectory(prefix="ovis-footprints-") as tmp:
        for seed in seeds:
            result = _one_scene(config, rig_name, int(seed), method, marked, Path(tmp))
            out.append(result)
            if on_scene is not None:
                on_scene(result)
    return out


def _mean_max(values: list[float]) -> tuple[float, float]:
    v = [x for x in values if math.isfinite(x)]
    return (float(np.mean(v)), float(np.max(v))) if v else (math.nan, math.nan)


def summarise(
    results: Sequence[SceneResult], rig_name: str, method: str, *, marked: bool = False
) -> RigReport:
    """The table's column of one rig and method from its scenes."""
    rows = [(s, i) for s in results for i in range(len(s.must_find))]
    must = [(s, i) for s, i in rows if s.must_find[i]]
    hidden = [(s, i) for s, i in rows if not s.must_find[i]]
    found = [(s, i) for s, i in must if s.found[i]]
    errors = [s.footprint_error_cm[i] for s, i in found if not s.position_unmeasurable[i]]
    unmeasurable = [(s, i) for s, i in rows if s.found[i] and s.position_unmeasurable[i]]

    def near(height: float) -> list[float]:
        return [
            s.footprint_error_cm[i]
            for s, i in found
            if abs(s.true_height_cm[i] - height) <= HEIGHT_BIN_CM and not s.position_unmeasurable[i]
        ]

    n7, n20 = near(7.0), near(20.0)
    measured = [(s, i) for s, i in found if s.height_source[i] in ("one camera", "cameras")]
    dz = [abs(s.height_cm[i] - s.true_height_cm[i]) for s, i in measured]
    fm, fx = _mean_max(errors)
    m7, x7 = _mean_max(n7)
    m20, x20 = _mean_max(n20)
    hm, hx = _mean_max(dz)
    return RigReport(
        rig=rig_name,
        method=method,
        marked=marked,
        seeds=[s.seed for s in results],
        obstacles=len(must),
        found=len(found),
        missed=sum(1 for s, i in must if not s.found[i] and not s.as_robot[i]),
        as_robot=sum(1 for s, i in must if s.as_robot[i]),
        spurious=sum(s.spurious for s in results),
        hidden=len(hidden),
        hidden_found=sum(1 for s, i in hidden if s.found[i]),
        footprint_mean_cm=fm,
        footprint_max_cm=fx,
        positions_unmeasurable=sum(s.unmeasurable for s in results),
        positions_within_stated=sum(s.unmeasurable_within for s in results),
        unmeasurable_error_max_cm=_mean_max([s.footprint_error_cm[i] for s, i in unmeasurable])[1],
        unmeasurable_sigma_max_cm=_mean_max([s.position_sigma_cm[i] for s, i in unmeasurable])[1],
        near_7cm=len(n7),
        near_7cm_mean_cm=m7,
        near_7cm_max_cm=x7,
        near_20cm=len(n20),
        near_20cm_mean_cm=m20,
        near_20cm_max_cm=x20,
        heights_measured=len(measured),
        height_mean_cm=hm,
        height_max_cm=hx,
        heights_within_1cm=sum(1 for d in dz if d <= 1.0),
        heights_not_measurable=sum(1 for s, i in found if s.height_source[i] == "not measurable"),
        robot_scenes=sum(1 for s in results if s.robot_found),
        scenes=len(results),
        seconds_per_scene=float(np.mean([s.seconds for s in results])) if results else 0.0,
    )

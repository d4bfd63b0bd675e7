"""``ovis simulate --world physical``: frames of a physical world with their truth and
everything a user needs to calibrate the camera on the floor marks.

Files written in ``out_dir`` (each atomically):

* ``frame_0000.png`` … — the grey frames; frame k shows the world at ``t = k / fps``
  (``[simulator] fps``; the world repeats every ``period_s``);
* ``truth.json`` — the seed, the camera, the floor marks and, per frame, its time and
  every solid read from the physics state (:class:`~ovis.common.sim.arena.SimObject`:
  footprint centre, height, yaw, velocity, shape) with how much of it the camera sees
  (:class:`~ovis.common.physical.world.SolidView`);
* ``background.png`` — the empty floor with its marks, without sensor noise (for
  ``[image] background``: the configuration in ``points.toml`` names it);
* ``points.toml`` — the floor marks as control points, their pixels measured in the
  empty floor (:mod:`ovis.common.physical.marks`), and the configuration;
* ``lens.yaml`` — the camera's lens (a pinhole camera only): what ``ovis intrinsics``
  measures from board photos, here exact, for ``ovis calibrate --intrinsics``;
* ``true_calibration.json`` — the camera the frames were rendered through as a
  calibration file (ground truth: for skipping the calibration, or judging one).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import msgspec

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import Calibration, now_iso, save_calibration
from ovis.common.calibration.floor import MIN_POINTS
from ovis.common.camera.intrinsics import write_intrinsics
from ovis.common.config import OvisConfig, PinholeParams, dump_toml
from ovis.common.physical.marks import lens_of, measure_marks
from ovis.common.physical.scene import FloorMark, random_scene
from ovis.common.physical.world import PhysicalWorld, SolidView
from ovis.common.sim.arena import SimObject

__all__ = ["PhysicalDatasetInfo", "true_calibration", "write_physical_dataset"]


class PhysicalDatasetInfo(msgspec.Struct, kw_only=True, frozen=True):
    """What :func:`write_physical_dataset` wrote (``lens`` None: not a pinhole camera)."""

    out_dir: Path
    frames: list[Path]
    truth: Path
    background: Path
    points: Path
    marks_measured: int
    lens: Path | None
    true_calibration: Path


class _FrameRecord(msgspec.Struct, kw_only=True):
    index: int
    file: str
    t_s: float
    objects: list[SimObject]
    views: list[SolidView]


class _TruthFile(msgspec.Struct, kw_only=True):
    seed: int
    preset: str
    world: str
    camera: dict[str, object]
    fps: float
    period_s: float
    marks: list[FloorMark]
    frames: list[_FrameRecord]


def _png(path: Path, image) -> Path:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"could not encode {path.name} as PNG")
    write_atomic(path, buf.tobytes())
    return path


def true_calibration(config: OvisConfig) -> Calibration:
    """The configured camera as a calibration file: ground truth, not calibrated (no
    residuals), with the configuration's image and pose settings."""
    none = dict.fromkeys(("dipe_px", "dipe_max_px"), 0.0)
    return Calibration(
        created=now_iso(),
        dipe_mm=None,
        dipe_max_mm=None,
        camera=config.camera,
        image=config.image,
        pose=config.pose,
        source_image="ground truth: the camera the physical world renders through",
        simulated=True,
        **none,
    )


def write_physical_dataset(
    out_dir: Path,
    config: OvisConfig,
    frames: int,
    seed: int,
    *,
    robots: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> PhysicalDatasetInfo:
    """Render ``frames`` frames of the physical world of ``seed`` through
    ``config.camera`` and write the data set (module docstring); ``robots``: unmarked
    robots when ``config.pose.robots`` lists none; ``progress(done, total)`` after each
    frame. Raises ValueError for a scene that does not fit (its message says what to
    change)."""
    if int(frames) < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    camera = config.camera
    background = out_dir / "background.png"
    image = msgspec.structs.replace(config.image, background=str(background))
    config = msgspec.structs.replace(config, image=image)
    scene = random_scene(config, seed, [camera], robots=robots)
    world = PhysicalWorld(scene, config, [camera])
    fps = config.simulator.fps
    records: list[_FrameRecord] = []
    paths: list[Path] = []
    try:
        floor = world.clean(solids=False)
        _png(background, floor)
        marks = measure_marks(floor, scene.marks, camera)
        if len(marks) < MIN_POINTS:
            raise ValueError(
                f"{len(marks)} floor mark(s) seen in the empty floor: calibrating the camera "
                f"on them needs at least {MIN_POINTS}; raise [physical] floor_marks"
            )
        for k in range(int(frames)):
            t = k / fps
            world.set_time(t)
            name = f"frame_{k:04d}.png"
            paths.append(_png(out_dir / name, world.render(k)))
            truth = world.truth(k)
            records.append(
                _FrameRecord(index=k, file=name, t_s=t, objects=truth.objects, views=world.views())
            )
            if progress is not None:
                progress(k + 1, int(frames))
    finally:
        world.close()
    truth_path = out_dir / "truth.json"
    truth_file = _TruthFile(
        seed=int(seed),
        preset=config.preset,
        world="physical",
        camera=msgspec.to_builtins(camera),
        fps=fps,
        period_s=scene.period_s,
        marks=scene.marks,
        frames=records,
    )
    write_atomic(truth_path, msgspec.json.format(msgspec.json.encode(truth_file), indent=2))
    lens = None
    if isinstance(camera, PinholeParams):
        lens = out_dir / "lens.yaml"
        note = (
            "the physical world's camera lens, exact (ground truth): what ovis intrinsics measures"
        )
        write_intrinsics(lens, lens_of(camera), note=note)
    header = (
        f"# ovis physical world (seed {int(seed)}): control points = the floor marks, the "
        "centres of their printed discs (world cm), their pixels (row, col) measured in "
        f"{background.name}\n"
    )
    points = [msgspec.to_builtins(p) for p in marks]
    text = header + dump_toml({"points": points, "config": msgspec.to_builtins(config)})
    points_path = out_dir / "points.toml"
    write_atomic(points_path, text.encode("utf-8"))
    calib_path = out_dir / "true_calibration.json"
    save_calibration(calib_path, true_calibration(config))
    return PhysicalDatasetInfo(
        out_dir=out_dir,
        frames=paths,
        truth=truth_path,
        background=background,
        points=points_path,
        marks_measured=len(marks),
        lens=lens,
        true_calibration=calib_path,
    )

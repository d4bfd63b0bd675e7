"""What the commands share about the physical world (``--world physical``,
docs/physical.md): the configuration it runs with, whether this machine can render it,
the camera to render through, its scene, and ``ovis simulate --world physical``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec

from ovis.services.cli.errors import UserError

__all__ = [
    "WORLDS",
    "live_physical",
    "physical_camera",
    "physical_scene",
    "require_physical",
    "simulate_physical",
    "with_empty_floor",
    "world_config",
    "world_options",
]

WORLDS = ("light", "physical")


def world_config(config_file: Path | None, preset: str | None, world: str | None) -> Any:
    """The configuration of an offline command: ``--config``, else ``--preset`` (the
    ``physical`` preset for ``--world physical`` when neither is given), with ``--world``
    laid over its ``[simulator] world``."""
    from ovis.common.config import resolve_config

    if world is not None and world not in WORLDS:
        raise UserError(f"--world must be one of {', '.join(WORLDS)}, got {world!r}")
    if world == "physical" and config_file is None and preset is None:
        preset = "physical"
    cfg = resolve_config(config_file, preset)
    if world is not None:
        cfg = msgspec.structs.replace(
            cfg, simulator=msgspec.structs.replace(cfg.simulator, world=world)
        )
    return cfg


def world_options(config_file: Path | None, world: str | None) -> dict[str, str | None]:
    """``with_options``' ``preset`` and ``world`` for ``--world``: the ``physical``
    preset for ``--world physical`` without ``--config``."""
    if world is not None and world not in WORLDS:
        raise UserError(f"--world must be one of {', '.join(WORLDS)}, got {world!r}")
    preset = "physical" if world == "physical" and config_file is None else None
    return {"preset": preset, "world": world}


def live_physical(cfg: Any, calibration: Path | None) -> bool:
    """Whether ``ovis up`` renders the physical world live (source ``sim``, ``[simulator]
    world = "physical"``); exit 2 when this machine cannot render it, or when the
    calibrator could not calibrate its camera on the floor marks and no --calibration
    is given."""
    if cfg.service.source != "sim" or cfg.simulator.world != "physical":
        return False
    require_physical()
    if calibration is None and cfg.service.points == "simulator":
        from ovis.common.pipeline.floor_marks import marks_problem

        problem = marks_problem(cfg)
        if problem is not None:
            raise UserError(f"{problem} (nothing was started)")
    return True


def with_empty_floor(cfg: Any, folder: Path) -> tuple[Any, str]:
    """The configuration segmenting the frames against the physical world's empty floor,
    rendered now into ``folder``/background.png (a configured ``[image] background`` is
    kept), and what to say about it."""
    from ovis.common.physical.marks import empty_floor

    fps = f"{cfg.service.fps:g} frames/s" if cfg.service.fps > 0 else "as fast as it renders"
    world = (
        f"the physical world (seed {cfg.service.seed}), each frame rendered by MuJoCo "
        f"when it is due at {fps}"
    )
    if cfg.image.background:
        return cfg, f"{world}; segmented against {cfg.image.background} ([image] background)"
    from ovis.common.analysis.plots import save_png

    path = folder / "background.png"
    save_png(path, empty_floor(cfg).image)
    image = msgspec.structs.replace(cfg.image, background=str(path))
    return (
        msgspec.structs.replace(cfg, image=image),
        f"{world}; segmented against its empty floor, rendered to {path}",
    )


def require_physical() -> None:
    """Stop with one line (exit 2) when this machine cannot render the physical world."""
    from ovis.common.physical.availability import why_unavailable

    why = why_unavailable()
    if why is not None:
        raise UserError(f"the physical world cannot run here: {why}")


def physical_camera(spec: str | None, cfg: Any) -> Any:
    """The configuration with the camera ``--camera`` names: a rig ('oblique',
    'overhead', over the configuration's arena at its frame size) or a calibration JSON
    (its camera); None keeps the configuration's."""
    if spec is None:
        return cfg
    from ovis.common.physical.rigs import RIGS, rig

    if spec in RIGS:
        camera = rig(spec, cfg)
    else:
        from ovis.common.calibration.file import load_calibration

        path = Path(spec)
        if not path.is_file():
            raise UserError(
                f"--camera {spec!r} is neither a rig ({', '.join(RIGS)}) nor a calibration file"
            )
        camera = load_calibration(path).camera
    return msgspec.structs.replace(cfg, camera=camera)


def physical_scene(cfg: Any, robots: int | None, obstacles: int | None) -> Any:
    """The configuration with ``robots`` marked robots (markers 0…N−1 on robots of the
    light world's marked size, :func:`ovis.common.sim.scenes.marked_scene`; the arena
    kept) and ``obstacles`` obstacles (``[physical] n_obstacles``)."""
    if robots is not None:
        from ovis.common.sim.scenes import marked_scene

        arena = {"arena_x_cm": cfg.simulator.arena_x_cm, "arena_y_cm": cfg.simulator.arena_y_cm}
        cfg = marked_scene(cfg, robots)
        cfg = msgspec.structs.replace(
            cfg, simulator=msgspec.structs.replace(cfg.simulator, **arena)
        )
    if obstacles is not None:
        phys = msgspec.structs.replace(cfg.physical, n_obstacles=obstacles)
        cfg = msgspec.structs.replace(cfg, physical=phys)
    return cfg


def simulate_physical(
    out: Path,
    cfg: Any,
    frames: int,
    seed: int,
    *,
    json: bool,
    robots: int | None,
    obstacles: int | None,
    camera: str | None,
) -> None:
    """``ovis simulate --world physical``: the data set of
    :func:`ovis.common.physical.dataset.write_physical_dataset`, with progress."""
    from ovis.services.cli.ui import emit_json, progress

    require_physical()
    cfg = physical_scene(physical_camera(camera, cfg), robots, obstacles)
    from ovis.common.physical.dataset import write_physical_dataset

    try:
        with progress("rendering", show=not json) as update:
            info = write_physical_dataset(
                out,
                cfg,
                frames,
                seed,
                progress=lambda done, total: update(done, total, "frames"),
            )
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if json:
        emit_json(info)
    else:
        _say_written(out, cfg, frames, seed, info)


def _say_written(out: Path, cfg: Any, frames: int, seed: int, info: Any) -> None:
    """What ``ovis simulate --world physical`` wrote, and what to run next."""
    from ovis.services.cli.ui import console

    con = console()
    con.soft_wrap = True  # paths and the next command whole, to be copied (not cut at 80)
    cam = cfg.camera
    con.print(
        f"wrote {frames} frame(s) of the physical world ({cam.cols}x{cam.rows}, seed {seed}, "
        f"{cfg.simulator.fps:g} frames/s) to {out}"
    )
    con.print(
        f"  ground truth: {info.truth}\n  empty floor: {info.background}\n"
        f"  control points: {info.points} ({info.marks_measured} floor marks)\n"
        f"  true camera: {info.true_calibration}"
    )
    calib = out / "calib.json"
    if info.lens is None:
        con.print(
            "  the camera is the paper's model: no lens file; detect with the true camera "
            f"(ovis detect {out / 'frame_0*.png'} --calibration {info.true_calibration})"
        )
        return
    con.print(
        f"next: ovis calibrate {info.background} --intrinsics {info.lens} --points "
        f"{info.points} --out {calib}\n"
        f"then: ovis detect {out / 'frame_0000.png'} --calibration {calib}"
    )

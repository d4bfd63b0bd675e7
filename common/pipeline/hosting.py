"""Which cameras one stage process serves, and the configuration of each.

With several cameras on a host (``[[cameras]]``), one process per stage serves every
camera of the host (``[service] layout = "per-stage"``): each camera keeps its own
topics, counters, status and calibration, exactly as its own chain's process would
have them, so no consumer can tell the two layouts apart. The configuration a camera's
handlers see is the arena's with that camera's name, source and model laid over it
(:func:`camera_config`): what ``[service] camera_name`` gives one camera's chain.
"""

from __future__ import annotations

from pathlib import Path

import msgspec

from ovis.common.calibration.file import load_calibration
from ovis.common.config import CameraModel, CameraSpec, OvisConfig
from ovis.common.trust.keys import keys_dir

__all__ = ["camera_config", "camera_model", "camera_state_dir", "served_cameras"]


def camera_model(spec: CameraSpec) -> CameraModel:
    """A camera's model on the shared floor: inline, or from its calibration file."""
    if spec.camera is not None:
        return spec.camera
    return load_calibration(spec.calibration).camera  # type: ignore[arg-type]


def served_cameras(cfg: OvisConfig) -> list[str]:
    """The cameras a stage process of ``cfg`` serves: ``[service] cameras``, else every
    camera of ``[[cameras]]``; none when the process is one camera's chain
    (``camera_name``) or there is one camera (no ``[[cameras]]``)."""
    if cfg.service.camera_name is not None:
        return []
    return list(cfg.service.cameras) or [spec.name for spec in cfg.cameras]


def camera_state_dir(cfg: OvisConfig, name: str) -> str:
    """Where a camera's calibrations are kept when one process serves several: its own
    folder under the state folder (each camera's versions are its own)."""
    return str(Path(cfg.service.state_dir) / "cam" / name)


def camera_config(cfg: OvisConfig, name: str) -> OvisConfig:
    """The configuration of camera ``name``'s handlers: the arena's, with the camera's
    name (its topics ``ovis/<arena>/cam/<name>/…``), source, model on the shared floor
    and empty floor (if it has one), and its own state folder; the keys stay where the
    arena's are (one signer per role and host). A calibration file that cannot be read raises
    :class:`~ovis.common.calibration.file.CalibrationFileError`."""
    spec = next((s for s in cfg.cameras if s.name == name), None)
    if spec is None:
        listed = ", ".join(s.name for s in cfg.cameras) or "none"
        raise ValueError(f"camera {name!r} is not in [[cameras]] (listed: {listed})")
    service = msgspec.structs.replace(
        cfg.service,
        camera_name=name,
        cameras=[],
        source=spec.source,
        state_dir=camera_state_dir(cfg, name),
    )
    trust = msgspec.structs.replace(cfg.trust, keys_dir=str(keys_dir(cfg)))
    image = cfg.image
    if spec.background is not None:  # its own empty floor
        image = msgspec.structs.replace(image, background=spec.background)
    return msgspec.structs.replace(
        cfg, camera=camera_model(spec), image=image, service=service, trust=trust, cameras=[]
    )

"""The calibrator's control points in the physical world: the floor marks, not the
objects' top faces (the solids' walls would pull a top face's blob off its centre).

As a user would before placing anything: the empty floor pictured by the configured
camera (:meth:`~ovis.common.physical.world.PhysicalWorld.clean`), the marks' pixels
measured in it, and the camera's pose over the floor solved from them with its lens
fixed (:mod:`ovis.common.physical.marks`). The world and its marks come from the seed
(the capture's own world: the same configuration, the same seed), so the result is the
same every time: it is computed once per process.
"""

from __future__ import annotations

import threading

import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration
from ovis.common.config import OvisConfig, PinholeParams

__all__ = ["FloorMarksCalibration", "marks_problem"]


def marks_problem(config: OvisConfig) -> str | None:
    """Why the calibrator cannot calibrate on the physical world's floor marks, or None."""
    if not isinstance(config.camera, PinholeParams):
        return (
            "the physical world's calibration solves the pose of a pinhole camera on the "
            f"floor marks; [camera] model is {config.camera.model!r}: give a pinhole camera, "
            "or a calibration (ovis up --calibration)"
        )
    return None


class FloorMarksCalibration:
    """The calibration on the floor marks of ``config``'s physical world (the module
    docstring), made on the first call and kept."""

    def __init__(self, config: OvisConfig) -> None:
        self.config = config
        #: the empty floor the marks were measured in (once made)
        self.floor: NDArray[np.uint8] | None = None
        self._made: Calibration | None = None
        self._lock = threading.Lock()

    def __call__(self) -> Calibration:
        """The calibration; ValueError (a ``FloorPoseError``) when the marks give no pose,
        or the camera is not a pinhole."""
        with self._lock:
            if self._made is None:
                self._made = self._make()
            return self._made

    def _make(self) -> Calibration:
        problem = marks_problem(self.config)
        if problem is not None:
            raise ValueError(problem)
        from ovis.common.physical.marks import calibrate_on_marks, empty_floor, measure_marks

        cfg = self.config
        camera = cfg.camera
        assert isinstance(camera, PinholeParams)
        seed = cfg.service.seed
        floor = empty_floor(cfg)
        self.floor = floor.image
        points = measure_marks(floor.image, floor.marks, camera)
        source = (
            f"{len(points)} floor marks of the empty floor (physical world, seed {seed}), "
            "the lens of the configured camera"
        )
        calib = calibrate_on_marks(points, camera, cfg, source=source)
        return msgspec.structs.replace(calib, simulated=True)

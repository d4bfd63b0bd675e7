"""What cameras saw, on the shared floor frame: one object as a :class:`Sighting`
(a readable Struct, for tests and tools) or a whole frame's objects as
:class:`Sightings` (columns of numbers), which is what the per-frame path carries, so
that a world frame costs a few vectorised operations and not a Python object and a
numpy call per object."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

__all__ = ["Sighting", "Sightings"]

FloatArray = NDArray[np.float64]

#: the columns of :attr:`Sightings.data`
X, Y, Z, R, CXX, CXY, CYY, HEADING, MARKER = range(9)
COLUMNS = 9


class Sighting(msgspec.Struct, kw_only=True, frozen=True):
    """One object as one camera saw it, on the shared floor frame (cm, degrees);
    ``cov_cm2`` is the position covariance ``(xx, xy, yy)``, see
    :func:`ovis.common.fusion.accuracy.position_covariance`."""

    camera: str
    kind: str  # "robot" or "obstacle"
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    cov_cm2: tuple[float, float, float]
    marker_id: int | None = None
    heading_deg: float | None = None


class Sightings:
    """Several sightings as columns: ``data`` ``(n, 9)`` floats (x, y, z, radius,
    covariance xx, xy, yy, heading, marker; heading and marker NaN when absent),
    ``robot`` (kind is "robot"), ``cam`` (index into ``cameras``, the camera names).
    ``resolved`` False: detections as a camera sent them, their covariances not known
    yet and blobs cut by the image border not left out (see
    :meth:`ovis.common.fusion.tables.TableSet.resolve`)."""

    __slots__ = ("cam", "cameras", "data", "resolved", "robot")

    def __init__(
        self,
        cameras: Sequence[str],
        data: FloatArray,
        robot: NDArray[np.bool_],
        cam: NDArray[np.intp] | None = None,
        *,
        resolved: bool = True,
    ) -> None:
        self.cameras = tuple(cameras)
        self.data = data
        self.robot = robot
        self.cam = np.zeros(len(data), np.intp) if cam is None else cam
        self.resolved = resolved

    def __len__(self) -> int:
        return len(self.data)

    @classmethod
    def empty(cls, camera: str) -> Sightings:
        """No sighting (a camera's frame with nothing in it)."""
        return cls((camera,), np.zeros((0, COLUMNS)), np.zeros(0, bool))

    @classmethod
    def of(cls, sightings: Iterable[Sighting]) -> Sightings:
        """Sighting Structs as columns (any cameras)."""
        items = list(sightings)
        names = list(dict.fromkeys(s.camera for s in items))
        index = {n: k for k, n in enumerate(names)}
        none = float("nan")
        rows = [
            (s.x_cm, s.y_cm, s.z_cm, s.radius_cm, *s.cov_cm2,
             none if s.heading_deg is None else s.heading_deg,
             none if s.marker_id is None else s.marker_id)
            for s in items
        ]  # fmt: skip
        return cls(
            names,
            np.array(rows, float).reshape(-1, COLUMNS),
            np.array([s.kind == "robot" for s in items], bool),
            np.array([index[s.camera] for s in items], np.intp),
        )

    @classmethod
    def joined(cls, parts: Sequence[Sightings]) -> Sightings:
        """Several batches (e.g. one per camera of a world frame) as one."""
        if len(parts) == 1:
            return parts[0]
        names: dict[str, int] = {}
        cams = []
        for p in parts:
            remap = np.array([names.setdefault(n, len(names)) for n in p.cameras], np.intp)
            cams.append(remap[p.cam] if len(p) else p.cam)
        return cls(
            list(names),
            np.concatenate([p.data for p in parts]) if parts else np.zeros((0, COLUMNS)),
            np.concatenate([p.robot for p in parts]) if parts else np.zeros(0, bool),
            np.concatenate(cams) if parts else np.zeros(0, np.intp),
        )

    def to_list(self) -> list[Sighting]:
        """The sightings as Structs (for reading, not for the per-frame path)."""
        out = []
        for row, robot, cam in zip(self.data.tolist(), self.robot.tolist(), self.cam.tolist(),
                                   strict=True):  # fmt: skip
            heading, marker = row[HEADING], row[MARKER]
            out.append(
                Sighting(
                    camera=self.cameras[cam],
                    kind="robot" if robot else "obstacle",
                    x_cm=row[X],
                    y_cm=row[Y],
                    z_cm=row[Z],
                    radius_cm=row[R],
                    cov_cm2=(row[CXX], row[CXY], row[CYY]),
                    marker_id=None if marker != marker else int(marker),
                    heading_deg=None if heading != heading else heading,
                )
            )
        return out

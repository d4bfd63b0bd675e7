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

__all__ = ["Sighting", "Sightings", "detection_row"]

FloatArray = NDArray[np.float64]

#: the columns of :attr:`Sightings.data`: footprint and height as reported, radius, the
#: covariance of (x, y) (xx, xy, yy), heading, marker; then the fitted height's
#: covariance with them (xz, yz, zz; NaN: no height fitted), where the reported height
#: comes from (an index into :data:`Z_SOURCES`) and the fitted height (the reported one
#: where measured, the fit's where not measurable by this camera alone; NaN: none)
X, Y, Z, R, CXX, CXY, CYY, HEADING, MARKER, CXZ, CYZ, CZZ, ZSRC, ZFIT = range(14)
COLUMNS = 14
#: ``DetectedObject.z_source``'s values, by their code in the column ``ZSRC``
Z_SOURCES = ("configured", "marker", "one camera", "cameras")


def detection_row(
    x_cm: float,
    y_cm: float,
    z_cm: float,
    radius_cm: float,
    *,
    heading_deg: float | None = None,
    marker_id: int | None = None,
    covariance_cm2: Sequence[float] | None = None,
    z_source: str = "configured",
    z_unmeasured: str = "",
    z_fit_cm: float | None = None,
) -> tuple[float, ...]:
    """One detection as a row of :data:`COLUMNS` (a ``DetectedObject``'s fields): its
    covariance of (x, y, z) where its camera fitted one (9 numbers, row by row), the
    height's part only where a height was fitted: measured (``z_source`` "one camera"
    or "cameras") or, "not measurable" by this camera alone, ``z_fit_cm``; the (x, y)
    covariance NaN where none came (the camera's accuracy map gives it,
    :meth:`ovis.common.fusion.tables.TableSet.resolve`)."""
    nan = float("nan")
    c = [nan] * 9 if covariance_cm2 is None else [float(v) for v in covariance_cm2]
    fit = nan
    if z_source in ("one camera", "cameras") and not z_unmeasured:
        fit = z_cm
    elif z_unmeasured == "not measurable" and z_fit_cm is not None:
        fit = z_fit_cm
    cz = (c[2], c[5], c[8]) if fit == fit else (nan, nan, nan)
    return (
        x_cm, y_cm, z_cm, radius_cm, c[0], c[1], c[4],
        nan if heading_deg is None else heading_deg,
        nan if marker_id is None else marker_id,
        *cz, Z_SOURCES.index(z_source), fit,
    )  # fmt: skip


class Sighting(msgspec.Struct, kw_only=True, frozen=True):
    """One object as one camera saw it, on the shared floor frame (cm, degrees);
    ``cov_cm2`` is the position covariance ``(xx, xy, yy)``, see
    :func:`ovis.common.fusion.accuracy.position_covariance`; ``cov_z_cm2`` the measured
    height's covariance with x, y and itself ``(xz, yz, zz)`` (None: ``z_cm`` is not
    measured, it counts for nothing where a camera measures it); ``z_source`` one of
    :data:`Z_SOURCES`."""

    camera: str
    kind: str  # "robot" or "obstacle"
    x_cm: float
    y_cm: float
    z_cm: float
    radius_cm: float
    cov_cm2: tuple[float, float, float]
    marker_id: int | None = None
    heading_deg: float | None = None
    cov_z_cm2: tuple[float, float, float] | None = None
    z_source: str = "configured"
    z_fit_cm: float | None = None  # the fitted height (default: z_cm where cov_z_cm2 is given)


class Sightings:
    """Several sightings as columns: ``data`` ``(n, 13)`` floats (see :data:`COLUMNS`;
    heading and marker NaN when absent, the height's covariance NaN when not measured),
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
             none if s.marker_id is None else s.marker_id,
             *((none, none, none) if s.cov_z_cm2 is None else s.cov_z_cm2),
             Z_SOURCES.index(s.z_source),
             none if s.cov_z_cm2 is None else s.z_cm if s.z_fit_cm is None else s.z_fit_cm)
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
            cov_z = (row[CXZ], row[CYZ], row[CZZ])
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
                    cov_z_cm2=None if cov_z[2] != cov_z[2] else cov_z,
                    z_source=Z_SOURCES[int(row[ZSRC])],
                    z_fit_cm=None if row[ZFIT] != row[ZFIT] else row[ZFIT],
                )
            )
        return out

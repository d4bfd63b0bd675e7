"""The camera's pose over the floor with a known lens, from points whose pixel is known.

With the intrinsics fixed (K and distortion from ``ovis intrinsics``), a pose has six
unknowns, and each control point with a known pixel (a board corner, a marker corner, a
clicked point: ``row``, ``col`` in the points file) gives two equations; no blob
matching is needed. ``cv2.solvePnP`` gives the pose (IPPE for points on one plane, SQPnP
otherwise), ``cv2.solvePnPRefineLM`` refines it by Levenberg–Marquardt on the pixel
residuals. Error is reported as for the GA: each point's DIPE (eq. 14, px; mm only with a
known pixel pitch) and, held out, leave-one-out: the pose refitted without a point and
that point's error in px (projection vs. its pixel) and in cm on its plane (its pixel
back-projected vs. its position). The residuals are judged against what the lens's own
error and the points' pixel precision explain (:mod:`ovis.common.calibration.lens_check`,
``accuracy.lens``): a wrong point, or a lens that is not this camera's, is named.

The points must be usable: at least :data:`MIN_POINTS`, inside the image, not all on
one line (in the world or in the image), no two at the same place.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.file import Calibration, PointResidual, mm_or_none, now_iso
from ovis.common.calibration.lens_check import CLICK_PX, pose_check
from ovis.common.calibration.quality import AccuracyReport, HeldOut, HeldOutPoint
from ovis.common.camera.intrinsics import CameraIntrinsics, with_pose
from ovis.common.camera.paper_model import Projection
from ovis.common.camera.pinhole import back_project, project
from ovis.common.config import (
    PINHOLE_VARIABLES,
    ControlPoint,
    ImageParams,
    OvisConfig,
    PinholeParams,
    PinholeRanges,
    PoseConfig,
)
from ovis.common.vision.boards import BoardSpec, MarkerView, find_board
from ovis.common.vision.boards import board_points as printed_corners

__all__ = [
    "MIN_POINTS",
    "BoardPlacement",
    "FloorPoseError",
    "MarkerSpec",
    "MarkersFile",
    "PlacedBoard",
    "board_floor_xy",
    "board_points",
    "check_image_size",
    "known_lens_config",
    "load_markers",
    "marker_points",
    "place_board",
    "solve_floor_pose",
]

#: Fewest pixel-known points: 4 give a unique pose for points on a plane.
MIN_POINTS = 4
#: Points closer than this to a line (as a fraction of their spread) count as collinear.
COLLINEAR_TOLERANCE = 1e-3
#: The residual (px) counted for a point a trial lens does not project (keeps the focal
#: length search finite).
_NO_FIT_PX = 1e6
#: How far the measured distance between a placed board's two corners may be from the
#: board's own: this share of it, and at least PLACEMENT_TOLERANCE_CM (a tape's reading
#: of two points; a wrong corner or a wrong --square-cm is far beyond).
PLACEMENT_TOLERANCE = 0.02
PLACEMENT_TOLERANCE_CM = 0.5


class FloorPoseError(ValueError):
    """Points or files that cannot give a floor pose; the message says what to fix."""


def check_image_size(intr: CameraIntrinsics, width: int, height: int, what: str) -> None:
    """The image must be the size the intrinsics were calibrated at."""
    if (intr.width, intr.height) != (width, height):
        raise FloorPoseError(
            f"{what} is {width}x{height} but the intrinsics are for {intr.width}x"
            f"{intr.height}; calibrate the lens at the size the camera delivers"
        )


def _spread_rank(xy: NDArray[np.float64]) -> bool:
    """Whether 2-D points span a plane (not all on one line or at one place)."""
    centred = xy - xy.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return bool(s[0] > 0 and s[-1] > COLLINEAR_TOLERANCE * s[0])


def _validate(points: Sequence[ControlPoint], width: int, height: int) -> None:
    unknown = [p.name for p in points if not p.pixel_known]
    if unknown:
        raise FloorPoseError(
            f"control point(s) {', '.join(unknown)} have no row, col: with known intrinsics "
            "give every point's pixel, or use blob points with [calibration.pinhole] pose ranges"
        )
    if len(points) < MIN_POINTS:
        raise FloorPoseError(
            f"a floor pose needs at least {MIN_POINTS} points with known pixels, got {len(points)}"
        )
    outside = [
        f"{p.name} ({p.row:g}, {p.col:g})"
        for p in points
        if not (0 <= p.row <= height - 1 and 0 <= p.col <= width - 1)  # type: ignore[operator]
    ]
    if outside:
        raise FloorPoseError(
            f"point(s) {', '.join(outside)} lie outside the {width}x{height} image "
            f"(row 0..{height - 1}, col 0..{width - 1})"
        )
    xyz = np.array([[p.x_cm, p.y_cm, p.z_cm] for p in points])
    pix = np.array([[p.col, p.row] for p in points], dtype=np.float64)
    if not _spread_rank(xyz[:, :2]) and np.ptp(xyz[:, 2]) == 0:
        raise FloorPoseError(
            "the control points lie on one line on the floor: a pose needs points spread "
            "over an area (e.g. the four corners of a board)"
        )
    if not _spread_rank(pix):
        raise FloorPoseError("the control points' pixels lie on one line in the image")
    for a in range(len(points)):
        d = np.linalg.norm(xyz[a + 1 :] - xyz[a], axis=1)
        if np.any(d == 0):
            b = a + 1 + int(np.argmin(d))
            raise FloorPoseError(
                f"points {points[a].name} and {points[b].name} are at the same place"
            )


def _pose(
    xyz: NDArray[np.float64], pix: NDArray[np.float64], intr: CameraIntrinsics
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """solvePnP (IPPE on a plane, SQPnP otherwise) then solvePnPRefineLM."""
    K, D = intr.matrix, intr.coefficients
    planar = np.ptp(xyz[:, 2]) == 0
    flag = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
    # IPPE solves for points on the plane z = 0: points on another level plane are
    # lowered onto it, and the pose lifted back (p_cam = R·(p − z0·e_z) + t)
    z0 = float(xyz[0, 2]) if planar else 0.0
    ok, rvec, tvec = cv2.solvePnP(xyz - [0.0, 0.0, z0], pix, K, D, flags=flag)
    if not ok:
        raise FloorPoseError("OpenCV found no camera pose for these points")
    tvec = tvec - z0 * cv2.Rodrigues(rvec)[0][:, 2:3]
    rvec, tvec = cv2.solvePnPRefineLM(xyz, pix, K, D, rvec, tvec)
    return rvec.ravel(), tvec.ravel()


def _camera(intr: CameraIntrinsics, rvec, tvec, pitch: float | None) -> PinholeParams:
    return with_pose(intr, tuple(rvec), tuple(tvec), pixel_pitch_mm=pitch)


def _point_fields(p: ControlPoint, predicted_row: float, predicted_col: float) -> dict:
    """The fields a residual record shares: where the point is, seen and predicted."""
    return {
        "name": p.name,
        "x_cm": p.x_cm,
        "y_cm": p.y_cm,
        "z_cm": p.z_cm,
        "detected_row": float(p.row),  # type: ignore[arg-type]
        "detected_col": float(p.col),  # type: ignore[arg-type]
        "predicted_row": float(predicted_row),
        "predicted_col": float(predicted_col),
    }


def _held_out_point(p: ControlPoint, cam: PinholeParams, in_sample: float | None) -> HeldOutPoint:
    xyz = np.array([[p.x_cm, p.y_cm, p.z_cm]])
    pix = np.array([[p.col, p.row]], dtype=np.float64)
    pred, px = _projected(xyz, pix, cam)
    return HeldOutPoint(
        **_point_fields(p, float(pred.row[0]), float(pred.col[0])),
        error_px=float(px[0]),
        error_cm=_floor_errors(pix, xyz, cam)[0],
        in_sample_px=in_sample,
    )


def _projected(
    xyz: NDArray[np.float64], pix: NDArray[np.float64], cam: PinholeParams
) -> tuple[Projection, NDArray[np.float64]]:
    """Where ``cam`` projects the points, and each point's pixel (col, row) distance from
    its projection (inf where it does not project)."""
    pred = project(xyz[:, 0], xyz[:, 1], xyz[:, 2], cam)
    d = np.hypot(pix[:, 1] - pred.row, pix[:, 0] - pred.col)
    return pred, np.where(pred.valid, d, np.inf)


def _residuals(
    xyz: NDArray[np.float64], pix: NDArray[np.float64], cam: PinholeParams
) -> NDArray[np.float64]:
    """Each point's pixel distance from its projection (inf where it does not project)."""
    return _projected(xyz, pix, cam)[1]


def _leave_one_out(
    points: Sequence[ControlPoint],
    xyz: NDArray[np.float64],
    pix: NDArray[np.float64],
    intr: CameraIntrinsics,
    in_sample: NDArray[np.float64],
) -> tuple[HeldOut, NDArray[np.float64]] | None:
    """Each point held out in turn (needs MIN_POINTS others); also the others' sum of
    squared residuals (px²) under each refit, for the outlier test of
    :mod:`ovis.common.calibration.lens_check`."""
    n = len(points)
    if n <= MIN_POINTS:
        return None
    held: list[HeldOutPoint] = []
    rest_ssr = np.empty(n)
    for i in range(n):
        use = np.arange(n) != i
        rvec, tvec = _pose(xyz[use], pix[use], intr)
        cam = _camera(intr, rvec, tvec, None)
        held.append(_held_out_point(points[i], cam, float(in_sample[i])))
        rest_ssr[i] = float(np.sum(np.square(_residuals(xyz[use], pix[use], cam))))
    px = np.array([h.error_px for h in held])
    cm = np.array([h.error_cm for h in held if h.error_cm is not None])
    return HeldOut(
        method="leave-one-out",
        source=f"{n} pixel-known points, the pose refitted without each (solvePnP + LM)",
        points=held,
        mean_px=float(px.mean()),
        max_px=float(px.max()),
        mean_cm=float(cm.mean()) if cm.size else None,
        max_cm=float(cm.max()) if cm.size else None,
    ), rest_ssr


def _refit(
    xyz: NDArray[np.float64], pix: NDArray[np.float64], intr: CameraIntrinsics
) -> NDArray[np.float64]:
    """The residuals of the pose refitted with the lens ``intr``."""
    try:
        rvec, tvec = _pose(xyz, pix, intr)
    except (FloorPoseError, cv2.error):
        return np.full(len(xyz), np.inf)
    return _residuals(xyz, pix, _camera(intr, rvec, tvec, None))


def _scaled_focal(intr: CameraIntrinsics, scale: float) -> CameraIntrinsics:
    K = intr.matrix
    K[0, 0] *= scale
    K[1, 1] *= scale
    return msgspec.structs.replace(intr, camera_matrix=tuple(map(tuple, K.tolist())))


def _lens_alternatives(
    xyz: NDArray[np.float64], pix: NDArray[np.float64], intr: CameraIntrinsics
) -> list[tuple[str, NDArray[np.float64], int]]:
    """The pose refitted with the lens file's distortion left out, and with the best
    single scale on its focal length (a bounded search over ¼×..4×): what each change
    was, the residuals, their degrees of freedom."""
    from scipy.optimize import minimize_scalar

    n = len(xyz)
    plain = msgspec.structs.replace(intr, dist=(0.0,) * 5)

    def ssr(log_scale: float) -> float:
        r = _refit(xyz, pix, _scaled_focal(intr, math.exp(log_scale)))
        return float(np.sum(np.square(np.minimum(r, _NO_FIT_PX))))

    best = minimize_scalar(ssr, bounds=(math.log(0.25), math.log(4.0)), method="bounded")
    scale = math.exp(float(best.x))
    focal = _scaled_focal(intr, scale)
    return [
        ("with its distortion left out", _refit(xyz, pix, plain), 2 * n - 6),
        (
            f"with its focal length ×{scale:.3g} (fx {focal.matrix[0, 0]:.1f} px)",
            _refit(xyz, pix, focal),
            2 * n - 7,
        ),
    ]


def solve_floor_pose(
    intr: CameraIntrinsics,
    points: Sequence[ControlPoint],
    *,
    image_size: tuple[int, int],
    image: ImageParams | None = None,
    pose: PoseConfig | None = None,
    pixel_pitch_mm: float | None = None,
    source: str = "",
    point_px: float = CLICK_PX,
    lens_name: str = "the intrinsics file",
    frame: str | None = None,
) -> Calibration:
    """The calibration of a camera with lens ``intr`` from pixel-known ``points`` seen in an
    image of ``image_size`` (width, height), judged against what the lens and the points'
    pixel precision ``point_px`` (RMS, px) explain (``accuracy.lens``, see
    :mod:`ovis.common.calibration.lens_check`); ``frame`` says what the points' floor
    frame rests on (the first of the report's notes). See the module docstring."""
    t0 = time.perf_counter()
    check_image_size(intr, *image_size, "the image")
    _validate(points, *image_size)
    xyz = np.array([[p.x_cm, p.y_cm, p.z_cm] for p in points], dtype=np.float64)
    pix = np.array([[p.col, p.row] for p in points], dtype=np.float64)
    rvec, tvec = _pose(xyz, pix, intr)
    cam = _camera(intr, rvec, tvec, pixel_pitch_mm)
    pred, px = _projected(xyz, pix, cam)
    if not np.all(pred.valid):
        raise FloorPoseError("the pose found puts control points behind the camera")
    pitch = cam.d_x_mm
    residuals = [
        PointResidual(
            **_point_fields(p, pred.row[i], pred.col[i]),
            dipe_px=float(px[i]),
            dipe_mm=mm_or_none(px[i] * pitch),
        )
        for i, p in enumerate(points)
    ]
    loo = _leave_one_out(points, xyz, pix, intr, px)
    notes = [] if frame is None else [frame]
    if loo is None:
        notes.append(f"leave-one-out needs more than {MIN_POINTS} points (got {len(points)})")
    lens = pose_check(
        names=[p.name for p in points],
        residuals_px=px,
        residuals_cm=_floor_errors(pix, xyz, cam),
        lens=intr,
        cam=cam,
        point_px=point_px,
        rest_ssr=None if loo is None else loo[1],
        held_out=None if loo is None else [(h.error_px, h.error_cm) for h in loo[0].points],
        alternatives=functools.partial(_lens_alternatives, xyz, pix, intr),
        what=lens_name,
    )
    return Calibration(
        created=now_iso(),
        dipe_px=float(px.mean()),
        dipe_mm=mm_or_none(px.mean() * pitch),
        dipe_max_px=float(px.max()),
        dipe_max_mm=mm_or_none(px.max() * pitch),
        camera=cam,
        image=image or ImageParams(),
        pose=pose or PoseConfig(),
        points=residuals,
        elapsed_s=time.perf_counter() - t0,
        source_image=source,
        accuracy=AccuracyReport(
            leave_one_out=None if loo is None else loo[0], notes=notes, lens=lens
        ),
    )


def _floor_errors(
    pix: NDArray[np.float64], xyz: NDArray[np.float64], cam: PinholeParams
) -> list[float | None]:
    """Each point's pixel (col, row) back-projected onto its plane vs. its position (cm);
    None where it does not reach the plane."""
    b = back_project(pix[:, 1], pix[:, 0], cam, xyz[:, 2])
    err = np.hypot(b.x_cm - xyz[:, 0], b.y_cm - xyz[:, 1])
    return [float(e) if ok else None for e, ok in zip(err, b.valid, strict=True)]


def board_floor_xy(spec: BoardSpec) -> NDArray[np.float64]:
    """(N, 2) floor positions of a board's inner corners (OpenCV's corner order) in the
    board's own floor frame: its first inner corner at the origin, x along its first row,
    z up to the camera, so y points away from its other rows (corner i of row j of a
    chessboard at ``(i·S, −j·S)``); in the board's unit (cm)."""
    return printed_corners(spec)[:, :2].astype(np.float64) * (1.0, -1.0)


class BoardPlacement(msgspec.Struct, frozen=True, kw_only=True):
    """Where a board lying face up on the floor lies in the arena, as a tape measures it:
    the arena floor positions (cm) of its origin corner (its first inner corner) and of
    the last inner corner of its first row."""

    origin_cm: tuple[float, float]
    row_end_cm: tuple[float, float]

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (*self.origin_cm, *self.row_end_cm)):
            raise ValueError("a board's placement must be finite positions in cm")


def _row_end_index(spec: BoardSpec) -> int:
    """The index of the last inner corner of a board's first row."""
    return spec.cols - 1 if spec.kind == "chessboard" else spec.cols - 2


class PlacedBoard(NamedTuple):
    """The rigid motion of the floor taking a board's floor frame to the arena's,
    ``arena = rotation · board + shift`` (cm), and one line saying what it rests on."""

    rotation: NDArray[np.float64]
    shift: NDArray[np.float64]
    note: str

    def arena(self, board_xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) arena positions of points given in the board's floor frame."""
        return board_xy @ self.rotation.T + self.shift


def place_board(spec: BoardSpec, placement: BoardPlacement) -> PlacedBoard:
    """Where the board's floor frame (:func:`board_floor_xy`) lies in the arena's: its two
    measured corners fitted in the least-squares sense (their midpoint on the measured
    one, the first row along the measured direction).

    Raises FloorPoseError for a board whose pattern does not fix its origin corner (a
    chessboard looking the same turned half-way round) and for measured corners whose
    distance is not the board's (:data:`PLACEMENT_TOLERANCE`)."""
    if not spec.oriented:
        raise FloorPoseError(
            f"{spec.describe()} looks the same turned half-way round, so which corner is its "
            "origin depends on the camera's view: place a board with one odd and one even "
            "count of inner corners (e.g. chessboard:9x6) or a ChArUco board"
        )
    xy = board_floor_xy(spec)
    board = np.array([xy[0], xy[_row_end_index(spec)]])
    measured = np.array([placement.origin_cm, placement.row_end_cm], dtype=np.float64)
    d_board, d_measured = board[1] - board[0], measured[1] - measured[0]
    length, apart = float(np.hypot(*d_board)), float(np.hypot(*d_measured))
    allowed = max(PLACEMENT_TOLERANCE * length, PLACEMENT_TOLERANCE_CM)
    if abs(apart - length) > allowed:
        raise FloorPoseError(
            f"the board's origin corner and the end of its first row are {apart:.2f} cm apart "
            f"as placed, but {length:.2f} cm on the board ({spec.describe()}, "
            f"{spec.square:g} cm squares; at most {allowed:.2f} cm off): check the two "
            "measured corners (the origin is the first inner corner, docs/real-camera.md) "
            "and --square-cm"
        )
    turn = math.atan2(d_measured[1], d_measured[0]) - math.atan2(d_board[1], d_board[0])
    c, s = math.cos(turn), math.sin(turn)
    R = np.array([[c, -s], [s, c]])
    t = measured.mean(axis=0) - R @ board.mean(axis=0)
    o, e = placement.origin_cm, placement.row_end_cm
    note = (
        f"floor frame: the arena's; {spec.describe()}'s origin corner placed at "
        f"({o[0]:g}, {o[1]:g}) cm and its first row's last inner corner at ({e[0]:g}, "
        f"{e[1]:g}) cm, {apart:.2f} cm apart as measured ({length:.2f} cm on the board)"
    )
    return PlacedBoard(R, t, note)


def board_points(
    gray: NDArray[np.uint8], spec: BoardSpec, placed: PlacedBoard | None = None
) -> list[ControlPoint]:
    """Every corner of a board lying on the floor as a pixel-known control point: in the
    board's own floor frame (:func:`board_floor_xy`), or in the arena's where the board
    is ``placed`` (:func:`place_board`)."""
    xy = board_floor_xy(spec)
    if placed is not None:
        xy = placed.arena(xy)
    view = find_board(gray, spec)
    if view is None:
        raise FloorPoseError(
            f"{spec.describe()} not found in the image: check the board size (inner corners "
            "of a chessboard) and that the whole board is in view"
        )
    return [
        ControlPoint(
            name=f"corner{int(i)}",
            x_cm=float(xy[i, 0]) + 0.0,
            y_cm=float(xy[i, 1]) + 0.0,
            z_cm=0.0,
            row=float(p[1]),
            col=float(p[0]),
        )
        for i, p in zip(view.ids, view.image_xy, strict=True)
    ]


class MarkerSpec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """One ArUco marker taped on the floor: its id, centre, side and turn.

    Corners (as ``cv2.aruco`` orders them: top-left, top-right, bottom-right, bottom-left
    of the printed marker) lie at ``centre + R(angle)·(±side/2, ±side/2)``: with
    ``angle_deg = 0`` the printed marker's rightward edge runs along the floor's +x and
    its upward edge along +y (z up to the camera); ``angle_deg`` turns it CCW.
    """

    id: int
    x_cm: float
    y_cm: float
    side_cm: float
    z_cm: float = 0.0
    angle_deg: float = 0.0

    def __post_init__(self) -> None:
        values = (self.x_cm, self.y_cm, self.z_cm, self.side_cm, self.angle_deg)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"marker {self.id}: positions, side and angle must be finite")
        if self.side_cm <= 0:
            raise ValueError(f"marker {self.id}: side_cm must be positive")


class MarkersFile(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """``--markers`` file: the ArUco dictionary and the surveyed markers."""

    dictionary: str
    markers: list[MarkerSpec]

    def __post_init__(self) -> None:
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ValueError(f"marker ids must be unique, got {ids}")


def load_markers(path: Path | str) -> MarkersFile:
    """Read and validate a markers TOML file."""
    import tomllib

    try:
        data = tomllib.loads(Path(path).read_text("utf-8"))
        return msgspec.convert(data, MarkersFile)
    except FileNotFoundError:
        raise FloorPoseError(f"markers file {path} does not exist") from None
    except (tomllib.TOMLDecodeError, msgspec.ValidationError, UnicodeDecodeError) as exc:
        raise FloorPoseError(
            f'markers file {path}: {exc}. Expected dictionary = "DICT_4X4_50" and '
            "[[markers]] tables with id, x_cm, y_cm, side_cm (optional z_cm, angle_deg)"
        ) from None


def marker_points(found: MarkerView, markers: MarkersFile) -> list[ControlPoint]:
    """The four corners of every surveyed marker found, as pixel-known control points."""
    survey = {m.id: m for m in markers.markers}
    half = np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]], dtype=np.float64) / 2
    points: list[ControlPoint] = []
    for marker_id, corners in zip(found.ids.tolist(), found.corners_xy, strict=True):
        m = survey.get(marker_id)
        if m is None:
            continue
        a = math.radians(m.angle_deg)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        world = half * m.side_cm @ rot.T + (m.x_cm, m.y_cm)
        for k, ((x, y), (c, r)) in enumerate(zip(world, corners, strict=True)):
            points.append(
                ControlPoint(
                    name=f"m{marker_id}.{'abcd'[k]}",
                    x_cm=float(x),
                    y_cm=float(y),
                    z_cm=m.z_cm,
                    row=float(r),
                    col=float(c),
                )
            )
    if not points:
        raise FloorPoseError(
            f"none of the surveyed markers ({', '.join(str(m.id) for m in markers.markers)}) "
            f"is in the image (dictionary {markers.dictionary})"
        )
    return points


def known_lens_config(config: OvisConfig, intr: CameraIntrinsics) -> OvisConfig:
    """The configuration for a GA calibration of blob control points with the lens fixed:
    a pinhole camera with ``intr``'s K and distortion, only the pose (the
    ``[calibration.pinhole]`` rvec/tvec ranges) and the threshold and size filter free,
    as in the paper's single-step GA."""
    ranges = config.calibration.pinhole or PinholeRanges()
    lens = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    pose_free = [n for n in PINHOLE_VARIABLES if n not in lens and getattr(ranges, n)]
    if not pose_free:
        raise FloorPoseError(
            "blob control points with known intrinsics need the pose's search ranges: set "
            "[calibration.pinhole] rvec_x..z and tvec_x_cm..z_cm in --config, or give the "
            "points' pixels (row, col), --board or --markers instead"
        )
    old = config.camera
    pose = {"rvec": old.rvec, "tvec_cm": old.tvec_cm} if isinstance(old, PinholeParams) else {}
    pitch = old.pixel_pitch_mm if isinstance(old, PinholeParams) else None
    camera = with_pose(intr, pixel_pitch_mm=pitch, **pose)
    fixed = msgspec.structs.replace(ranges, **dict.fromkeys(lens))
    calibration = msgspec.structs.replace(config.calibration, pinhole=fixed)
    return msgspec.structs.replace(config, camera=camera, calibration=calibration)

"""A lens's intrinsics from photos of a board: OpenCV's detectors and ``calibrateCamera``.

The images must share one size: the size most of them have is kept and the others are
rejected unread, by name (one odd file never decides the size for the rest). Each
view's board corners come from :func:`ovis.common.vision.boards.find_board` (a
chessboard's refined in a window half its smallest square wide); views
where the board is not found are rejected, by name and reason. ``cv2.calibrateCameraExtended``
(five distortion coefficients, no flags: OpenCV's defaults) gives K, the distortion, the
overall RMS reprojection error and each view's. A view whose RMS is above
:data:`OUTLIER_FACTOR` × the median view's (and above :data:`OUTLIER_FLOOR_PX`) is flagged
as an outlier (a blurred photo, a bent board, a wrong detection); with ``drop_outliers``
the calibration is run again without them.

Coverage says whether the corners of the image were seen: the image is cut into a
:data:`COVERAGE_GRID` grid and a cell is covered when a corner of any used view falls in
it. The distortion is only measured where corners were seen, so uncovered image corners
mean an extrapolated lens model there; one that folds back inside the image is named in
the report's warnings.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.calibration.lens_check import distortion_problems
from ovis.common.camera.intrinsics import CameraIntrinsics
from ovis.common.vision.boards import BoardSpec, BoardView, find_board
from ovis.common.vision.frames import as_gray

__all__ = [
    "COVERAGE_GRID",
    "Coverage",
    "FoundView",
    "IntrinsicsError",
    "IntrinsicsReport",
    "RejectedView",
    "ViewResult",
    "calibrate_intrinsics",
    "common_size",
    "corner_coverage",
    "detect_views",
    "distinct_view",
]

#: A view is an outlier when its RMS exceeds this many times the median view's ...
OUTLIER_FACTOR = 3.0
#: ... and this many pixels (sub-pixel views are never outliers).
OUTLIER_FLOOR_PX = 0.5
#: Coverage grid (columns, rows) over the image.
COVERAGE_GRID = (8, 6)
#: Fewest views with the board for a calibration (OpenCV needs several poses).
MIN_VIEWS = 3


class IntrinsicsError(ValueError):
    """Intrinsics that cannot be computed from the views given; the message says why."""


class RejectedView(msgspec.Struct, kw_only=True):
    view: str
    reason: str


class ViewResult(msgspec.Struct, kw_only=True):
    view: str
    corners: int
    rms_px: float
    outlier: bool = False
    #: side (px) of the square window cornerSubPix refined this view's corners in: twice
    #: the half window :func:`ovis.common.vision.boards.subpix_window` fits to the view's
    #: smallest square, plus one; None for ChArUco (its detector refines its own corners)
    window_px: int | None = None


class Coverage(msgspec.Struct, kw_only=True):
    """Which cells of a grid over the image hold a board corner (row-major, top first)."""

    grid_cols: int
    grid_rows: int
    covered: list[list[bool]]
    fraction: float
    image_corners_covered: int  # of the 4 corner cells of the grid


class IntrinsicsReport(msgspec.Struct, kw_only=True):
    """What ``ovis intrinsics`` prints with ``--json``."""

    board: str
    image_width: int
    image_height: int
    rms_px: float
    camera_matrix: list[list[float]]
    dist: list[float]
    views_used: list[str]
    views_rejected: list[RejectedView]
    per_view: list[ViewResult]
    outliers: list[str]
    outliers_dropped: bool
    coverage: Coverage
    #: what makes the lens doubtful beyond its RMS (a distortion that folds back inside
    #: the image: :func:`ovis.common.calibration.lens_check.distortion_problems`)
    warnings: list[str] = []

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics(
            width=self.image_width,
            height=self.image_height,
            camera_matrix=tuple(tuple(r) for r in self.camera_matrix),
            dist=tuple(self.dist),
            rms_px=self.rms_px,
        )


class FoundView(NamedTuple):
    """A view with the board: its name and corners."""

    name: str
    view: BoardView


def common_size(
    images: Sequence[tuple[str, NDArray[np.uint8]]],
) -> tuple[tuple[int, int], list[tuple[str, tuple[int, int]]]]:
    """The size (width, height) most images share (a tie: the one seen first) and the
    others' names and sizes: one odd file must not decide the size for the rest."""
    sizes = [(name, (image.shape[1], image.shape[0])) for name, image in images]
    if not sizes:
        raise IntrinsicsError("no images given")
    counts = Counter(size for _, size in sizes)
    best = max(counts.values())
    size = next(s for _, s in sizes if counts[s] == best)
    return size, [(name, s) for name, s in sizes if s != size]


def detect_views(
    images: Iterable[tuple[str, NDArray[np.uint8]]],
    spec: BoardSpec,
    *,
    on_view: Callable[[str, bool], None] | None = None,
    on_skipped: Callable[[list[tuple[str, tuple[int, int]]], tuple[int, int]], None] | None = None,
) -> tuple[list[FoundView], list[RejectedView], tuple[int, int]]:
    """Find the board in each (name, image) of the size most of them share
    (:func:`common_size`); the others are rejected unread (``on_skipped`` hears of them
    once, with the size kept).

    Returns the views with the board, the rejected ones (why) and the size (width, height).
    """
    images = list(images)
    size, odd = common_size(images)
    if odd and on_skipped:
        on_skipped(odd, size)
    found: list[FoundView] = []
    rejected: list[RejectedView] = []
    for name, image in images:
        h, w = image.shape[:2]
        if (w, h) != size:
            reason = f"image is {w}x{h}, most of the images are {size[0]}x{size[1]}: skipped"
            rejected.append(RejectedView(view=name, reason=reason))
            continue
        view = find_board(as_gray(image), spec)
        if view is None:
            reason = f"{spec.describe()} not found"
            rejected.append(RejectedView(view=name, reason=reason))
        else:
            found.append(FoundView(name, view))
        if on_view:
            on_view(name, view is not None)
    return found, rejected, size


def distinct_view(view: BoardView, kept: list[BoardView], min_shift_px: float) -> bool:
    """Whether ``view`` differs from every kept view: its common corners moved by more than
    ``min_shift_px`` on average (a camera stream repeats nearly the same view)."""
    for other in kept:
        common, a, b = np.intersect1d(view.ids, other.ids, return_indices=True)
        if common.size == 0:
            continue
        shift = np.linalg.norm(view.image_xy[a] - other.image_xy[b], axis=1).mean()
        if shift < min_shift_px:
            return False
    return True


def corner_coverage(
    views: Iterable[BoardView], size: tuple[int, int], grid: tuple[int, int] = COVERAGE_GRID
) -> Coverage:
    """Cells of a ``grid`` (cols, rows) over an image of ``size`` (width, height) holding
    a corner of any view."""
    gc, gr = grid
    covered = np.zeros((gr, gc), dtype=bool)
    for v in views:
        c = np.clip((v.image_xy[:, 0] / size[0] * gc).astype(int), 0, gc - 1)
        r = np.clip((v.image_xy[:, 1] / size[1] * gr).astype(int), 0, gr - 1)
        covered[r, c] = True
    corners = int(covered[0, 0]) + int(covered[0, -1]) + int(covered[-1, 0]) + int(covered[-1, -1])
    return Coverage(
        grid_cols=gc,
        grid_rows=gr,
        covered=covered.tolist(),
        fraction=float(covered.mean()),
        image_corners_covered=corners,
    )


def _calibrate(views: list[FoundView], size: tuple[int, int]):
    obj = [f.view.board_xyz for f in views]
    img = [f.view.image_xy.reshape(-1, 1, 2) for f in views]
    rms, K, D, _, _, _, _, per_view = cv2.calibrateCameraExtended(obj, img, size, None, None)
    return float(rms), K, D.ravel(), per_view.ravel()


def calibrate_intrinsics(
    images: Iterable[tuple[str, NDArray[np.uint8]]] | None,
    spec: BoardSpec,
    *,
    views: tuple[list[FoundView], list[RejectedView], tuple[int, int]] | None = None,
    drop_outliers: bool = False,
    on_view: Callable[[str, bool], None] | None = None,
) -> IntrinsicsReport:
    """Calibrate K and distortion from named images of ``spec`` (or already detected
    ``views``, as :func:`detect_views` returns them). See the module docstring."""
    found, rejected, size = (
        views if views is not None else detect_views(images or [], spec, on_view=on_view)
    )
    if len(found) < MIN_VIEWS:
        names = ", ".join(r.view for r in rejected) or "none"
        raise IntrinsicsError(
            f"{spec.describe()} found in {len(found)} view(s), at least {MIN_VIEWS} are needed "
            f"(rejected: {names}); check the board size (inner corners) and take more photos"
        )
    rms, K, D, per_view = _calibrate(found, size)
    median = float(np.median(per_view))
    outlier = (per_view > OUTLIER_FACTOR * median) & (per_view > OUTLIER_FLOOR_PX)
    dropped = bool(drop_outliers and outlier.any() and (~outlier).sum() >= MIN_VIEWS)
    results = [
        ViewResult(
            view=f.name,
            corners=len(f.view.ids),
            rms_px=float(e),
            outlier=bool(o),
            window_px=None if f.view.window_px is None else 2 * f.view.window_px + 1,
        )
        for f, e, o in zip(found, per_view, outlier, strict=True)
    ]
    used = found
    if dropped:
        used = [f for f, o in zip(found, outlier, strict=True) if not o]
        rms, K, D, per_view = _calibrate(used, size)
        errors = dict(zip((f.name for f in used), per_view, strict=True))
        for r in results:
            if r.view in errors:
                r.rms_px = float(errors[r.view])
    report = IntrinsicsReport(
        board=spec.describe(),
        image_width=size[0],
        image_height=size[1],
        rms_px=rms,
        camera_matrix=K.tolist(),
        dist=[float(v) for v in np.concatenate([D, np.zeros(5)])[:5]],
        views_used=[f.name for f in used],
        views_rejected=rejected,
        per_view=results,
        outliers=[r.view for r in results if r.outlier],
        outliers_dropped=dropped,
        coverage=corner_coverage((f.view for f in used), size),
    )
    report.warnings = distortion_problems(report.intrinsics(), "this lens")
    return report

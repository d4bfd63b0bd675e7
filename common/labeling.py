"""Connected-component labeling and per-object moments (paper §3, "Labeling").

"All spatially close pixels of a binary image having value 1 are grouped into connected
components" (paper §3, after Kim et al. 2004). Here the grouping is 8-connected and done
by ``cv2.connectedComponentsWithStats``; area, sub-pixel centroid, bounding box and the
central second moments of every component are then read off in one pass.

Coordinates: pixel ``(i, j)`` has its centre at ``row = i``, ``col = j``. Moments treat
every pixel as a unit point mass at its centre (no 1/12 pixel-extent term), so a single
pixel has zero second moments.

The size filter of paper §3 is :func:`filter_components` with a mask built from
``area_px`` (converted to cm² with the calibrated pixel footprint by the caller).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.preprocess import ImageError

__all__ = ["Components", "filter_components", "label_components"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False, slots=True)
class Components:
    """Labeled 8-connected components of a binary image and their per-object statistics.

    Component ``k`` (``k = 1 … count``) is the set of pixels where ``labels == k``; 0 is
    the background. Every per-component array has shape ``(count,)`` and entry ``k - 1``
    describes component ``k``.

    Attributes
    ----------
    labels : (H, W) int32 array
        Label image; 0 = background, components numbered 1 … ``count``.
    count : int
        Number of components n.
    area_px : (n,) float64 array
        Pixel count.
    row, col : (n,) float64 arrays
        Centroid, the mean of the pixel-centre row / column indices.
    top, left, height, width : (n,) int64 arrays
        Bounding box: rows ``top … top + height - 1``, columns ``left … left + width - 1``.
    mu_rr, mu_cc, mu_rc : (n,) float64 arrays
        Central second moments divided by the area:
        ``mu_rr = mean((r - row)²)``, ``mu_cc = mean((c - col)²)``,
        ``mu_rc = mean((r - row)·(c - col))``.
    """

    labels: NDArray[np.int32]
    count: int
    area_px: FloatArray
    row: FloatArray
    col: FloatArray
    top: IntArray
    left: IntArray
    height: IntArray
    width: IntArray
    mu_rr: FloatArray
    mu_cc: FloatArray
    mu_rc: FloatArray


def label_components(binary: NDArray[np.uint8] | NDArray[np.bool_]) -> Components:
    """Label the 8-connected components of a binary image and measure them.

    Parameters
    ----------
    binary : (H, W) uint8 or bool array
        Object pixels are the non-zero ones (the output of
        :func:`ovis.common.preprocess.binarize`).

    Returns
    -------
    Components
        Labels are numbered in OpenCV's scan order (its block-based algorithms visit
        2×2 blocks, so this is not strictly the row-by-row order of first pixels);
        callers must not rely on the order.

    Raises
    ------
    ImageError
        If ``binary`` is not a non-empty 2-D uint8 or bool array.

    Notes
    -----
    Moments come from ``cv2.moments`` on each component's bounding-box crop: on a
    640×480 frame with ~10 blobs this is ~20× faster than ``np.bincount`` over the
    whole label image, and still faster with a few hundred noise specks. The loop runs
    over components, never over pixels.
    """
    if (
        not isinstance(binary, np.ndarray)
        or binary.ndim != 2
        or binary.size == 0
        or binary.dtype not in (np.uint8, np.bool_)
    ):
        shape = (binary.shape, binary.dtype) if isinstance(binary, np.ndarray) else binary
        raise ImageError(f"binary: expected a non-empty 2-D uint8 or bool image, got {shape!r}")
    image = binary.view(np.uint8) if binary.dtype == np.bool_ else binary
    n_with_bg, labels, stats, _ = cv2.connectedComponentsWithStats(
        np.ascontiguousarray(image), connectivity=8, ltype=cv2.CV_32S
    )
    n = n_with_bg - 1
    stats = stats[1:].astype(np.int64)
    left = stats[:, cv2.CC_STAT_LEFT]
    top = stats[:, cv2.CC_STAT_TOP]
    width = stats[:, cv2.CC_STAT_WIDTH]
    height = stats[:, cv2.CC_STAT_HEIGHT]
    area = stats[:, cv2.CC_STAT_AREA].astype(np.float64)

    # Per component: [m01, m10, mu02, mu20, mu11] of the crop (cv2: x = col, y = row).
    sums = np.empty((n, 5), dtype=np.float64)
    for k in range(n):
        t, lf, h, w = top[k], left[k], height[k], width[k]
        mask = (labels[t : t + h, lf : lf + w] == k + 1).view(np.uint8)
        m = cv2.moments(mask, binaryImage=True)
        sums[k] = (m["m01"], m["m10"], m["mu02"], m["mu20"], m["mu11"])
    area_safe = np.maximum(area, 1.0)
    return Components(
        labels=labels,
        count=n,
        area_px=area,
        row=top + sums[:, 0] / area_safe,
        col=left + sums[:, 1] / area_safe,
        top=top,
        left=left,
        height=height,
        width=width,
        mu_rr=sums[:, 2] / area_safe,
        mu_cc=sums[:, 3] / area_safe,
        mu_rc=sums[:, 4] / area_safe,
    )


def filter_components(components: Components, keep_mask: NDArray[np.bool_]) -> Components:
    """Keep a subset of the components (e.g. the size filter of paper §3).

    Parameters
    ----------
    components : Components
    keep_mask : (n,) bool array
        ``True`` for the components to keep, in label order.

    Returns
    -------
    Components
        The kept components renumbered 1 … m in their original order; the label image is
        relabeled to match (dropped components become background 0) with one lookup-table
        pass, so ``labels == k`` is component ``k`` of the result.
    """
    keep = np.asarray(keep_mask)
    if keep.dtype != np.bool_ or keep.shape != (components.count,):
        raise ValueError(
            f"keep_mask: expected a bool array of shape ({components.count},), "
            f"got shape {keep.shape} {keep.dtype}"
        )
    lut = np.zeros(components.count + 1, dtype=np.int32)
    lut[1:][keep] = np.arange(1, int(keep.sum()) + 1, dtype=np.int32)
    c = components
    return Components(
        labels=lut[c.labels],
        count=int(keep.sum()),
        area_px=c.area_px[keep],
        row=c.row[keep],
        col=c.col[keep],
        top=c.top[keep],
        left=c.left[keep],
        height=c.height[keep],
        width=c.width[keep],
        mu_rr=c.mu_rr[keep],
        mu_cc=c.mu_cc[keep],
        mu_rc=c.mu_rc[keep],
    )

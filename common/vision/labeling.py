"""Connected-component labeling and per-object moments (paper §3, "Labeling").

"All spatially close pixels of a binary image having value 1 are grouped into connected
components" (paper §3, after Kim et al. 2004). Here the grouping is 8-connected and
contour-based: one ``cv2.findContours`` (``RETR_CCOMP``) traces the outer border of every
8-connected component and the borders of its holes in a single raster scan, and every
statistic comes from those border chains — no pass over the object pixels, so the cost
after the scan grows with the length of the borders, not with the area of the objects,
and one vectorised pass over all chains serves every object at once.

Area, centroid and second moments are exact pixel sums, by the discrete Green's theorem
(Tang 1982; Yang & Albregtsen 1996): a component's pixels in one row are runs
``[a, b]``, and ``Σ_{j=a..b} f(j) = G(b) − G(a − 1)`` with ``G(x) = Σ_{j≤x} f(j)``. The
run ends are the border pixels whose right (left) neighbour is background, and border
following sweeps every such pixel side exactly once: at each visit of a chain it turns
from the previous chain point to the next one through background neighbours only
(Suzuki & Abe 1985, the tracer of ``cv2.findContours``). So each visit adds ``G(x)`` if
its right neighbour is swept and subtracts ``G(x − 1)`` if its left one is, for
``f ∈ {1, col, row, col², row², col·row}``; hole borders do the same on the inner side.

Coordinates: pixel ``(i, j)`` has its centre at ``row = i``, ``col = j``. Moments treat
every pixel as a unit point mass at its centre (no 1/12 pixel-extent term), so a single
pixel has zero second moments.

The size filter of paper §3 is :func:`filter_components` with a mask built from
``area_px`` (converted to cm² with the calibrated pixel footprint by the caller).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.frames import ImageError

__all__ = ["Borders", "Components", "filter_components", "label_components"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Chain = NDArray[np.int32]


@dataclass(frozen=True, eq=False)
class Borders:
    """Every border chain ``cv2.findContours`` traced in a binary image, concatenated.

    Attributes
    ----------
    points : (M, 2) int32 array
        Chain points, (col, row) pixel centres, chain after chain in tracing order
        (``CHAIN_APPROX_NONE``: successive points are 8-neighbours; each chain is closed,
        its last point followed by its first).
    start, length : (b,) int64 arrays
        Where each chain begins in ``points`` and how many points it has.
    parent : (b,) int64 array
        For a hole border, the index of the outer border of its component; −1 for an
        outer border.
    code : (M,) array of ints in 0…8
        The step from each point to the next of its chain, as :func:`step_code`
        ``(Δrow + 1)·3 + (Δcol + 1)``; 4 (no step) only in a one-point chain.
    """

    points: Chain
    start: IntArray
    length: IntArray
    parent: IntArray
    code: IntArray

    def chain(self, i: int) -> Chain:
        """Border ``i`` as an (m, 2) int32 array of (col, row) points."""
        s = int(self.start[i])
        return self.points[s : s + int(self.length[i])]

    def holes(self, i: int) -> list[Chain]:
        """The hole borders of the component whose outer border is ``i``."""
        return [self.chain(int(h)) for h in np.flatnonzero(self.parent == i)]


@dataclass(frozen=True, eq=False)
class Components:
    """Labeled 8-connected components of a binary image and their per-object statistics.

    Every per-component array has shape ``(count,)``; components are in raster order of
    their first (top-most, then left-most) pixel.

    Attributes
    ----------
    shape : (H, W)
        Shape of the binary image.
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
    borders : Borders
        Every border chain of the image (outer borders, hole borders, left-out specks).
    border : (n,) int64 array
        Index in ``borders`` of each component's outer border.
    filled : (n, 3) float64 array
        Area, centroid row and column of each component with its holes filled (the
        region inside its outer border): a solid's silhouette whatever holes a marker
        or noise leaves in it.
    """

    shape: tuple[int, int]
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
    borders: Borders
    border: IntArray
    filled: FloatArray

    @property
    def outer(self) -> list[Chain]:
        """The closed 8-connected outer border chain of each component, (m, 2) int32
        (col, row) points in image coordinates."""
        return [self.borders.chain(int(i)) for i in self.border]

    @cached_property
    def labels(self) -> NDArray[np.int32]:
        """(H, W) int32 label image: 0 = background, component ``k`` (1-based) = k.

        Drawn from the border chains (outer border filled, holes cleared, hole borders
        put back): a view for people and tests, not used on the per-frame path.
        """
        out = np.zeros(self.shape, dtype=np.int32)
        for k, i in enumerate(self.border.tolist()):
            x, y, w, h = (
                int(self.left[k]),
                int(self.top[k]),
                int(self.width[k]),
                int(self.height[k]),
            )
            mask = np.zeros((h, w), np.uint8)
            at = (-x, -y)
            cv2.drawContours(mask, [self.borders.chain(i)], -1, 1, cv2.FILLED, offset=at)
            holes = self.borders.holes(i)
            if holes:
                cv2.drawContours(mask, holes, -1, 0, cv2.FILLED, offset=at)
                cv2.drawContours(mask, holes, -1, 1, 1, offset=at)
            out[y : y + h, x : x + w][mask > 0] = k + 1
        return out


def _validated(binary: NDArray[np.uint8] | NDArray[np.bool_]) -> NDArray[np.uint8]:
    if (
        not isinstance(binary, np.ndarray)
        or binary.ndim != 2
        or binary.size == 0
        or binary.dtype not in (np.uint8, np.bool_)
    ):
        shape = (binary.shape, binary.dtype) if isinstance(binary, np.ndarray) else binary
        raise ImageError(f"binary: expected a non-empty 2-D uint8 or bool image, got {shape!r}")
    image = binary.view(np.uint8) if binary.dtype == np.bool_ else binary
    return np.ascontiguousarray(image)


#: Neighbour offsets (Δcol, Δrow) in turning order around a pixel (counter-clockwise on
#: the screen, rows pointing down): E, NE, N, NW, W, SW, S, SE.
_TURN = ((1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1))
_EAST, _WEST = 0, 4


def step_code(d_col: IntArray, d_row: IntArray) -> IntArray:
    """Code ``(Δrow + 1)·3 + (Δcol + 1)`` in 0…8 of a step between 8-neighbours (4: none)."""
    return (d_row + 1) * 3 + (d_col + 1)


def _run_end_table() -> IntArray:
    """Bit 1 / bit 2: whether a chain visit that arrives by step ``a`` and leaves by step
    ``b`` sweeps the pixel's right / left neighbour; indexed by ``9·a + b``.

    Border following turns around the pixel from the previous chain point to the next,
    counter-clockwise on the screen, through background neighbours only (Suzuki & Abe
    1985): the neighbours strictly between the two are swept, all seven others when it
    turns back to where it came from. A one-point chain (``a = b = 4``) sweeps both.
    """
    position = {(dr + 1) * 3 + dc + 1: k for k, (dc, dr) in enumerate(_TURN)}
    table = np.zeros(81, dtype=np.int64)
    for a in position:
        back = position[8 - a]  # the previous point, seen from here
        for b, leave in position.items():
            span = (leave - back) % 8 or 8
            east, west = (_EAST - back) % 8, (_WEST - back) % 8
            table[9 * a + b] = (0 < east < span) | (0 < west < span) << 1
    table[9 * 4 + 4] = 3
    return table


_RUN_END = _run_end_table()


def _trace_borders(contours: tuple[Chain, ...], hierarchy: NDArray[np.int32]) -> Borders:
    """Concatenate the chains of ``cv2.findContours`` and code each point's step.

    Written for few numpy calls (the per-frame path runs it after the stage has slept,
    when every distinct numpy function costs tens of µs): chain bounds in plain Python.
    """
    length_list = [len(c) for c in contours]
    start_list = [0, *itertools.accumulate(length_list)]
    total = start_list.pop()
    points = np.concatenate(contours).reshape(total, 2)
    start = np.array(start_list, dtype=np.int64)
    length = np.array(length_list, dtype=np.int64)
    last = start + length - 1
    d = np.empty_like(points)
    np.subtract(points[1:], points[:-1], out=d[:-1])
    d[last] = points[start] - points[last]  # closing step of every chain
    code = step_code(d[:, 0], d[:, 1]).astype(np.int64)
    return Borders(points, start, length, hierarchy[:, 3].astype(np.int64), code)


def _empty(shape: tuple[int, ...]) -> Components:
    """The components of an image without any object pixel."""
    none_f, none_i = np.zeros(0), np.zeros(0, dtype=np.int64)
    return Components(
        shape=(int(shape[0]), int(shape[1])),
        count=0,
        borders=Borders(np.zeros((0, 2), np.int32), none_i, none_i, none_i, none_i),
        border=none_i,
        filled=np.zeros((0, 3)),
        **dict.fromkeys(("area_px", "row", "col", "mu_rr", "mu_cc", "mu_rc"), none_f),
        **dict.fromkeys(("top", "left", "height", "width"), none_i),
    )


def label_components(
    binary: NDArray[np.uint8] | NDArray[np.bool_], *, min_area_px: float = 0.0
) -> Components:
    """Label the 8-connected components of a binary image and measure them.

    Parameters
    ----------
    binary : (H, W) uint8 or bool array
        Object pixels are the non-zero ones (the output of
        :func:`ovis.common.vision.threshold.binarize`).
    min_area_px : float
        Components with fewer pixels are left out (specks below any size filter).

    Returns
    -------
    Components
        In raster order of their first pixel.

    Raises
    ------
    ImageError
        If ``binary`` is not a non-empty 2-D uint8 or bool array.
    """
    image = _validated(binary)
    contours, hierarchy = cv2.findContours(image, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return _empty(image.shape)
    b = _trace_borders(contours, hierarchy[0])
    raw = _border_sums(b)
    outer = b.parent < 0
    holes = np.flatnonzero(~outer)
    solid = raw[:3].copy() if holes.size else raw[:3]  # Σ1, Σcol, Σrow inside outer borders
    for s in raw if holes.size else ():  # a component's sums: outer border + hole borders
        s += np.bincount(b.parent[holes], weights=s[holes], minlength=s.size)
    first = b.points[b.start]
    border = np.flatnonzero(outer)
    border = border[np.lexsort((first[border, 0], first[border, 1]))]  # raster order
    raw, solid = raw[:, border], solid[:, border]
    if min_area_px > 0:
        big = raw[0] >= min_area_px
        raw, solid, border = raw[:, big], solid[:, big], border[big]
    top, left, bottom, right = _boxes(b, border)
    area, s_c, s_r, s_cc, s_rr, s_cr = _about(raw, top.astype(np.float64), left.astype(np.float64))
    mean_c, mean_r = s_c / area, s_r / area
    whole = solid[0]
    filled = np.column_stack([whole, solid[2] / whole, solid[1] / whole])
    return Components(
        shape=(int(image.shape[0]), int(image.shape[1])),
        count=int(border.size),
        area_px=area,
        row=top + mean_r,
        col=left + mean_c,
        top=top,
        left=left,
        height=bottom - top + 1,
        width=right - left + 1,
        mu_rr=s_rr / area - mean_r * mean_r,
        mu_cc=s_cc / area - mean_c * mean_c,
        mu_rc=s_cr / area - mean_c * mean_r,
        borders=b,
        border=border,
        filled=filled,
    )


def _border_sums(b: Borders) -> FloatArray:
    """(6, b) sums Σ1, Σcol, Σrow, Σcol², Σrow², Σcol·row that each border chain adds
    to its component (discrete Green's theorem, see the module docstring): a visit that
    ends a run of its row adds ``G(x)``, one that starts a run subtracts ``G(x − 1)``.

    With ``e``, ``s`` ∈ {0, 1} for "ends a run", "starts a run", ``a = e − s`` and
    ``c = e + s``, the visit adds ``e + a·x`` (f = 1), ``x·(a·x + c)/2`` (f = col) and
    ``x·(a·(2x² + 1) + 3c·x)/6`` (f = col²), times ``row`` or ``row²`` for the others.
    Every term and every sum is an integer below 2⁵³ (Σcol² over a whole W×H image is
    about H·W³/3) for images up to about 10 000 pixels a side, so the sums are exact in
    float64.
    """
    arrive = np.empty_like(b.code)
    arrive[1:] = b.code[:-1]
    arrive[b.start] = b.code[b.start + b.length - 1]  # arriving step of each chain's start
    arrive *= 9
    arrive += b.code
    kind = _RUN_END[arrive]
    terms = np.empty((6, kind.size))  # rows: Σ1, Σcol, Σrow, Σcol², Σrow², Σcol·row
    g0, g1, yg0, g2, yyg0, yg1 = terms
    e = (kind & 1).astype(np.float64)
    s = (kind >> 1).astype(np.float64)
    x = b.points[:, 0].astype(np.float64)
    y = b.points[:, 1].astype(np.float64)
    a, c = e - s, e + s
    np.multiply(a, x, out=g0)
    np.add(g0, c, out=g1)
    g1 *= x
    g1 *= 0.5
    np.multiply(x, x, out=g2)
    g2 *= 2.0
    g2 += 1.0
    g2 *= a
    c *= 3.0
    c *= x
    g2 += c
    g2 *= x
    g2 /= 6.0
    g0 += e
    np.multiply(y, g0, out=yg0)
    np.multiply(y, yg0, out=yyg0)
    np.multiply(y, g1, out=yg1)
    return np.add.reduceat(terms, b.start, axis=1)


def _boxes(b: Borders, which: IntArray) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Bounding box (top, left, bottom, right) of the chains ``which`` (outer borders)."""
    low = np.minimum.reduceat(b.points, b.start)[which].astype(np.int64)
    high = np.maximum.reduceat(b.points, b.start)[which].astype(np.int64)
    return low[:, 1], low[:, 0], high[:, 1], high[:, 0]


def _about(raw: FloatArray, row0: FloatArray, col0: FloatArray) -> tuple[FloatArray, ...]:
    """The sums of :func:`_border_sums` with coordinates taken from ``(row0, col0)``
    (exact: integer arithmetic below 2⁵³), so that central moments lose no digits."""
    s1, sc, sr, scc, srr, scr = raw
    c, r = col0, row0
    return (
        s1,
        sc - c * s1,
        sr - r * s1,
        scc - 2.0 * c * sc + c * c * s1,
        srr - 2.0 * r * sr + r * r * s1,
        scr - c * sr - r * sc + c * r * s1,
    )


def filter_components(components: Components, keep_mask: NDArray[np.bool_]) -> Components:
    """Keep a subset of the components (e.g. the size filter of paper §3).

    Parameters
    ----------
    components : Components
    keep_mask : (n,) bool array
        ``True`` for the components to keep, in order.

    Returns
    -------
    Components
        The kept components, renumbered 1 … m in their original order (no pass over the
        image: the label image is drawn only if asked for).
    """
    keep = np.asarray(keep_mask)
    if keep.dtype != np.bool_ or keep.shape != (components.count,):
        raise ValueError(
            f"keep_mask: expected a bool array of shape ({components.count},), "
            f"got shape {keep.shape} {keep.dtype}"
        )
    c = components
    return Components(
        shape=c.shape,
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
        borders=c.borders,
        border=c.border[keep],
        filled=c.filled[keep],
    )

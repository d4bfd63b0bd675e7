"""A blob's outline to sub-pixel precision, from the frame less the empty floor.

The label stage hands each blob on as a :class:`Patch`: the frame's difference from the
empty floor (``D = frame − background``, grey levels, signed) around the blob. Solid
objects are brighter than the floor they stand on; their shadows are darker and their
walls may be barely brighter, so the object's pixels are those where the smoothed D is
at least the threshold (:func:`patch_outline`), holes filled (a marker's cells, a floor
mark the object hides).

Sub-pixel edges (:func:`subpixel_edges`): along each outline pixel's outward normal, D
is sampled from 4 px inside to 4 px outside and fitted, by least squares over a grid of
positions, with one or two blurred steps (a Gaussian edge spread of ``blur_px``): the
object against the floor, or a bright top face, then a dark wall, then the floor. The
outer step is the silhouette's edge; two steps are taken only where they fit clearly
better (a wall of its own level wide enough to be seen). Where one step is taken and a
shelf follows it outside — D still a few levels above the floor past the step's blur (a
wall too thin for two steps, lit only by the room) — the edge is where D falls to half
the shelf's level. Points on bright spots of the empty floor (floor marks,
:func:`background_spots`) are left out: there the object's edge is not against the
floor. :func:`edges_along` finds an edge of either sign where one is expected inside an
object (a top face against its wall).

A blob may hold several objects whose silhouettes overlap in the image (a tall object in
front of another): the union of convex silhouettes, cut where its outline turns inward
(:func:`split_outline`, at pairs of deep convexity defects).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Sequence
from typing import NamedTuple, overload

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.vision.labeling import Borders

__all__ = [
    "BlobPatches",
    "Outline",
    "Patch",
    "SmoothedDiff",
    "background_spots",
    "blob_outline",
    "blob_patches",
    "chain_normals",
    "edges_along",
    "object_mask",
    "patch_outline",
    "smoothed_mask",
    "split_outline",
    "subpixel_edges",
    "wall_tops",
]

FloatArray = NDArray[np.float64]

#: Pixels of floor kept around a blob in its patch (the profiles reach 4 px out).
PATCH_MARGIN_PX = 7
#: Profile samples: from −PROFILE_REACH to +PROFILE_REACH px along the normal, this apart.
PROFILE_REACH_PX = 4.0
PROFILE_STEP_PX = 0.5
#: Grid of step positions tried (px from the outline pixel) and its spacing.
STEP_RANGE_PX = 3.0
STEP_GRID_PX = 0.1
#: Two-step models on every this-many-th grid position.
TWO_STEP_EVERY = 3
#: Chain points on each side whose positions give an outline pixel's normal.
NORMAL_SPAN = 3
#: Two steps are taken when their residual sum of squares is smaller than one step's by
#: this many noise variances per sample; a wall step must be this many grey levels.
TWO_STEP_GAIN = 12.0
WALL_STEP = 2.0
#: A shelf just outside a single step (a thin dark wall) is looked for from this far
#: (px) past the step, is a wall when this many levels above the floor, whose level is
#: the profile's last few samples'.
SHELF_FROM_PX = 1.25
SHELF_STEP = 3.0
FLOOR_SAMPLES = 3
#: An edge whose outer step is weaker than this (grey levels) is no edge.
MIN_STEP = 3.0
#: Two steps closer than this (px) are no wall of its own (:func:`wall_tops`): a bright
#: top's one edge, blurred a little otherwise than the model, is often fitted so too.
WALL_MIN_PX = 0.9
#: A bright spot of the empty floor: this many levels above its 15-px median.
SPOT_LEVEL = 25
#: Gaussian smoothing (px) of D before the object pixels are thresholded.
SMOOTH_PX = 0.8


class Patch(NamedTuple):
    """``D`` (int16, frame − empty floor) of a blob's surroundings; its top-left pixel is
    (``top``, ``left``) of the frame. ``mask``: its object pixels cut from the whole
    frame's mask (:class:`BlobPatches` given it), which :func:`patch_outline` then takes
    instead of smoothing ``diff`` again: the same pixels farther than the smoothing's
    reach from a cut edge (the patch's margin), up to the last bits of the floats; None:
    worked out from ``diff``."""

    top: int
    left: int
    diff: NDArray[np.int16]
    mask: NDArray[np.uint8] | None = None


class Outline(NamedTuple):
    """A blob's outline in frame pixels: the closed chain of its outer pixels (n, 2)
    (col, row), the filled silhouette's area (px²) and centroid (row, col)."""

    chain: NDArray[np.int32]
    area_px: float
    row: float
    col: float


def blob_patches(
    gray: NDArray[np.uint8],
    background: NDArray[np.uint8],
    top: NDArray[np.int64],
    left: NDArray[np.int64],
    height: NDArray[np.int64],
    width: NDArray[np.int64],
    margin: int = PATCH_MARGIN_PX,
) -> list[Patch]:
    """Each blob's :class:`Patch`: the frame less the empty floor around its bounding
    box (``top``, ``left``, ``height``, ``width``, px)."""
    rows, cols = gray.shape
    out = []
    boxes = zip(top.tolist(), left.tolist(), height.tolist(), width.tolist(), strict=True)
    for t, lf, h, w in boxes:
        r0, c0 = _corner(t, lf, margin)
        r1, c1 = min(rows, t + h + margin), min(cols, lf + w + margin)
        diff = np.subtract(gray[r0:r1, c0:c1], background[r0:r1, c0:c1], dtype=np.int16)
        out.append(Patch(r0, c0, diff))
    return out


def _corner(top: int, left: int, margin: int) -> tuple[int, int]:
    """The top-left pixel (row, col) of the patch of a blob's box whose top-left pixel is
    (``top``, ``left``)."""
    return max(0, top - margin), max(0, left - margin)


class BlobPatches(Sequence[Patch]):
    """:func:`blob_patches` cut when first asked for, one blob at a time: most frames of
    a tracked scene need none (its solids are followed from their centroids). ``mask``:
    the frame's :func:`object_mask` (the one its blobs come from, no region of interest
    applied; a buffer the next frame may reuse: patches are cut within their frame),
    cut with each patch (a copy, kept with it); ``borders`` and ``border``: the label
    stage's border chains of that mask and each blob's outer one among them
    (:func:`~ovis.common.vision.labeling.label_components`)."""

    def __init__(
        self,
        gray: NDArray[np.uint8],
        background: NDArray[np.uint8],
        box: NDArray[np.int64],
        margin: int = PATCH_MARGIN_PX,
        mask: NDArray[np.uint8] | None = None,
        borders: Borders | None = None,
        border: NDArray[np.int64] | None = None,
    ) -> None:
        self._gray, self._background, self._margin = gray, background, margin
        self._mask = mask
        #: with ``mask``: the label stage's border chains in it and each blob's outer one
        #: (:meth:`own_outline`)
        self._outer = (borders, border) if mask is not None and border is not None else None
        self._box = np.asarray(box, dtype=np.int64).reshape(-1, 4)
        self._cut: dict[int, Patch] = {}

    def __len__(self) -> int:
        return len(self._box)

    def own_outline(self, k: int, at: tuple[float, float]) -> Outline | None:
        """Blob ``k``'s :func:`patch_outline` at ``at`` from its outer border chain, where
        that is known and holds ``at`` (the outline the patch's mask, the frame's, gives
        then: the one component there); else None (cut the patch and ask it)."""
        if self._outer is None or self._outer[0] is None:
            return None
        borders, border = self._outer
        i = int(border[k])
        start, length = int(borders.start[i]), int(borders.length[i])
        if length < 3:
            return None
        chain = borders.points[start : start + length]
        top, left = _corner(int(self._box[k, 0]), int(self._box[k, 1]), self._margin)
        own = (chain - np.array([left, top], dtype=np.int32)).reshape(-1, 1, 2)
        if cv2.pointPolygonTest(own, (at[1] - left, at[0] - top), True) < 0:
            return None
        return _outline_of(own, top, left)

    @overload
    def __getitem__(self, i: int) -> Patch: ...
    @overload
    def __getitem__(self, i: slice) -> list[Patch]: ...
    def __getitem__(self, i: int | slice) -> Patch | list[Patch]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        k = range(len(self))[i]  # IndexError as a list's
        if k not in self._cut:
            box = self._box[k : k + 1].T
            cut = blob_patches(self._gray, self._background, *box, self._margin)[0]
            if self._mask is not None:
                rows, cols = cut.diff.shape
                at = self._mask[cut.top : cut.top + rows, cut.left : cut.left + cols]
                cut = cut._replace(mask=at.copy())
            self._cut[k] = cut
        return self._cut[k]


@functools.lru_cache(maxsize=4)
def _spots(key: bytes, shape: tuple[int, int]) -> NDArray[np.uint8]:
    background = np.frombuffer(key, dtype=np.uint8).reshape(shape)
    med = cv2.medianBlur(background, 15)
    lift = background.astype(np.int16) - med
    spot = cv2.dilate((lift > SPOT_LEVEL).astype(np.uint8), np.ones((5, 5), np.uint8))
    out = np.where(spot > 0, np.clip(lift, 1, 255), 0).astype(np.uint8)
    out.flags.writeable = False  # shared by every caller (cached)
    return out


def background_spots(background: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Where the empty floor has a bright spot (a floor mark) or is near one: how much
    brighter it is there than the floor around it (at least 1), else 0."""
    bg = np.ascontiguousarray(background)
    return _spots(bg.tobytes(), bg.shape)


def object_mask(
    diff: NDArray[np.int16], level: float, spots: NDArray[np.uint8] | None = None
) -> NDArray[np.uint8]:
    """The object pixels of the frame less the empty floor (measured heights): D,
    smoothed (Gaussian, :data:`SMOOTH_PX`), at least ``level``; on bright floor spots
    (``spots``, of the same shape, :func:`background_spots`) a difference of at least
    ``level`` either way (an object hiding a spot may be darker than it) that leaves the
    pixel at least ``level`` brighter than the floor around the spot (a shadow on a
    spot darkens it too, but not above the floor). The label stage's blobs and the
    outlines fitted come from this one mask."""
    d = cv2.GaussianBlur(diff.astype(np.float32), (0, 0), SMOOTH_PX)
    return smoothed_mask(d, level, spots)


def smoothed_mask(
    d: NDArray[np.float32],
    level: float,
    spots: NDArray[np.uint8] | None = None,
) -> NDArray[np.uint8]:
    """:func:`object_mask` from D already smoothed (:data:`SMOOTH_PX`)."""
    mask = np.greater_equal(d, level).view(np.uint8)
    if spots is not None:
        entry = _spot_entry(spots)
        _hidden_spots(mask, d.ravel()[entry[1]], level, spots, entry)
    return mask


def _hidden_spots(
    mask: NDArray[np.uint8],
    here: NDArray[np.float32],
    level: float,
    spots: NDArray[np.uint8],
    entry: list,
) -> None:
    """Add to ``mask`` the bright floor spots' pixels an object hides: smoothed D
    (``here``, at the spots' pixels, ``entry``: :func:`_spot_entry`) at least ``level``
    darker, yet at least ``level`` brighter than the floor around the spot. A spot's
    pixel at least ``level`` brighter is in already; the spot level is worked out only
    where one is that dark."""
    dark = here <= -level
    if dark.any():
        hidden = dark & (here + _spot_lift(spots, entry) >= level)
        mask.ravel()[entry[1][hidden]] = 1


class SmoothedDiff:
    """Object pixels of whole frames as :func:`object_mask` finds them, into buffers kept
    from one frame to the next (a frame's images allocated afresh each time cost more in
    page faults than their arithmetic). The smoothing is linear, so the frame's smoothed
    D is the smoothed frame less the smoothed empty floor: the floor's side (smoothed,
    plus the level) is worked out once for a read-only floor image, and a frame's pixel
    is an object's where its smoothed grey level reaches it; D itself is formed only at
    the floor's bright spots. The kernel is ``cv2.GaussianBlur``'s
    (``cv2.sepFilter2D`` applied to the 8-bit frame straight away: no float copy of it).
    Not to be shared between threads."""

    def __init__(self) -> None:
        self._gray: NDArray[np.float32] | None = None
        self._mask: NDArray[np.bool_] | None = None
        self._floor: NDArray[np.uint8] | None = None  # the read-only floor image kept
        self._floor_smooth: NDArray[np.float32] | None = None
        self._level = math.nan
        self._above: NDArray[np.float32] | None = None  # smoothed floor + level

    def mask(
        self,
        gray: NDArray[np.uint8],
        background: NDArray[np.uint8],
        level: float,
        spots: NDArray[np.uint8] | None = None,
    ) -> NDArray[np.uint8]:
        """:func:`object_mask` of the frame less the empty floor; valid until the next
        call."""
        if self._gray is None or self._gray.shape != gray.shape:
            self._gray = np.empty(gray.shape, np.float32)
            self._mask = np.empty(gray.shape, bool)
        floor, above = self._floor_side(background, level)
        cv2.sepFilter2D(gray, cv2.CV_32F, _SMOOTH, _SMOOTH, dst=self._gray)
        mask = np.greater_equal(self._gray, above, out=self._mask).view(np.uint8)
        if spots is not None:
            entry = _spot_entry(spots)
            at = entry[1]
            here = self._gray.ravel()[at] - floor.ravel()[at]
            _hidden_spots(mask, here, level, spots, entry)
        return mask

    def _floor_side(
        self, background: NDArray[np.uint8], level: float
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """The empty floor smoothed, and that plus ``level``: kept for a read-only floor
        image (the configured one is read once and kept read-only), else made again."""
        kept = (
            background is self._floor
            and not background.flags.writeable
            and level == self._level
            and self._floor_smooth is not None
            and self._above is not None
        )
        if not kept:
            smooth = cv2.sepFilter2D(background, cv2.CV_32F, _SMOOTH, _SMOOTH)
            self._floor, self._floor_smooth, self._level = background, smooth, level
            self._above = smooth + np.float32(level)
        assert self._floor_smooth is not None and self._above is not None
        return self._floor_smooth, self._above


#: ``cv2.GaussianBlur``'s kernel for :data:`SMOOTH_PX` on float images (its taps:
#: 8 σ + 1, rounded, odd).
_SMOOTH = cv2.getGaussianKernel(round(8 * SMOOTH_PX + 1) | 1, SMOOTH_PX, cv2.CV_32F)


#: The spots' pixels and their :func:`_spot_lift` (None until asked for) of the last few
#: spot images kept (:func:`_spot_key`), with the whole image they belong to: whole
#: images and patches' slices apart (the patches of moving blobs come and go, the whole
#: image stays).
_LIFTS: dict[tuple, list] = {}
_PATCH_LIFTS: dict[tuple, list] = {}
_LIFTS_LOCK = threading.Lock()


def _spot_key(spots: NDArray[np.uint8]) -> tuple[NDArray[np.uint8], tuple] | None:
    """The whole image a spot image's numbers are kept under, and their key: a whole
    read-only image of :func:`background_spots` by its identity (every frame's mask uses
    it), a patch's slice of one by the whole's identity and the slice's place in it (a
    blob that stays put is cut at the same place frame after frame); None: not kept."""
    if not spots.flags.writeable and spots.base is None:
        return spots, (id(spots),)
    whole = spots.base
    if not isinstance(whole, np.ndarray) or whole.flags.writeable or whole.base is not None:
        return None
    start = spots.__array_interface__["data"][0] - whole.__array_interface__["data"][0]
    return whole, (id(whole), start, spots.shape)


def _spot_entry(spots: NDArray[np.uint8]) -> list:
    """[whole image, the spots' flat indices, their level or None] of a spot image, kept
    where :func:`_spot_key` says."""
    kept = _spot_key(spots)
    cache, most = (_LIFTS, 4) if kept is None or len(kept[1]) == 1 else (_PATCH_LIFTS, 8)
    if kept is not None:
        hit = cache.get(kept[1])
        if hit is not None and hit[0] is kept[0]:
            return hit
    entry = [None if kept is None else kept[0], np.flatnonzero(spots), None]
    if kept is not None:
        with _LIFTS_LOCK:  # the frames' thread and the fitting thread
            while len(cache) >= most:
                cache.pop(next(iter(cache)))
            cache[kept[1]] = entry
    return entry


def _spot_lift(spots: NDArray[np.uint8], entry: list) -> NDArray[np.float32]:
    """The smoothed spot level at the spots' pixels (``entry``, :func:`_spot_entry`), as
    :func:`object_mask` smooths D (a patch's smoothed within the slice, as its D is),
    worked out once per entry."""
    if entry[2] is None:
        at = entry[1]
        if not at.size:
            entry[2] = np.zeros(0, dtype=np.float32)
        else:
            smooth = cv2.GaussianBlur(spots.astype(np.float32), (0, 0), SMOOTH_PX)
            entry[2] = smooth.ravel()[at]
    return entry[2]


def patch_outline(
    patch: Patch,
    level: float,
    at: tuple[float, float] | None = None,
    spots: NDArray[np.uint8] | None = None,
) -> Outline | None:
    """The outline of the object pixels of a patch (smoothed D ≥ ``level``), holes
    filled: the component nearest ``at`` (frame row, col; default the patch's
    centre); None when the patch has none. On the frame's bright floor spots
    (``spots``, :func:`background_spots`) an object hiding a spot may be darker than
    the spot: there any difference from the floor image counts. The patch's ``mask``
    when it has one (cut from the frame's, worked out at ``level`` with ``spots``)."""
    mask = patch.mask
    if mask is None:
        rows, cols = patch.diff.shape
        here = None
        if spots is not None:
            here = spots[patch.top : patch.top + rows, patch.left : patch.left + cols]
        mask = object_mask(patch.diff, level, here)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    if at is None:
        goal = (0.5 * (mask.shape[1] - 1), 0.5 * (mask.shape[0] - 1))
    else:
        goal = (at[1] - patch.left, at[0] - patch.top)
    best, best_key = None, None
    for c in contours:
        if len(c) < 3:
            continue
        inside = cv2.pointPolygonTest(c, goal, True)
        key = (0.0, -float(len(c))) if inside >= 0 else (1.0, -inside)
        if best_key is None or key < best_key:
            best, best_key = c, key
    if best is None:
        return None
    return _outline_of(best, patch.top, patch.left)


def _outline_of(contour: NDArray[np.int32], top: int, left: int) -> Outline | None:
    """The :class:`Outline` of a contour (n, 1, 2) of a patch whose top-left pixel is
    (``top``, ``left``); None when it encloses nothing."""
    m = cv2.moments(contour)
    if m["m00"] <= 0:
        return None
    chain = contour[:, 0, :] + np.array([left, top], dtype=np.int32)
    area = float(m["m00"])
    return Outline(chain, area, m["m01"] / area + top, m["m10"] / area + left)


def blob_outline(
    patches: Sequence[Patch],
    k: int,
    level: float,
    at: tuple[float, float],
    spots: NDArray[np.uint8] | None = None,
) -> Outline | None:
    """:func:`patch_outline` of ``patches[k]`` at ``at`` (frame row, col), from the blob's
    outer border chain where :class:`BlobPatches` knows it and it holds ``at``
    (:meth:`BlobPatches.own_outline`: no patch cut, no contours traced again)."""
    if isinstance(patches, BlobPatches):
        own = patches.own_outline(k, at)
        if own is not None:
            return own
    return patch_outline(patches[k], level, at, spots)


def chain_normals(chain: NDArray[np.int32]) -> tuple[FloatArray, FloatArray]:
    """Chain points (col, row) as floats and their outward unit normals (from the
    chain's direction over ±:data:`NORMAL_SPAN` points; its orientation from its signed
    area, :func:`cv2.contourArea`: exact on whole pixels)."""
    p = chain.astype(np.float64)
    k = NORMAL_SPAN % len(p)
    ring = np.concatenate([p[len(p) - k :], p, p[:k]])  # the chain, wrapped k each way
    tangent = ring[2 * k :] - ring[: len(p)]
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-9)[:, None]
    sign = 1.0 if cv2.contourArea(p.astype(np.float32), oriented=True) > 0 else -1.0
    return p, tangent[:, ::-1] * np.array([sign, -sign])


class _Steps(NamedTuple):
    """The step models fitted to every profile: their positions, design matrices
    ([1, outer step(, inner step)] over the samples) and pseudo-inverses."""

    outer: FloatArray  # (K,) outer step positions (px along the normal)
    design: FloatArray  # (K, T, c)
    pinv: FloatArray  # (K, c, T)
    inner: FloatArray  # (K,) inner step positions (the outer one's for one step)


def _design(blur_px: float, positions: list[tuple[float, ...]], reach: float) -> _Steps:
    from scipy.special import ndtr  # on first use: most processes never fit an edge

    ts = np.arange(-reach, reach + 1e-9, PROFILE_STEP_PX)
    cols = [np.ones((len(positions), ts.size))]
    for j in range(len(positions[0])):
        at = np.array([p[j] for p in positions])
        cols.append(ndtr((at[:, None] - ts) / blur_px))
    design = np.stack(cols, -1)
    outer = np.array([p[0] for p in positions])
    return _Steps(outer, design, np.linalg.pinv(design), np.array([p[-1] for p in positions]))


@functools.lru_cache(maxsize=8)
def _step_models(blur_px: float, reach: float = STEP_RANGE_PX) -> tuple[_Steps, _Steps, int]:
    """One step at every position of the fine grid within ±``reach`` px; two steps
    (outer, inner) on a coarser grid (every ``TWO_STEP_EVERY``-th fine position), and
    that stride; profiles reach a pixel further."""
    fine = np.arange(-reach, reach + 1e-9, STEP_GRID_PX)
    sampled = reach + PROFILE_REACH_PX - STEP_RANGE_PX
    one = _design(blur_px, [(b,) for b in fine], sampled)
    coarse = fine[::TWO_STEP_EVERY]
    pairs = [(b, a) for b in coarse for a in coarse if a < b - 1e-9]
    two = _design(blur_px, pairs, sampled)
    return one, two, TWO_STEP_EVERY


def _fit_steps(prof: FloatArray, steps: _Steps) -> tuple[FloatArray, FloatArray]:
    """Residual sums of squares (K, n) and coefficients (K, n, c) of every step model
    (least squares by the pseudo-inverse; the residual by ``|p|² − (Bᵀp)·c``, B·B⁺ being
    a projection)."""
    coef = np.matmul(steps.pinv, prof.T)  # (K, c, n)
    projected = np.matmul(steps.design.transpose(0, 2, 1), prof.T)  # (K, c, n)
    ss = np.einsum("ij,ij->i", prof, prof)[None, :] - (coef * projected).sum(1)
    return np.maximum(ss, 0.0), coef.transpose(0, 2, 1)


def _profiles(
    diff: NDArray[np.float32],
    origin: tuple[int, int],
    points: FloatArray,
    normals: FloatArray,
    reach: float = PROFILE_REACH_PX,
) -> FloatArray:
    """D sampled along each point's normal, from −reach to +reach (bilinear)."""
    ts = np.arange(-reach, reach + 1e-9, PROFILE_STEP_PX)
    local = points - np.array([origin[1], origin[0]], dtype=np.float64)
    xs = (local[:, None, 0] + ts * normals[:, None, 0]).astype(np.float32)
    ys = (local[:, None, 1] + ts * normals[:, None, 1]).astype(np.float32)
    prof = cv2.remap(diff, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return prof.astype(np.float64)


def _one_step(prof: FloatArray, steps: _Steps, either_sign: bool) -> tuple[FloatArray, FloatArray]:
    """Each profile's best single step: its position (px along the normal, refined
    between grid points) and residual sum of squares (inf: no step strong enough)."""
    ss1, c1 = _fit_steps(prof, steps)
    strong = np.abs(c1[..., 1]) if either_sign else c1[..., 1]
    ss1 = np.where(strong > MIN_STEP, ss1, np.inf)
    n = np.arange(len(prof))
    k1 = ss1.argmin(0)
    best1 = ss1[k1, n]
    lo, hi = np.maximum(k1 - 1, 0), np.minimum(k1 + 1, len(steps.outer) - 1)
    a, b, c = ss1[lo, n], best1, ss1[hi, n]
    fine = np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & (lo < k1) & (hi > k1)
    a, b, c = np.where(fine, a, 0.0), np.where(fine, b, 0.0), np.where(fine, c, 0.0)
    curve = a - 2.0 * b + c
    shift = np.where(fine & (curve > 0), 0.5 * (a - c) / np.where(curve > 0, curve, 1.0), 0.0)
    return steps.outer[k1] + np.clip(shift, -0.5, 0.5) * STEP_GRID_PX, best1


def _off_spots(edge: FloatArray, spots: NDArray[np.uint8] | None) -> NDArray[np.bool_]:
    if spots is None:
        return np.ones(len(edge), dtype=bool)
    r = np.clip(np.rint(edge[:, 1]).astype(np.int64), 0, spots.shape[0] - 1)
    c = np.clip(np.rint(edge[:, 0]).astype(np.int64), 0, spots.shape[1] - 1)
    return spots[r, c] == 0


def subpixel_edges(
    diff: NDArray[np.float32],
    origin: tuple[int, int],
    chain: NDArray[np.int32],
    *,
    blur_px: float,
    noise: float,
    spots: NDArray[np.uint8] | None = None,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Sub-pixel silhouette edge points (frame col, row), outward normals and which are
    usable, one per chain point (see the module's docstring); ``diff`` is D around the
    chain with its top-left pixel at ``origin`` (row, col) of the frame; ``spots`` (the
    frame's :func:`background_spots`) drop points on bright floor."""
    p, nrm, prof, steps = _chain_steps(diff, origin, chain, blur_px, noise)
    at = np.where(steps.two, steps.outer, _past_the_wall(prof, steps.outer))
    edge = p + at[:, None] * nrm
    return edge, nrm, np.isfinite(steps.best) & _off_spots(edge, spots)


class _EdgeSteps(NamedTuple):
    """Each profile's steps: the outer one's position (px along the normal), the inner
    one's (NaN: one step), whether two were taken and the residual sum of squares of the
    model taken (inf: none strong enough)."""

    outer: FloatArray
    inner: FloatArray
    two: NDArray[np.bool_]
    best: FloatArray


def _chain_steps(
    diff: NDArray[np.float32],
    origin: tuple[int, int],
    chain: NDArray[np.int32],
    blur_px: float,
    noise: float,
) -> tuple[FloatArray, FloatArray, FloatArray, _EdgeSteps]:
    """A pixel chain's points and outward normals, D's profile across each and the steps
    fitted to it (:func:`subpixel_edges` and :func:`wall_tops` read them two ways)."""
    p, nrm = chain_normals(chain)
    prof = _profiles(diff, origin, p, nrm)
    return p, nrm, prof, _edge_steps(prof, float(blur_px), noise)


def _edge_steps(prof: FloatArray, blur_px: float, noise: float) -> _EdgeSteps:
    """One step, or two where they fit clearly better (module docstring)."""
    one, two, _ = _step_models(blur_px)
    at1, best1 = _one_step(prof, one, either_sign=False)
    gain = TWO_STEP_GAIN * noise * noise
    # two steps only where one leaves more than the gain they must bring
    n = len(prof)
    k2 = np.zeros(n, dtype=np.int64)
    best2 = np.full(n, np.inf)
    poor = np.flatnonzero(~(best1 <= gain))
    if poor.size:
        ss2, c2 = _fit_steps(prof[poor], two)
        valid = (c2[..., 1] > WALL_STEP) & (np.abs(c2[..., 2]) > WALL_STEP)
        ss2 = np.where(valid, ss2, np.inf)
        k2[poor] = ss2.argmin(0)
        best2[poor] = ss2[k2[poor], np.arange(poor.size)]
    take_two = best2 < best1 - gain
    return _EdgeSteps(
        np.where(take_two, two.outer[k2], at1),
        np.where(take_two, two.inner[k2], np.nan),
        take_two,
        np.where(take_two, best2, best1),
    )


def wall_tops(
    diff: NDArray[np.float32],
    origin: tuple[int, int],
    chain: NDArray[np.int32],
    *,
    blur_px: float,
    noise: float,
    spots: NDArray[np.uint8] | None = None,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Where a wall of its own level shows at the silhouette (two steps, as
    :func:`subpixel_edges` takes them, at least :data:`WALL_MIN_PX` apart, the floor
    past them: the wall's foot outside, the top face's edge inside), that inner edge
    (frame col, row), one per chain point, the outward normals and which were found: a
    top's edge over a wall too thin for :func:`edges_along`'s look, whose one step
    there would be the silhouette's."""
    p, nrm, prof, steps = _chain_steps(diff, origin, chain, blur_px, noise)
    inner = np.nan_to_num(steps.inner)
    edge = p + inner[:, None] * nrm
    wide = steps.outer - inner >= WALL_MIN_PX - 0.5 * STEP_GRID_PX
    # the floor just past the outer step: else a darker part of the wall lies beyond it
    # (a shelf, :func:`_past_the_wall`), and the outer step is not the wall's foot
    footed = _past_the_wall(prof, steps.outer) == steps.outer
    return edge, nrm, steps.two & wide & footed & _off_spots(edge, spots)


def _past_the_wall(prof: FloatArray, inner: FloatArray) -> FloatArray:
    """Each profile's silhouette edge given its one step at ``inner``: that step, unless
    a shelf follows it — D still :data:`SHELF_STEP` above the floor just outside it (a
    wall too thin for two steps to tell, lit only by the room, between a bright top and
    the floor) — then where D falls to half the shelf's level past it."""
    ts = np.arange(-PROFILE_REACH_PX, PROFILE_REACH_PX + 1e-9, PROFILE_STEP_PX)
    floor = prof[:, -FLOOR_SAMPLES:].mean(1)
    above = prof - floor[:, None]
    past = ts[None, :] >= inner[:, None] + SHELF_FROM_PX
    first = np.argmax(past, axis=1)
    rows = np.arange(len(prof))
    take = past.any(1) & (first + 1 < ts.size - FLOOR_SAMPLES)
    nxt = np.minimum(first + 1, ts.size - 1)
    level = np.where(take, (above[rows, first] + above[rows, nxt]) / 2.0, 0.0)
    wall = take & (level >= SHELF_STEP)
    below = (above < (level / 2.0)[:, None]) & (np.arange(ts.size) > first[:, None])
    k = np.argmax(below, axis=1)
    wall &= below[rows, k] & (k > 0)
    a, b = above[rows, np.maximum(k - 1, 0)], above[rows, k]
    frac = np.where(a > b, (a - level / 2.0) / np.where(a > b, a - b, 1.0), 0.5)
    crossing = ts[np.maximum(k - 1, 0)] + np.clip(frac, 0.0, 1.0) * PROFILE_STEP_PX
    return np.where(wall, crossing, inner)


def edges_along(
    diff: NDArray[np.float32],
    origin: tuple[int, int],
    points: FloatArray,
    normals: FloatArray,
    *,
    blur_px: float,
    reach_px: float = 2.0,
    spots: NDArray[np.uint8] | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The edge of either sign nearest each of ``points`` (frame col, row) along its
    ``normals`` (an edge expected there, inside an object: a top face against its
    wall), within ``reach_px``; and which were found. A step whose best position is an
    end of the positions tried is none found: the profile still falls past it, the edge
    lies beyond the reach (taken there, a top's edge looked for far inside its true one
    would be found at the reach, a fixed distance short of it)."""
    if not len(points):
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    one, _, _ = _step_models(float(blur_px), float(reach_px))
    sampled = reach_px + PROFILE_REACH_PX - STEP_RANGE_PX
    prof = _profiles(diff, origin, points, normals, sampled)
    at, best = _one_step(prof, one, either_sign=True)
    edge = points + at[:, None] * normals
    within = np.abs(at) < float(np.abs(one.outer).max()) - 0.25 * STEP_GRID_PX
    return edge, np.isfinite(best) & within & _off_spots(edge, spots)


#: A cut needs a convexity defect at least this deep (px) at one end and this at the other.
DEFECT_DEEP_PX = 2.5
DEFECT_PX = 1.0
#: Pieces a blob is cut into at most.
MAX_PIECES = 6


def split_outline(
    chain: NDArray[np.int32], spots: NDArray[np.uint8] | None = None
) -> list[NDArray[np.int64]]:
    """Index arrays into ``chain`` of the pieces of a blob holding several convex
    silhouettes: cut between the pair of convexity defects (one deep) deepest at its
    shallower end for the cut's length (two silhouettes crossing make two concave
    corners; a pixel's dent beside one is not the other), again in each piece, until
    none is left. Never at a defect on a bright floor
    spot (``spots``): there the outline is uncertain."""
    avoid = np.zeros(len(chain), dtype=bool)
    if spots is not None:
        r = np.clip(chain[:, 1], 0, spots.shape[0] - 1)
        c = np.clip(chain[:, 0], 0, spots.shape[1] - 1)
        avoid = spots[r, c] > 0
    todo = [np.arange(len(chain))]
    done: list[NDArray[np.int64]] = []
    while todo:
        idx = todo.pop()
        full = len(done) + len(todo) + 1 >= MAX_PIECES
        cut = None if full else _best_cut(chain[idx], avoid[idx])
        if cut is None:
            done.append(idx)
            continue
        i, j = cut
        todo.append(idx[i : j + 1])
        todo.append(np.concatenate([idx[j:], idx[: i + 1]]))
    return done


def _best_cut(points: NDArray[np.int32], avoid: NDArray[np.bool_]) -> tuple[int, int] | None:
    """The chain indices (i < j) of the cut of :func:`split_outline`, or None."""
    if len(points) < 12:
        return None
    pts = np.ascontiguousarray(points, dtype=np.int32).reshape(-1, 1, 2)
    hull = np.sort(cv2.convexHull(pts, returnPoints=False).ravel())
    if len(hull) < 4:
        return None
    try:
        defects = cv2.convexityDefects(pts, hull.reshape(-1, 1).astype(np.int32))
    except cv2.error:  # a self-touching chain
        return None
    if defects is None:
        return None
    defects = defects.reshape(-1, 4)
    depth = defects[:, 3] / 256.0
    keep = (depth >= DEFECT_PX) & ~avoid[defects[:, 2]]
    far, depth = defects[keep, 2], depth[keep]
    if len(far) < 2 or depth.max() < DEFECT_DEEP_PX:
        return None
    best = None
    for a in range(len(far)):
        for b in range(a + 1, len(far)):
            if max(depth[a], depth[b]) < DEFECT_DEEP_PX:
                continue
            i, j = sorted((int(far[a]), int(far[b])))
            if j - i < 4 or len(points) - (j - i) < 4:
                continue
            length = float(np.hypot(*(points[i] - points[j])))
            score = -min(depth[a], depth[b]) / max(length, 1.0)  # deep at both ends, short
            if best is None or score < best[0]:
                best = (score, i, j)
    return None if best is None else (best[1], best[2])

"""Measured heights: each blob's solids fitted and followed from frame to frame.

With ``[pose] heights = "measured"``, a blob's solids (shape, footprint, height:
:func:`ovis.common.solids.fit.fit_blob`) are fitted to its sub-pixel outline
(:mod:`ovis.common.vision.outline`, from its :class:`~ovis.common.vision.outline.Patch`
of the frame less the empty floor). A solid's shape and height do not change, so the
fit is not repeated every frame: :class:`SolidTracker` keeps each blob's fitted solids
(a *group*) and finds the blob again in the next frame by its image centroid (within
:data:`GATE_PX`, its area within :data:`AREA_RATIO`). Each frame then

* a blob that holds one known solid gets its footprint from its centroid
  (:mod:`ovis.common.solids.footprint`: the footprint centre whose silhouette's image
  centroid is the blob's, less the offset the two had at the fit; the map kept from
  one frame to the next while the solid stays within :data:`RELINEARISE_CM`);
* a blob of several solids (overlapping in the image) gets their footprints from its
  outline's pixel chain (:func:`~ovis.common.solids.fit.follow_union`: their centres
  moved and polygons turned from where their last motion puts them, shapes and heights
  kept, each edge offset as at the fit);
* a blob that is new because solids met or parted in the image gets the known solids
  whose images it holds, followed onto its outline (:meth:`SolidTracker._carry`), and is
  fitted again as soon as no new blob waits;
* a new blob they do not explain is fitted; the periodic refit of a known blob (every
  :data:`REFIT_FRAMES` frames, the one fitted longest ago) averages its heights over
  its track (inverse-variance weights). At most ``pose.fits_per_frame`` fits run per
  frame (0: all); a blob that waits is said ``pending``, at the configured height, its
  footprint rough (:func:`~ovis.common.solids.fit.rough_footprint`, from its outline's
  pixel chain, with the covariance of where it may be and of a height anywhere within
  a fit's range) or, where that cannot be had, its centroid on its class's plane (no
  covariance stated).

A live stage (``background``) never waits for a fit: the fits run on a thread of their
own while the frames go on, a refit or every new blob's at once (queued one after the
other; each blob said ``pending`` meanwhile and followed by its centroid), and each
fitted group joins the others at the first frame after it is done, found again by its
centroid as any group of the last frame is (a fit's cost is many frame periods' worth of
the per-frame work, which is then only matching and following).

Each solid's height counts as measured when its uncertainty (1σ, including what a bias
of all its edges would do) is at most ``pose.height_sigma_max_cm``; else it is *not
measurable* there (near the camera's nadir, or where the walls are too thin or hidden):
its footprint still comes from the fit (its height held at the configured one, or
lower where the frame shows the solid is lower: :meth:`SolidTracker._hold_height`), its
reported height is the configured one. A fit that does not explain its outline (too
many edge points off its silhouettes: :attr:`~ovis.common.solids.fit.Solid.explains`)
is not measured either. Nor is a solid whose walls' foot is hidden behind another of its
blob: only its top shows, and the outline's points where its silhouette meets the other's
are no evidence of its height (:func:`~ovis.common.solids.fit.refit_with_tops`); it is
held (:func:`~ovis.common.solids.fit.feet_hidden`) while the others are fitted again with
their top edges, then placed where the others let it stand, its position's uncertainty
spread over that stretch of the line of sight
(:func:`~ovis.common.solids.fit.bound_behind`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.camera.plane_table import PlaneTables
from ovis.common.camera.projection import PixelJacobian, project
from ovis.common.config import CameraModel, ImageParams, PoseConfig
from ovis.common.solids.fit import (
    HEIGHT_STARTS,
    ITERATIONS,
    MAX_OFF_SHARE,
    FloorOutline,
    RoughFootprint,
    Solid,
    bound_behind,
    feet_hidden,
    fit_blob,
    fit_piece,
    follow_union_steps,
    height_spread,
    held_covariance,
    held_height,
    refit_with_tops,
    robot_misfit,
    rough_footprint,
    union_offsets,
    unplaced_covariance,
)
from ovis.common.solids.footprint import PoseMap, centroid_map, turn_between
from ovis.common.solids.outline_floor import chain_floor, floor_outline
from ovis.common.solids.shapes import equal_area_radius, size_and_yaw, yaw_index
from ovis.common.solids.silhouette import Viewpoint, signed_distance, top_near_edges
from ovis.common.vision.contrast import NEUTRAL
from ovis.common.vision.outline import (
    Outline,
    Patch,
    background_spots,
    blob_outline,
    edges_along,
    patch_outline,
    split_outline,
    subpixel_edges,
    wall_tops,
)
from ovis.common.vision.shape import axis_deg
from ovis.common.world.pose import gated_assignment, gated_pairs_few
from ovis.common.world.robot_turn import (
    AXIS_CHECK_DEG,
    AXIS_REACH_DEG,
    STILL_PX,
    TURN_CHECK_DEG,
    TurnState,
    degrees_between,
    robot_turn,
)

__all__ = [
    "AREA_RATIO",
    "GATE_PX",
    "REFIT_FRAMES",
    "RELINEARISE_CM",
    "SolidObjects",
    "SolidTracker",
    "heights_unavailable",
    "measurable",
    "robot_row",
    "with_heights",
]

FloatArray = NDArray[np.float64]

#: A blob is the same as last frame's when its centroid moved at most this far (px) …
GATE_PX = 20.0
#: … and its area changed by at most this factor.
AREA_RATIO = 1.2
#: A known solid is refitted every this many frames (the one fitted longest ago).
REFIT_FRAMES = 60
#: A solid's centroid map is worked out again when it moved this far (cm) from where it
#: was worked out.
RELINEARISE_CM = 2.0
#: Any other lone solid's centroid map is worked out again where it turned this far
#: (rad: 1°; a carry into a new blob turns one).
RELINEARISE_RAD = math.radians(1.0)
#: Chain points left out at each end of a cut outline's piece (the cut's corner).
CUT_TRIM = 3
#: How far (px) from where the fit puts it the top face's inner edge is looked for:
#: widely first, then again closer after a refit.
TOP_REACH_PX = (6.0, 1.5)
#: The top face's inner edge is used only where the wall below it is this tall in the
#: frame (px): a thinner wall blurs into one edge with the silhouette's.
MIN_WALL_PX = 4.0
#: The top face's inner edge is taken only this far (px) inside the silhouette.
TOP_INSIDE_PX = 1.5
#: Iterations of a known solid's refit (it starts where it was).
WARM_ITERATIONS = 10
#: An outline needs this many usable edge points to be fitted.
MIN_EDGE_POINTS = 12
#: Held at the configured height, a solid's walls are clearly tall enough for a look
#: for its top's edge to be decisive where walls too thin to show stop below this share
#: of that height (twice :data:`MIN_WALL_PX` tall, the walls growing with the height).
CLEAR_WALLS_SHARE = 0.5
#: A blob's several solids are followed in at most this many Gauss–Newton steps, fewer
#: where a step moves none of them more than this (cm).
FOLLOW_STEPS = 3
FOLLOW_TOL_CM = 0.02
#: … and in one where frames come at most this far apart (s): from where their last
#: motion puts them they moved too little for a second step to tell.
ONE_STEP_S = 0.05
#: … and are left where they are while its centroid stays within
#: :data:`~ovis.common.world.robot_turn.STILL_PX`, its filled area within this share and
#: its axis in the frame within :data:`~ovis.common.world.robot_turn.TURN_CHECK_DEG` of
#: where they were last followed (solids standing still: a follow would move them by
#: the frame's noise alone).
STILL_AREA_SHARE = 0.01
#: Known solids carried into a blob where they met or parted (:meth:`SolidTracker._carry`)
#: are followed onto its outline in at most this many steps, and kept where no more than
#: ``MAX_OFF_SHARE`` of its pixel chain is over this far (px) from their union.
CARRY_STEPS = 6
CARRY_OFF_PX = 1.5
#: A carried solid that was alone in its blob is tried turned by these (deg) too.
CARRY_TURNS_DEG = (20.0, -20.0, 40.0, -40.0, 60.0, -60.0, 90.0)
#: A followed solid's reported yaw is updated when it turned by more than this (deg).
REPORTED_TURN_DEG = 0.1
#: How closely (cm) the tallest height whose walls are too thin to show is worked out.
THIN_STEP_CM = 0.05
#: A point of the outline is on the walls' foot when its outward normal on the floor
#: points at the camera's foot within this cosine (its wall faces the camera); a top's
#: edge over thin walls is taken where a wall shows along at least this share of them
#: (where a face of the walls does not show, as dark as the floor, their foot there is
#: not where the outline puts it, and the height between it and the top's edge is off).
WALL_FACING_COS = 0.3
WALL_SHARE = 0.75


def heights_unavailable(image: ImageParams) -> str | None:
    """Why heights cannot be measured with these image settings, or None."""
    if not image.background:
        return (
            "heights measured need an image of the empty floor ([image] background, "
            "e.g. a frame taken before the objects are put down)"
        )
    if image.threshold_mode != "fixed" or image.polarity != "bright":
        return (
            'heights measured need [image] threshold_mode = "fixed" and polarity = '
            '"bright" (objects brighter than the empty floor by threshold - 128)'
        )
    return None


@dataclass
class _Tracked:
    """One fitted solid kept across frames: the last fit, its height averaged over the
    fits (inverse-variance), where it stands now, and its centroid map."""

    solid: Solid
    h_weight: float
    h_sum: float
    h_floor: float  # the least systematic uncertainty of one fit (does not average out)
    #: (x, y) cm: a fit's or a union's follow's array, a single solid's follow's pair of
    #: floats; never changed in place (each move replaces it)
    centre: FloatArray | tuple[float, float]
    bias: FloatArray = field(default_factory=lambda: np.zeros(2))
    map_at: FloatArray | tuple[float, float] | None = None
    map_yaw: float = math.nan  # its yaw (rad) where its map was worked out
    #: the unmarked robot's turns (None: not followed as the robot yet)
    turning: TurnState | None = None
    map_g: FloatArray | None = None
    map_j: FloatArray | None = None
    _report: tuple | None = None
    _reported_yaw: float = math.nan  # the yaw (rad) its report was made at
    #: how far out (px) its blob's pixel chain lay from its silhouette at its fit
    #: (:func:`~ovis.common.solids.fit.union_offsets`)
    chain_offset: float = 0.0
    #: in a blob of several, how its parameters changed from the last frame's follow to
    #: this one's (its centre moved, its yaw turned; None: not followed yet)
    motion: FloatArray | None = None
    _linear: tuple | None = None
    #: the σ (cm) of a height known only within the range a fit allows (reported where
    #: none is measured: :func:`~ovis.common.solids.fit.height_spread`)
    h_unknown: float = math.inf

    @property
    def height(self) -> float:
        return self.h_sum / self.h_weight if self.h_weight > 0 else float(self.solid.theta[-1])

    @property
    def height_sigma(self) -> float:
        if self.h_weight <= 0:
            return math.inf
        return max(math.sqrt(1.0 / self.h_weight), self.h_floor)

    def linear(self) -> tuple[float, ...]:
        """Its centroid map as plain numbers: where it was worked out (x, y), the image
        centroid there (row, col), its Jacobian (row by row) and the centroid's bias
        (row, col); kept while the map and the bias are the same."""
        kept = self._linear
        if kept is None or kept[0] is not self.map_g or kept[1] is not self.bias:
            assert self.map_at is not None and self.map_g is not None and self.map_j is not None
            values = (*self.map_at, *self.map_g, *self.map_j.ravel(), *self.bias)
            kept = self._linear = (self.map_g, self.bias, tuple(float(v) for v in values))
        return kept[2]

    def turn(self, theta: FloatArray) -> bool:
        """Take the yaw of ``theta`` (a follow turned it); whether what it reports
        changed (its yaw by over :data:`REPORTED_TURN_DEG`)."""
        k = yaw_index(self.solid.shape)
        if k is None or theta[k] == self.solid.theta[k]:
            return False
        self.solid = self.solid._replace(theta=self.solid.theta.copy())
        self.solid.theta[k] = theta[k]
        if self._report is None or abs(theta[k] - self._reported_yaw) <= math.radians(
            REPORTED_TURN_DEG
        ):
            return False
        yaw = size_and_yaw(self.solid.shape, self.solid.theta)[2]  # the rest is kept
        self._report = (*self._report[:_YAW], yaw, *self._report[_YAW + 1 :])
        self._reported_yaw = float(theta[k])
        return True

    def turn_to(self, yaw: float) -> bool:
        """:meth:`turn` to this yaw (rad)."""
        theta = self.solid.theta.copy()
        k = yaw_index(self.solid.shape)
        if k is None:
            return False
        theta[k] = yaw
        return self.turn(theta)

    @property
    def yaw_rate(self) -> float:
        """How far (rad) it turned from the last frame to this one as last followed onto
        its outline (NaN: not followed yet, or a cylinder)."""
        k = yaw_index(self.solid.shape)
        return math.nan if k is None or self.motion is None else float(self.motion[k])

    @property
    def yaw(self) -> float:
        """Its yaw (rad; NaN: a cylinder has none)."""
        k = yaw_index(self.solid.shape)
        return math.nan if k is None else float(self.solid.theta[k])

    def ahead(self) -> FloatArray:
        """Its parameter vector where it would be were it to move (and turn) as it did
        from the last frame to this one."""
        t = self.theta()
        if self.motion is not None:
            t += self.motion
        return t

    def theta(self) -> FloatArray:
        t = self.solid.theta.copy()
        t[0:2] = self.centre
        t[-1] = self.height
        return t

    def report(self) -> tuple:
        """What a frame reports of it besides where it stands (fixed from its fit on but
        its yaw, which :meth:`turn` updates): height, its σ, covariance of (x, y, h), shape,
        equal-area radius, footprint area, yaw (deg, NaN: none), (length, width)."""
        if self._report is None:
            theta = self.theta()
            shape = self.solid.shape
            radius = float(equal_area_radius(shape, theta))
            length, width, yaw = size_and_yaw(shape, theta)
            k = yaw_index(shape)
            self._reported_yaw = math.nan if k is None else float(theta[k])
            cov = self.solid.covariance
            sigma = self.height_sigma
            if cov.size:
                pick = [0, 1, cov.shape[0] - 1]
                c3 = cov[np.ix_(pick, pick)].copy()
                if math.isfinite(sigma):
                    c3[2, :2] *= sigma / max(math.sqrt(max(cov[-1, -1], 1e-18)), 1e-9)
                    c3[2, 2] = sigma * sigma
                else:  # no height measured (its fit does not explain the outline)
                    c3[2, :2] = 0.0
                    c3[2, 2] = self.h_unknown**2
                c3[:2, 2] = c3[2, :2]
            else:
                c3 = np.full((3, 3), math.nan)
            self._report = (
                self.height,
                sigma,
                c3,
                shape,
                radius,
                math.pi * radius * radius,
                math.nan if yaw is None else yaw,
                (length, width),
            )
        return self._report


@dataclass
class _Group:
    """The solids of one blob and where the blob was (filled area, centroid)."""

    solids: list[_Tracked]
    area: float
    row: float
    col: float
    fitted: int  # the frame of the last fit
    #: several solids: how far out their outline's pixel chain lies from each (px)
    offsets: FloatArray | None = None
    #: its solids were carried in from other blobs (:meth:`SolidTracker._carry`), not
    #: fitted to it: fitted again as soon as no new blob waits
    carried: bool = False
    #: several solids: the blob (filled area, row, col, axis in the frame in deg) when
    #: they were last followed onto its outline
    followed_at: tuple[float, float, float, float] | None = None


def _sigma(solid: Solid) -> float:
    """One fit's height uncertainty (1σ, cm) as :class:`_Tracked` counts it: its
    covariance, at least its edge shift."""
    var = float(solid.covariance[-1, -1]) if solid.covariance.size else math.inf
    shift = abs(float(solid.edge_shift[-1])) if solid.edge_shift.size else math.inf
    sd = math.sqrt(var) if math.isfinite(var) and var >= 0 else math.inf
    return max(sd, shift) if math.isfinite(shift) else math.inf


def _starts_of(group: _Group | None) -> list[Solid] | None:
    """A group's solids where they stand now (a refit starts there), or None."""
    if group is None:
        return None
    return [t.solid._replace(theta=t.theta()) for t in group.solids]


class SolidObjects(NamedTuple):
    """One frame's solids, one row per solid (a blob may hold several): the blob it
    stands in, its footprint centre (cm), measured height and uncertainty (NaN: none),
    covariance of (x, y, h) (cm²), shape name ("": pending), equal-area radius and
    footprint area, yaw (deg, NaN: none), length and width, image centroid, and
    whether it is still waiting for its fit."""

    blob: NDArray[np.int64]
    xy: FloatArray
    height: FloatArray
    height_sigma: FloatArray
    covariance: FloatArray
    shape: NDArray[np.object_]
    radius: FloatArray
    area_cm2: FloatArray
    yaw_deg: FloatArray
    size: FloatArray
    row: FloatArray
    col: FloatArray
    pending: NDArray[np.bool_]


@dataclass
class _Job:
    """A fit running (or queued) on the fitting thread: the group it fits again (None: a
    new blob), the calibration it was started under, and for a new blob its filled
    (area, row, col) in the last frame that showed it (followed while it waits)."""

    done: Future[_Group | None]
    old: _Group | None
    generation: int
    blob: list[float] | None = None


class SolidTracker:
    """Blobs → solids with measured footprints and heights, kept from frame to frame
    (module docstring). ``background``: fits run on a thread of their own, the frames
    never wait for them (a live stage); ``fit_all`` (per frame): fit every blob that
    needs it this frame, here."""

    def __init__(
        self,
        camera: CameraModel,
        image: ImageParams,
        pose: PoseConfig,
        tables: PlaneTables | None = None,
        *,
        background: bool = False,
    ) -> None:
        self.groups: list[_Group] = []
        self.tables = tables
        self.frame = 0
        self._generation = 0
        self._jobs: list[_Job] = []  # on the fitting thread, in the order they run
        self._reports: _Reports | None = None
        self._turned = False  # a follow turned a solid since its reports were stacked
        self._pool = ThreadPoolExecutor(1, "solid-fit") if background else None
        self._robot: _Tracked | None = None  # the unmarked robot's solid, last frame
        self.reconfigure(camera, image, pose)

    def reconfigure(self, camera: CameraModel, image: ImageParams, pose: PoseConfig) -> None:
        """A new calibration: the solids are fitted again (a fit running is dropped, the
        ones queued behind it are not run)."""
        self.camera, self.image, self.pose = camera, image, pose
        self.view = Viewpoint.of(camera)
        self.level = float(image.threshold - NEUTRAL)
        self.spots: NDArray[np.uint8] | None = None
        self._background: NDArray[np.uint8] | None = None
        self.groups = []
        self._generation += 1
        for job in self._jobs:
            job.done.cancel()
        self._jobs = []

    def use_background(self, background: NDArray[np.uint8]) -> None:
        """The empty floor's image: its bright spots (floor marks) are no edges (worked
        out once per image)."""
        if background is not self._background:
            self._background = background
            self.spots = background_spots(background)

    def _declared(self) -> float | None:
        """The height every fit holds, when obstacles' heights are declared."""
        if "obstacle" in self.pose.declared_heights:
            return float(self.pose.obstacle_height_cm)
        return None

    # ------------------------------------------------------------------ fitting
    def _outline_fit(
        self,
        patch: Patch,
        at: tuple[float, float],
        old: list[Solid] | None,
        known: float | None = None,
    ) -> tuple[list[Solid], Outline] | None:
        """The solids of a blob's patch, fitted afresh or again from ``old``, and its
        outline. ``known``: a single solid's height its track has measured (a refit):
        a fit that pins the height is taken before one that leaves it free (which
        explains the outline by sliding along the ambiguity: a turned robot's fresh fit
        as a tall thin wall), and a fit that leaves it free is held there, not at the
        configured height (the reported height is the track's: its footprint must be
        where that height puts it)."""
        outline = patch_outline(patch, self.level, at, self.spots)
        if outline is None:
            return None
        diff = patch.diff.astype(np.float32)
        edges, normals, usable = subpixel_edges(
            diff,
            (patch.top, patch.left),
            outline.chain,
            blur_px=self.image.edge_blur_px,
            noise=self.image.noise_sigma,
            spots=self.spots,
        )
        kept = np.flatnonzero(usable)
        if kept.size < MIN_EDGE_POINTS:
            return None
        floor = floor_outline(edges[kept], normals[kept], self.camera, self.tables)
        if len(floor.points) < MIN_EDGE_POINTS:
            return None
        height = self._declared()
        fits = []
        if old is not None:
            fits.append(self._refined(old, floor, patch, diff, height, warm=True))
        if old is None or len(old) == 1:
            # a single solid's refit is also made afresh: a solid that turned since
            # (a robot) leaves a warm start's yaw in the wrong valley
            at_point = np.full(len(outline.chain), -1, dtype=np.int64)
            at_point[kept] = np.arange(kept.size)
            pieces = split_outline(outline.chain, self.spots)
            cut = [p[CUT_TRIM:-CUT_TRIM] if len(pieces) > 1 else p for p in pieces]
            mapped = [at_point[p][at_point[p] >= 0] for p in cut]
            solids = fit_blob(floor, mapped, self.view, height=height)
            found: list[FloorOutline | None] = [None] * len(solids)
            if len(solids) == 1 and height is None:
                one, edge = self._along_the_ambiguity(solids[0], floor, patch, diff, outline.chain)
                if _sigma(one) <= self.pose.height_sigma_max_cm:  # an edge that pins it
                    found[0] = edge
                solids = [one]
            fresh = self._refined(solids, floor, patch, diff, height, warm=False, tops=found)
            if old is None or len(fresh) == 1:
                fits.append(fresh)
        limit = self.pose.height_sigma_max_cm

        def free(f: list[Solid]) -> bool:
            return known is not None and len(f) == 1 and _sigma(f[0]) > limit

        best = min(fits, key=lambda f: (free(f), sum(s.rms_px for s in f)))
        sigma = _sigma(best[0])
        if height is None and len(best) == 1 and sigma > limit:
            # not measurable: its footprint where the height it is held at puts it (its
            # track's, else the configured one or lower where the frame shows it is
            # lower), unless the outline rules that out (a free height runs off toward
            # the camera)
            one = best[0]
            hold = known if known is not None else self._hold_height(one, floor, patch, diff)
            if hold < float(self.pose.obstacle_height_cm) and known is None:
                # lower than its walls show: fitted afresh at that height (a free fit
                # that ran off toward the camera leaves its start in a wrong valley)
                fresh = fit_piece(floor, self.view, [one.shape], height=hold)
                widened = held_covariance(one, fresh.theta)
                one = fresh._replace(covariance=widened, edge_shift=one.edge_shift)
            best = [held_height(one, floor, self.view, hold, sigma)]
        if height is None and len(best) > 1:
            best = self._placed_behind(best, floor)
        return [self._placed(s) for s in best], outline

    def _placed(self, solid: Solid) -> Solid:
        """``solid``, with :func:`~ovis.common.solids.fit.unplaced_covariance` where its
        fit's covariance does not place it: a fit that does not explain its outline
        (:attr:`~ovis.common.solids.fit.Solid.explains`: its covariance is that of a
        model the frame contradicts), or one not finite, not positive semi-definite as a
        near-singular fit can leave it, or with a σ of its footprint's or height's over
        the camera's height (the outline pins it nowhere)."""
        c = solid.covariance
        if c.size and solid.explains:
            pick = [0, 1, c.shape[0] - 1]
            block = c[np.ix_(pick, pick)]
            if np.isfinite(block).all():
                axes = np.linalg.eigvalsh(0.5 * (block + block.T))
                if axes[0] >= -1e-9 * max(axes[-1], 1.0) and axes[-1] <= self.view.height_cm**2:
                    return solid
        return solid._replace(covariance=unplaced_covariance(solid, self.view))

    def _placed_behind(self, solids: list[Solid], floor: FloorOutline) -> list[Solid]:
        """A blob's solids, each whose walls' foot is hidden behind the others and whose
        height is not measurable placed where the others let it stand
        (:func:`~ovis.common.solids.fit.bound_behind`: between where its footprint meets
        theirs and where its foot would show), its covariance spread over that stretch
        of the line of sight (where the joint fit left it, the outline does not say)."""
        out = list(solids)
        for k, behind in enumerate(feet_hidden(solids, self.view)):
            if behind and _sigma(solids[k]) > self.pose.height_sigma_max_cm:
                placed = bound_behind(solids, k, floor, self.view)
                out[k] = solids[k] if placed is None else placed
        return out

    def _hold_height(
        self, solid: Solid, floor: FloorOutline, patch: Patch, diff: NDArray[np.float32]
    ) -> float:
        """The height a solid whose height is not measurable is held at for its footprint:
        the configured one, unless the frame shows the solid is lower — its walls, where it
        stands, would be clearly tall enough for its top's edge to show at the configured
        height (:meth:`_thin_up_to`, :data:`CLEAR_WALLS_SHARE`), and held at the configured
        height that edge is looked for and not found. It is then no taller than walls too
        thin to show, and is held halfway up to that (a low box seen side-on: held at the
        configured height, its footprint slid toward the camera's foot by centimetres)."""
        configured = float(self.pose.obstacle_height_cm)
        thin = self._thin_up_to(solid, configured)
        if thin > CLEAR_WALLS_SHARE * configured:  # its walls there not clearly tall
            return configured
        at = held_height(solid, floor, self.view, configured, math.inf)
        found, looked = self._top_points(at, patch, diff, TOP_REACH_PX[0])
        if not looked or found is not None:
            return configured
        return 0.5 * thin

    def _thin_up_to(self, solid: Solid, up_to: float) -> float:
        """The tallest height (cm, at most ``up_to``) at which the solid's walls, where it
        stands, are too thin in the frame for its top's edge to be looked for
        (:meth:`_top_points`), by bisection (the walls grow with the height)."""

        def thin(h: float) -> bool:
            theta = solid.theta.copy()
            theta[-1] = h
            points, _ = top_near_edges(
                solid.shape, theta, self.view, self.camera, min_wall_px=MIN_WALL_PX
            )
            return len(points) < MIN_EDGE_POINTS // 2

        if thin(up_to):
            return up_to
        lo, hi = 0.0, up_to
        while hi - lo > THIN_STEP_CM:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if thin(mid) else (lo, mid)
        return lo

    def _refined(
        self,
        solids: list[Solid],
        floor: FloorOutline,
        patch: Patch,
        diff: NDArray[np.float32],
        height: float | None,
        *,
        warm: bool,
        tops: list[FloorOutline | None] | None = None,
    ) -> list[Solid]:
        """``solids`` fitted to the outline with their top faces' inner edges (a warm
        start: one look, fewer iterations). A solid whose walls a fit made too thin to
        look for that edge again (:data:`MIN_WALL_PX`) keeps the edge points an earlier
        look found: not looking is no evidence that the edge is not there (else a low
        solid's height, pinned by its top edge, runs off again with the outline alone).
        ``tops``: points found before, per solid (along the ambiguity, where they made
        the height measurable)."""
        tops = [None] * len(solids) if tops is None else list(tops)
        # a solid whose walls' foot is hidden behind another slides freely along the line
        # of sight (onto the other, in one place with it): it stays where it was fitted
        hidden = feet_hidden(solids, self.view)
        for reach in TOP_REACH_PX[-1:] if warm else TOP_REACH_PX:
            looks = [
                (None, True) if behind else self._top_points(s, patch, diff, reach)
                for s, behind in zip(solids, hidden, strict=True)
            ]
            tops = [
                t if looked else before for (t, looked), before in zip(looks, tops, strict=True)
            ]
            iterations = WARM_ITERATIONS if warm else ITERATIONS
            solids = refit_with_tops(
                solids,
                floor,
                tops,
                self.view,
                height=height,
                iterations=iterations,
                held=hidden,
            )
        return solids

    def _along_the_ambiguity(
        self,
        solid: Solid,
        floor: FloorOutline,
        patch: Patch,
        diff: NDArray[np.float32],
        chain: NDArray[np.int32],
    ) -> tuple[Solid, FloorOutline | None]:
        """Where the outline alone leaves the height free (not measurable: its σ over
        ``pose.height_sigma_max_cm``; a box seen square-on shows four lines for six
        unknowns, and a low one's wall is too thin for the inner edge to pull a far-off
        start to it), the solid fitted at each of several heights and with its top face's
        inner edge looked for where each puts it: among those that still explain the
        outline (a low solid held tall finds edges inside its top face, not its top's
        edge, and then misses its outline by pixels), one whose edge pins its height
        before one whose edge does not (a box seen square-on started far too tall shrinks
        to a sliver whose few edge points fit anything), then the one whose predicted
        edge is found most fully, then fits best. None pinning it, the top's edge where a
        wall too thin for that look shows at the silhouette (:meth:`_thin_wall_tops`),
        if it pins the height and the fit still explains the outline. The solid, and the
        top edge's points found for it (None: no search, or nothing found)."""
        sigma = math.sqrt(max(float(solid.covariance[-1, -1]), 0.0))
        if not sigma > self.pose.height_sigma_max_cm:
            return solid, None
        candidates = [solid] + [
            fit_piece(floor, self.view, [solid.shape], height=h) for h in HEIGHT_STARTS
        ]
        best: tuple[tuple[bool, float], Solid, FloorOutline] | None = None
        for c in candidates:
            start = c._replace(theta=c.theta.copy())
            tops, share = self._top_points_found(start, patch, diff, TOP_REACH_PX[0])
            if tops is None:  # no top edge where this height puts it: no evidence
                continue
            fitted = refit_with_tops([start], floor, [tops], self.view)[0]
            if solid.explains and not fitted.explains:  # an edge inside, not the top's
                continue
            pinned = _sigma(fitted) <= self.pose.height_sigma_max_cm
            score = (not pinned, (1.0 - share) + fitted.rms_px)
            if best is None or score < best[0]:
                best = (score, fitted, tops)
        if best is None or best[0][0]:  # no edge pinned it: walls too thin for a look?
            walls = self._thin_wall_tops(solid, chain, patch, diff)
            if walls is not None:
                fitted = refit_with_tops([solid], floor, [walls], self.view)[0]
                if _sigma(fitted) <= self.pose.height_sigma_max_cm and (
                    fitted.explains or not solid.explains
                ):
                    return fitted, walls
        return (solid, None) if best is None else (best[1], best[2])

    def _thin_wall_tops(
        self, solid: Solid, chain: NDArray[np.int32], patch: Patch, diff: NDArray[np.float32]
    ) -> FloorOutline | None:
        """The top face's near edge on the floor where its walls are too thin in the frame
        for :meth:`_top_points_found`'s look but show as a level of their own at the
        silhouette (:func:`~ovis.common.vision.outline.wall_tops`: the foot's step, then
        the top's), on the outline's side whose walls face the camera and inside the
        solid's silhouette; None where too few are found, or a wall shows along less than
        :data:`WALL_SHARE` of that side (a plain edge, now and then fitted with two
        steps; a face of the walls as dark as the floor)."""
        edges, normals, found = wall_tops(
            diff,
            (patch.top, patch.left),
            chain,
            blur_px=self.image.edge_blur_px,
            noise=self.image.noise_sigma,
            spots=self.spots,
        )
        if found.sum() < MIN_EDGE_POINTS // 2:
            return None

        def facing(floor: FloorOutline) -> NDArray[np.bool_]:
            rel = floor.points - self.view.foot
            to_foot = -(floor.normals * rel).sum(1)
            return to_foot > WALL_FACING_COS * np.hypot(rel[:, 0], rel[:, 1])

        floor = floor_outline(edges[found], normals[found], self.camera, self.tables)
        inside = signed_distance(solid.shape, solid.theta, floor.points, self.view) < 0.0
        keep = facing(floor) & inside
        side = int(facing(chain_floor(chain, self.camera, self.tables)).sum())
        if keep.sum() < max(MIN_EDGE_POINTS // 2, WALL_SHARE * side):
            return None
        return floor.take(keep)

    def _top_points(
        self, solid: Solid, patch: Patch, diff: NDArray[np.float32], reach: float
    ) -> tuple[FloorOutline | None, bool]:
        """:meth:`_top_points_found`'s points, and whether the solid's walls are tall
        enough in the frame, along enough of its top's inner edge, for that edge to be
        looked for at all (a low box seen side-on: its walls reach :data:`MIN_WALL_PX`
        along too few pixels for a look to find the points a fit needs)."""
        points, _ = top_near_edges(
            solid.shape, solid.theta, self.view, self.camera, min_wall_px=MIN_WALL_PX
        )
        if len(points) < MIN_EDGE_POINTS // 2:
            return None, False
        return self._top_points_found(solid, patch, diff, reach)[0], True

    def _top_points_found(
        self, solid: Solid, patch: Patch, diff: NDArray[np.float32], reach: float
    ) -> tuple[FloorOutline | None, float]:
        """Where the solid's top face meets its walls inside its silhouette, found near
        where the fit puts that edge, on the floor."""
        points, normals = top_near_edges(
            solid.shape, solid.theta, self.view, self.camera, min_wall_px=MIN_WALL_PX
        )
        if not len(points):
            return None, 0.0
        edges, found = edges_along(
            diff,
            (patch.top, patch.left),
            points,
            normals,
            blur_px=self.image.edge_blur_px,
            reach_px=reach,
            spots=self.spots,
        )
        if found.sum() < MIN_EDGE_POINTS // 2:
            return None, 0.0
        floor = floor_outline(edges[found], normals[found], self.camera, self.tables)
        # the top's inner edge lies inside the silhouette: an edge found at the silhouette
        # (the walls' foot, strongest at a bright wall) is not it
        inside = floor.px_per_cm * signed_distance(
            solid.shape, solid.theta, floor.points, self.view
        )
        keep = inside < -TOP_INSIDE_PX
        if keep.sum() < MIN_EDGE_POINTS // 2:
            return None, 0.0
        return floor.take(keep), float(keep.sum()) / len(points)

    def _rough(self, patch: Patch, blob_filled: FloatArray) -> RoughFootprint | None:
        """A blob still waiting for its fit: its footprint centre roughly, and where it
        may be, from its outline's pixel chain (:func:`rough_footprint`), or None."""
        outline = patch_outline(patch, self.level, (blob_filled[1], blob_filled[2]), self.spots)
        if outline is None or len(outline.chain) < MIN_EDGE_POINTS:
            return None
        return rough_footprint(self._chain_floor(outline), self.view)

    def _robot_misfit(self, patch: Patch, blob_filled: FloatArray) -> float:
        """How far (rms px) a blob's outline's pixel chain is from the silhouette of the
        configured unmarked robot (``robot_size_cm`` × ``robot_height_cm``) standing
        where it fits best (:func:`~ovis.common.solids.fit.robot_misfit`); inf where
        the blob has no outline."""
        outline = patch_outline(patch, self.level, (blob_filled[1], blob_filled[2]), self.spots)
        if outline is None or len(outline.chain) < MIN_EDGE_POINTS:
            return math.inf
        size = (max(self.pose.robot_size_cm), min(self.pose.robot_size_cm))
        floor = self._chain_floor(outline)
        return robot_misfit(floor, self.view, size, float(self.pose.robot_height_cm))

    def _chain_floor(self, outline: Outline) -> FloorOutline:
        """An outline's pixel chain itself on the floor (no sub-pixel edges)."""
        return chain_floor(outline.chain, self.camera, self.tables)

    def _new_tracked(self, solid: Solid, before: _Tracked | None) -> _Tracked:
        """A solid as fitted now, its height averaged with its earlier fits'."""
        var = float(solid.covariance[-1, -1]) if solid.covariance.size else math.inf
        w = 1.0 / var if math.isfinite(var) and var > 0 else 0.0
        h = float(solid.theta[-1])
        floor = abs(float(solid.edge_shift[-1])) if solid.edge_shift.size else math.inf
        if not math.isfinite(floor) or not solid.explains:
            # a fit that leaves this many edge points unexplained did not find what the
            # outline is (two solids taken for one, a wrong shape): no height measured
            floor = math.inf
        w_sum, h_sum = w, w * h
        if before is not None:
            w_sum, h_sum = before.h_weight + w, before.h_sum + w * h
            floor = min(before.h_floor, floor)
        return _Tracked(
            solid, w_sum, h_sum, floor, solid.theta[:2].copy(), h_unknown=height_spread(self.view)
        )

    def _fit(self, patch: Patch, blob_filled: FloatArray, group: _Group | None) -> _Group | None:
        """Fit (or fit again) one blob; its group with the offsets of its solids' image
        centroids from the blob's and their centroid maps worked out."""
        return self._fit_from(patch, blob_filled, group, _starts_of(group), self.frame)

    def _fit_from(
        self,
        patch: Patch,
        blob_filled: FloatArray,
        group: _Group | None,
        old: list[Solid] | None,
        frame: int,
    ) -> _Group | None:
        """:meth:`_fit` from ``old`` (the group's solids where they stood when it was
        asked for: the frames move them on meanwhile), as of ``frame``."""
        row, col = float(blob_filled[1]), float(blob_filled[2])
        found = self._outline_fit(patch, (row, col), old, self._measured_height(group))
        if found is None or not found[0]:
            return None
        solids, outline = found
        if (
            group is not None
            and all(t.solid.explains for t in group.solids)
            and not all(s.explains for s in solids)
        ):
            return None  # a refit explains its blob worse than the solids it had: keep them
        before = group.solids if group is not None and len(group.solids) == len(solids) else None
        tracked = [
            self._new_tracked(s, before[k] if before is not None else None)
            for k, s in enumerate(solids)
        ]
        for t in tracked:
            self._map(t)
        now = [t.solid._replace(theta=t.theta()) for t in tracked]
        offsets = union_offsets(now, self._chain_floor(outline), self.view)
        for t, offset in zip(tracked, offsets.tolist(), strict=True):
            t.chain_offset = offset
        if len(tracked) == 1:
            t = tracked[0]
            assert t.map_g is not None
            t.bias = t.map_g - np.array([row, col])
            offsets = None
        return _Group(tracked, float(blob_filled[0]), row, col, frame, offsets)

    def _measured_height(self, group: _Group | None) -> float | None:
        """The height a group's single solid has measured over its track, or None (a
        new blob, several solids, not measurable, declared)."""
        if group is None or len(group.solids) != 1 or self._declared() is not None:
            return None
        t = group.solids[0]
        return t.height if t.height_sigma <= self.pose.height_sigma_max_cm else None

    def _map(self, t: _Tracked) -> None:
        """Work out a solid's centroid map where it stands now."""
        g, j = centroid_map(t.solid.shape, t.theta()[None], self.view, self.camera)
        t.map_at, t.map_g, t.map_j, t.map_yaw = t.centre, g[0], j[0], t.yaw

    # ------------------------------------------------------------------ per frame
    def update(
        self,
        filled: FloatArray,
        patches: Sequence[Patch] | None,
        fallback: Callable[[], PixelJacobian],
        skip: NDArray[np.bool_],
        *,
        fit_all: bool = False,
        moments: FloatArray | None = None,
        dt_s: float = math.inf,
    ) -> SolidObjects:
        """This frame's solids from its blobs' filled (area, row, col) (n, 3), their
        patches, their centroids on their class's plane (``fallback``, asked for when a
        blob waits for its fit) and the blobs that are no solid to fit (marked
        robots'); ``moments``: the blobs' central second moments (n, 3: row-row,
        col-col, row-col; px²), whose axis tells how the unmarked robot turned; ``dt_s``:
        the time since the last frame."""
        self.frame += 1
        n = len(filled)
        self._collect()
        self._relink_robot()
        rows, skips = filled.tolist(), skip.tolist()  # a frame's few blobs: plain numbers
        matched = self._match(rows, skips)
        if patches is not None:
            self._carry(rows, matched, skips, patches)
        self._follow_waiting(rows, matched, skips)
        limit = math.inf if fit_all or self.pose.fits_per_frame == 0 else self.pose.fits_per_frame
        beside = self._pool is not None and not fit_all
        if beside:
            limit = 1 if not self._jobs and patches is not None else 0
        todo = self._queue(filled, matched, skips, patches, limit)
        new_groups: dict[int, _Group] = {}
        fitted = set()
        if beside:
            if todo and limit and patches is not None:
                # a new blob's fit, and every other new blob's queued behind it (the
                # fitting thread goes from one to the next, not one a frame); else a
                # refit
                first = todo[0]
                batch = [first] if matched[first] >= 0 else [i for i in todo if matched[i] < 0]
                for i in batch:
                    group = self.groups[matched[i]] if matched[i] >= 0 else None
                    self._submit(patches[i], filled[i], group)
            todo = []
        for i in todo:
            if len(fitted) >= limit or patches is None:
                break
            group = self.groups[matched[i]] if matched[i] >= 0 else None
            g = self._fit(patches[i], filled[i], group)
            fitted.add(i)
            if g is not None:
                new_groups[i] = g
            elif group is not None:  # nothing better found: kept, and followed this frame
                group.fitted, group.carried = self.frame, False
        fitted &= set(new_groups)
        for i in range(n):
            if i in new_groups or matched[i] < 0 or skips[i]:
                continue
            new_groups[i] = self.groups[matched[i]]
        axes = _axes(moments, n)
        robot = self._lone_robot(new_groups, fitted, patches)
        if robot >= 0:
            assert patches is not None
            blob = rows[robot]
            self._follow_robot(new_groups[robot], patches, robot, blob, axes[robot], dt_s)
        self._follow(rows, new_groups, fitted | {robot})
        for i, g in new_groups.items():
            several = i not in fitted and len(g.solids) > 1 and patches is not None
            if several and self._moved(g, rows[i], axes[i]):
                assert patches is not None
                self._follow_group(g, patches, i, filled[i], dt_s)
        for i, g in new_groups.items():
            g.area, g.row, g.col = rows[i]
        self.groups = list(new_groups.values())
        return self._objects(filled, rows, new_groups, fallback, skips, patches)

    def _lone_robot(
        self, groups: dict[int, _Group], fitted: set[int], patches: Sequence[Patch] | None
    ) -> int:
        """The blob (not fitted this frame) that holds the unmarked robot alone, or −1."""
        if self._robot is None or patches is None:
            return -1
        for i, g in groups.items():
            if i not in fitted and len(g.solids) == 1 and g.solids[0] is self._robot:
                return i
        return -1

    def _follow_robot(
        self,
        group: _Group,
        patches: Sequence[Patch],
        i: int,
        blob: list[float],
        axis: float,
        dt_s: float,
    ) -> None:
        """The unmarked robot alone in blob ``i`` (its filled area, row, col: ``blob``;
        its axis in the frame ``axis``, deg, NaN: not known), which turns as it drives:
        its yaw as :func:`~ovis.common.world.robot_turn.robot_turn` says (by its axis
        only where that puts it within ``AXIS_CHECK_DEG`` of where its last turn rate
        does: else a blob's axis thrown by something else, turned to its outline), and
        its centre from its blob's centroid (less its bias) at that yaw, by its pose
        map."""
        t = group.solids[0]
        if t.turning is None:
            t.turning = TurnState()
        turning = t.turning
        at = (axis, blob[1], blob[2])
        how = robot_turn(turning.pose_map, turning.turned_at, at, dt_s, t.yaw_rate, turning.coasted)
        bias = t.bias.tolist()
        target = (blob[1] + bias[0], blob[2] + bias[1])
        if how == "axis":
            seen = math.radians(axis) + turning.axis_bias
            got = self._robot_map(t).solve((*target, seen), t.yaw)
            ahead = t.yaw + (t.yaw_rate if math.isfinite(t.yaw_rate) else 0.0)
            if got is not None and abs(got[2] - ahead) <= math.radians(AXIS_CHECK_DEG):
                t.centre = got[0:2]
                self._turned |= t.turn_to(got[2])
                return
            how = "outline"  # the axis tells a turn the robot cannot have made
        if how == "coast":
            turning.coasted = True
            self._turned |= t.turn_to(t.yaw + t.yaw_rate)
        elif how == "outline":
            turning.coasted = False
            turning.turned_at = at
            self._follow_group(group, patches, i, np.array(blob), dt_s)
            seen = self._robot_map(t).image_at(t.centre, t.yaw)[2]
            turning.axis_bias = float(turn_between(math.radians(axis), seen))
        got = self._robot_map(t).solve((*target, None), t.yaw)
        if got is not None:
            t.centre = got[0:2]

    def _robot_map(self, t: _Tracked) -> PoseMap:
        """The robot's pose map, worked out again where it moved or turned far from where
        it was."""
        assert t.turning is not None
        m = t.turning.pose_map
        if (
            m is None
            or math.dist(t.centre, m.at[:2]) > RELINEARISE_CM
            or abs(t.yaw - m.at[2]) > math.radians(AXIS_REACH_DEG)
        ):
            m = self._pose_map(t)
        return m

    def _pose_map(self, t: _Tracked) -> PoseMap:
        """Work out the robot's pose map where it stands now."""
        assert t.turning is not None
        t.turning.pose_map = PoseMap.of(t.solid.shape, t.theta(), self.view, self.camera)
        return t.turning.pose_map

    @staticmethod
    def _moved(group: _Group, blob: list[float], axis: float) -> bool:
        """Whether a blob of several solids moved (area, centroid or axis: ``blob`` is
        its filled (area, row, col)) beyond ``STILL_PX``, :data:`STILL_AREA_SHARE` and
        ``TURN_CHECK_DEG`` since its solids were last followed; if so, it is
        noted as followed now."""
        now = (blob[0], blob[1], blob[2], axis)
        was = group.followed_at
        if (
            was is not None
            and math.hypot(now[1] - was[1], now[2] - was[2]) <= STILL_PX
            and abs(now[0] - was[0]) <= STILL_AREA_SHARE * was[0]
            and abs(degrees_between(was[3], now[3])) <= TURN_CHECK_DEG
        ):
            return False
        group.followed_at = now
        return True

    def _relink_robot(self) -> None:
        """After a refit replaced the unmarked robot's group: the refitted solid standing
        where the robot stood (within :data:`RELINEARISE_CM`) is the robot."""
        robot = self._robot
        if robot is None or any(t is robot for g in self.groups for t in g.solids):
            return
        near = [
            t
            for g in self.groups
            for t in g.solids
            if t.solid.shape == robot.solid.shape
            and math.dist(t.centre, robot.centre) <= RELINEARISE_CM
        ]
        self._robot = min(near, key=lambda t: math.dist(t.centre, robot.centre), default=None)

    def note_robot(self, found: SolidObjects, row: int) -> None:
        """Keep which solid is the unmarked robot this frame: row ``row`` of ``found``
        (:func:`robot_row`, as the detection found it; −1: none; none kept with marked
        robots)."""
        self._robot = None
        if self.pose.robots or row < 0 or found.pending[row]:
            return
        at = found.xy[row].tolist()
        for g in self.groups:
            for t in g.solids:
                if [float(v) for v in t.centre] == at:
                    self._robot = t
                    return

    def close(self) -> None:
        """Stop the fitting thread (a fit running is waited for, none started again)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._jobs = []

    def wait(self) -> None:
        """Wait until the fits on the fitting thread, if any, are done (they join the
        groups at the next frame)."""
        for job in self._jobs:
            job.done.exception()

    def _submit(self, patch: Patch, blob_filled: FloatArray, group: _Group | None) -> None:
        """Queue one blob's fit on the fitting thread."""
        assert self._pool is not None
        done = self._pool.submit(
            self._fit_from, patch, blob_filled.copy(), group, _starts_of(group), self.frame
        )
        blob = None if group is not None else blob_filled.tolist()
        self._jobs.append(_Job(done, group, self._generation, blob))

    def _follow_waiting(
        self, rows: list[list[float]], matched: list[int], skip: list[bool]
    ) -> None:
        """Where each new blob whose fit waits on the fitting thread is this frame: among
        the blobs no group holds, the same blob as :meth:`_match` finds a group's
        (:func:`_same_blobs`), so that its fit joins the groups where it stands when it
        lands (a queued fit may land frames later)."""
        waiting = [job for job in self._jobs if job.blob is not None]
        free = [i for i, m in enumerate(matched) if m < 0 and not skip[i]]
        was = [job.blob for job in waiting if job.blob is not None]
        for r, c in _same_blobs(was, [rows[i] for i in free]):
            waiting[r].blob = list(rows[free[c]])

    def _collect(self) -> None:
        """The fits done on the fitting thread, in the order they ran, join the groups (a
        new blob's where it was last seen, a refit replacing the group it fitted again,
        where that group stands now); one started under an earlier calibration is
        dropped."""
        while self._jobs and self._jobs[0].done.done():
            self._join(self._jobs.pop(0))

    def _join(self, job: _Job) -> None:
        """One fit done on the fitting thread joins the groups (:meth:`_collect`)."""
        fitted = job.done.result()  # a fit's error is the frame's, as when fitted here
        if job.generation != self._generation:
            return
        if job.old is None:
            if fitted is not None:
                assert job.blob is not None
                fitted.area, fitted.row, fitted.col = job.blob
                self.groups.append(fitted)
            return
        if not any(g is job.old for g in self.groups):
            return  # its blob was lost meanwhile
        if fitted is None:  # nothing better found: not again straight away
            job.old.fitted, job.old.carried = self.frame, False
            return
        # found again where the old group is now; its solids followed from where they
        # were fitted (their offsets from the blob's centroid are the fit's)
        fitted.area, fitted.row, fitted.col = job.old.area, job.old.row, job.old.col
        self.groups = [fitted if g is job.old else g for g in self.groups]

    def _match(self, rows: list[list[float]], skip: list[bool]) -> list[int]:
        """Each blob's group of last frame (−1: none), from the blobs' filled (area, row,
        col)."""
        out = [-1] * len(rows)
        was = [(g.area, g.row, g.col) for g in self.groups]
        for r, c in _same_blobs(was, rows):
            if not skip[c]:
                out[c] = r
        return out

    def _carry(
        self,
        rows: list[list[float]],
        matched: list[int],
        skip: list[bool],
        patches: Sequence[Patch],
    ) -> None:
        """Known solids into the blobs that are new this frame because solids met or
        parted in the image: each solid of a group no blob matched goes to the new blob
        whose outline holds its image (its footprint centre at half its height, where it
        moved to), and the solids of a blob are followed onto its outline
        (:meth:`_placed_union`); a blob whose outline they do not explain (a solid new to
        the view among them) waits for its fit. Carried blobs join the groups and
        ``matched`` (their heights, measured over their tracks, are kept)."""
        taken = set(matched)
        lost = [g for r, g in enumerate(self.groups) if r not in taken]
        new = [i for i, m in enumerate(matched) if m < 0 and not skip[i]]
        if not lost or not new:
            return
        solids = [t for g in lost for t in g.solids]
        ahead = np.array([t.ahead()[[0, 1, -1]] for t in solids])
        seen = project(ahead[:, 0], ahead[:, 1], 0.5 * ahead[:, -1], self.camera)
        outlines = {}
        best: dict[int, tuple[float, int]] = {}  # solid → (depth inside, blob)
        for i in new:
            outline = blob_outline(patches, i, self.level, (rows[i][1], rows[i][2]), self.spots)
            if outline is None or len(outline.chain) < MIN_EDGE_POINTS:
                continue
            outlines[i] = outline
            contour = outline.chain.reshape(-1, 1, 2).astype(np.float32)
            for k in range(len(solids)):
                if not seen.valid[k]:
                    continue
                at = (float(seen.col[k]), float(seen.row[k]))
                depth = cv2.pointPolygonTest(contour, at, True)
                if depth >= 0.0 and depth > best.get(k, (-1.0, -1))[0]:
                    best[k] = (depth, i)
        by_blob: dict[int, list[int]] = {}
        for k, (_, i) in best.items():
            by_blob.setdefault(i, []).append(k)
        fitted = min((g.fitted for g in lost), default=self.frame)
        for i, ks in by_blob.items():
            group = self._placed_union([solids[k] for k in ks], outlines[i], rows[i], fitted)
            if group is not None:
                self.groups.append(group)
                matched[i] = len(self.groups) - 1

    def _placed_union(
        self, solids: list[_Tracked], outline: Outline, at: list[float], fitted: int
    ) -> _Group | None:
        """A group of known solids carried into a blob (:meth:`_carry`): followed from
        where they would be now onto its outline's pixel chain, each edge as far out as
        at its fit; a solid that was alone in its blob (its yaw not followed since its
        fit: a robot may have turned) tried at other yaws too (:data:`CARRY_TURNS_DEG`)
        where they do not fit as they were. None where the union leaves over
        :data:`~ovis.common.solids.fit.MAX_OFF_SHARE` of the chain more than
        :data:`CARRY_OFF_PX` off (they are not all that blob holds)."""
        floor = self._chain_floor(outline)
        offsets = np.array([t.chain_offset for t in solids])
        ahead = [t.solid._replace(theta=t.ahead()) for t in solids]
        starts = [ahead]
        for k, t in enumerate(solids):
            yi = yaw_index(t.solid.shape)
            if yi is None or t.motion is not None:
                continue
            for turn in CARRY_TURNS_DEG:
                theta = ahead[k].theta.copy()
                theta[yi] += math.radians(turn)
                starts.append([*ahead[:k], ahead[k]._replace(theta=theta), *ahead[k + 1 :]])
        for start in starts:
            now = follow_union_steps(start, offsets, floor, self.view, CARRY_STEPS, FOLLOW_TOL_CM)
            d = np.stack(
                [
                    floor.px_per_cm * signed_distance(s.shape, s.theta, floor.points, self.view)
                    - offsets[k]
                    for k, s in enumerate(now)
                ]
            ).min(0)
            if np.mean(np.abs(d) > CARRY_OFF_PX) <= MAX_OFF_SHARE:
                break
        else:
            return None
        for t, s in zip(solids, now, strict=True):
            t.centre = s.theta[0:2]
            t.motion = None
            t.turn(s.theta)
            if t.turning is not None:  # a robot among them: turned to its outline next
                t.turning.turned_at = (math.nan,) * 3
            self._map(t)
        self._reports = None
        row, col = at[1], at[2]
        if len(solids) == 1:
            t = solids[0]
            assert t.map_g is not None
            t.bias = t.map_g - np.array([row, col])
            return _Group(solids, at[0], row, col, fitted, carried=True)
        return _Group(solids, at[0], row, col, fitted, offsets, carried=True)

    def _queue(
        self,
        filled: FloatArray,
        matched: list[int],
        skip: list[bool],
        patches: Sequence[Patch] | None,
        limit: float,
    ) -> list[int]:
        """The blobs to fit this frame, first first: new blobs — where more wait than
        ``limit`` fits this frame, the one most like the unmarked robot first (until its
        fit lands the robot is reported as an obstacle: :meth:`_robot_misfit`), the
        larger first among equals —, then blobs whose solids were carried in
        (:meth:`_carry`), then, every :data:`REFIT_FRAMES` frames, the known blob fitted
        longest ago."""
        new = [i for i in range(len(filled)) if matched[i] < 0 and not skip[i]]
        if 0 < limit < len(new) and patches is not None and not self.pose.robots:
            misfit = [self._robot_misfit(patches[i], filled[i]) for i in new]
            order = np.lexsort((-filled[new, 0], np.array(misfit)))
            new = [new[k] for k in order]
        else:
            new.sort(key=lambda i: -filled[i, 0])
        known = [i for i in range(len(filled)) if matched[i] >= 0]
        carried = [i for i in known if self.groups[matched[i]].carried]
        new.extend(sorted(carried, key=lambda i: self.groups[matched[i]].fitted))
        if known and self.frame % REFIT_FRAMES == 0:
            oldest = min(known, key=lambda i: self.groups[matched[i]].fitted)
            if oldest not in carried:
                new.append(oldest)
        return new

    def _follow(self, rows: list[list[float]], groups: dict[int, _Group], fitted: set[int]) -> None:
        """Move the single solids not fitted this frame to where their blob's centroid
        says (their maps worked out again where they moved far): one linear step of
        :func:`~ovis.common.solids.footprint.solve_centres` each, in plain Python (a
        frame's few solids: a dozen array calls cost more than the arithmetic)."""
        moving = [
            (g.solids[0], i) for i, g in groups.items() if i not in fitted and len(g.solids) == 1
        ]
        if not moving:
            return
        by_shape: dict[str, list[_Tracked]] = {}
        for t, _ in moving:
            if (
                t.map_at is None
                or math.dist(t.centre, t.map_at) > RELINEARISE_CM
                or abs(t.yaw - t.map_yaw) > RELINEARISE_RAD  # turned where it stands
            ):
                by_shape.setdefault(t.solid.shape, []).append(t)
        for shape, ts in by_shape.items():
            g, j = centroid_map(shape, np.array([t.theta() for t in ts]), self.view, self.camera)
            for k, t in enumerate(ts):
                t.map_at, t.map_g, t.map_j, t.map_yaw = t.centre, g[k], j[k], t.yaw
        for t, i in moving:
            t.centre = _solve_centre(t.linear(), rows[i][1], rows[i][2])

    def _follow_group(
        self,
        group: _Group,
        patches: Sequence[Patch],
        i: int,
        blob_filled: FloatArray,
        dt_s: float = math.inf,
    ) -> None:
        """Move a blob's several solids (blob ``i``'s) to where its outline's pixel chain
        puts their union (shapes and heights kept): one Gauss–Newton step where frames
        come within :data:`ONE_STEP_S` (``dt_s`` since the last), else up to
        :data:`FOLLOW_STEPS`."""
        at = (float(blob_filled[1]), float(blob_filled[2]))
        outline = blob_outline(patches, i, self.level, at, self.spots)
        if outline is None or len(outline.chain) < MIN_EDGE_POINTS:
            return
        offsets = group.offsets
        if offsets is None:  # one solid (the robot): its edge as far out as at its fit
            offsets = np.array([t.chain_offset for t in group.solids])
        floor = chain_floor(outline.chain, self.camera, self.tables, closed_form=True)
        was = [t.theta() for t in group.solids]
        now = [t.solid._replace(theta=t.ahead()) for t in group.solids]
        # only a robot turns: the unmarked one, or any solid where marked robots stand
        turning = [bool(self.pose.robots) or t is self._robot for t in group.solids]
        steps = 1 if dt_s <= ONE_STEP_S else FOLLOW_STEPS
        now = follow_union_steps(now, offsets, floor, self.view, steps, FOLLOW_TOL_CM, turning)
        for t, s, before in zip(group.solids, now, was, strict=True):
            t.centre = s.theta[0:2]
            t.motion = s.theta - before
            if t.turn(s.theta):
                self._turned = True

    def _objects(
        self,
        filled: FloatArray,
        rows_of: list[list[float]],
        groups: dict[int, _Group],
        fallback: Callable[[], PixelJacobian],
        skip: list[bool],
        patches: Sequence[Patch] | None = None,
    ) -> SolidObjects:
        """This frame's :class:`SolidObjects` from its blobs' filled (area, row, col),
        as an array and as lists (``rows_of``), and their groups."""
        solids = [(i, t, len(g.solids) > 1) for i, g in groups.items() for t in g.solids]
        if solids and len(groups) == len(filled) - skip.count(True):
            return self._followed(rows_of, sorted(solids, key=lambda s: s[0]))
        rows: list[tuple] = []
        plane: PixelJacobian | None = None
        for i in range(len(filled)):
            if skip[i]:
                continue
            g = groups.get(i)
            if g is None:  # waiting for its fit: where today's method puts it
                plane = fallback() if plane is None else plane
                if not bool(plane.valid[i]):
                    continue
                xy = (float(plane.x_cm[i]), float(plane.y_cm[i]))
                cov = np.full((3, 3), math.nan)  # none stated: on the class's plane
                rough = None if patches is None else self._rough(patches[i], filled[i])
                if rough is not None:  # its height anywhere within a fit's range
                    xy = (float(rough.centre[0]), float(rough.centre[1]))
                    cov = np.zeros((3, 3))
                    cov[:2, :2] = rough.covariance
                    cov[2, 2] = height_spread(self.view) ** 2
                area = float(filled[i, 0] * plane.area_cm2[i])
                rows.append(
                    (
                        i,
                        xy,
                        math.nan,
                        math.nan,
                        cov,
                        "",
                        math.sqrt(area / math.pi),
                        area,
                        math.nan,
                        (math.nan, math.nan),
                        float(filled[i, 1]),
                        float(filled[i, 2]),
                        True,
                    )
                )
                continue
            for t in g.solids:
                r, c = (float(filled[i, 1]), float(filled[i, 2]))
                if len(g.solids) > 1 and t.map_g is not None:
                    r, c = float(t.map_g[0]), float(t.map_g[1])
                at = (float(t.centre[0]), float(t.centre[1]))
                rows.append((i, at, *t.report(), r, c, False))
        if not rows:
            z = np.zeros(0)
            return SolidObjects(
                np.zeros(0, dtype=np.int64),
                np.zeros((0, 2)),
                z,
                z,
                np.zeros((0, 3, 3)),
                np.zeros(0, dtype=object),
                z,
                z,
                z,
                np.zeros((0, 2)),
                z,
                z,
                np.zeros(0, dtype=bool),
            )
        cols = list(zip(*rows, strict=True))
        kinds = (np.int64, *[np.float64] * 4, object, *[np.float64] * 6, bool)
        return SolidObjects(*(np.array(c, dtype=k) for c, k in zip(cols, kinds, strict=True)))

    def _followed(
        self, rows: list[list[float]], solids: list[tuple[int, _Tracked, bool]]
    ) -> SolidObjects:
        """:meth:`_objects` where no blob waits for its fit: ``solids`` (blob, solid,
        whether its blob holds several) in blob order. What a solid reports besides where
        it stands is fixed from its fit on but its yaw: stacked once (:class:`_Reports`)
        and kept while the frames hold the same solids, the yaws again where one turned."""
        ts = [t for _, t, _ in solids]
        reports = self._reports
        if reports is None or not _same(ts, reports.solids):
            reports = self._reports = _Reports.of(ts)
        elif self._turned:
            reports = self._reports = reports.turned()
        self._turned = False
        rc = [
            t.map_g.tolist() if several and t.map_g is not None else rows[i][1:]
            for i, t, several in solids
        ]
        row, col = zip(*rc, strict=True)
        return SolidObjects(
            blob=np.array([i for i, _, _ in solids], dtype=np.int64),
            xy=np.array([t.centre for t in ts], dtype=np.float64),
            row=np.array(row, dtype=np.float64),
            col=np.array(col, dtype=np.float64),
            **reports.columns,
        )


def _same_blobs(
    was: Sequence[Sequence[float]], now: Sequence[Sequence[float]]
) -> list[tuple[int, int]]:
    """(earlier, now) index pairs of the same blobs, from their filled (area, row, col):
    centroids paired within :data:`GATE_PX` (the fewest-moves assignment), areas within
    :data:`AREA_RATIO` of each other."""
    if not was or not now:
        return []
    last = [(w[1], w[2]) for w in was]
    pairs = gated_pairs_few(last, [(r[1], r[2]) for r in now], GATE_PX)
    if pairs is None:
        at = np.array([(r[1], r[2]) for r in now])
        r_, c_ = gated_assignment(np.array(last), at, GATE_PX)
        pairs = list(zip(r_.tolist(), c_.tolist(), strict=True))
    return [
        (r, c)
        for r, c in pairs
        if 1.0 / AREA_RATIO <= now[c][0] / max(was[r][0], 1e-9) <= AREA_RATIO
    ]


def _axes(moments: FloatArray | None, n: int) -> list[float]:
    """The blobs' axes in the frame (deg) from their central second moments (n, 3:
    row-row, col-col, row-col; NaN: none given)."""
    if moments is None:
        return [math.nan] * n
    return [axis_deg(rr, cc, rc) for rr, cc, rc in moments.tolist()]


def _solve_centre(linear: tuple[float, ...], row: float, col: float) -> tuple[float, float]:
    """:func:`~ovis.common.solids.footprint.solve_centres` for one solid, in plain Python
    (the same operations in the same order): the footprint centre whose image centroid
    is (``row``, ``col``) less its bias, by one linear step of its map
    (:meth:`_Tracked.linear`); a singular map keeps the centre."""
    ax, ay, gr, gc, j00, j01, j10, j11, b0, b1 = linear
    det = j00 * j11 - j01 * j10
    ok = math.isfinite(det) and abs(det) > 1e-9 and math.isfinite(gr) and math.isfinite(gc)
    e0, e1 = ((row + b0) - gr, (col + b1) - gc) if ok else (0.0, 0.0)
    safe = det if ok else 1.0
    dx = (j11 * e0 - j01 * e1) / safe
    dy = (-j10 * e0 + j00 * e1) / safe
    return ax + dx, ay + dy


def _same(a: list[_Tracked], b: list[_Tracked]) -> bool:
    """Whether two lists hold the same solids (the same objects: a refit makes new ones),
    in the same order."""
    return len(a) == len(b) and all(x is y for x, y in zip(a, b, strict=True))


#: The :class:`SolidObjects` columns of :meth:`_Tracked.report`, in its order, and their
#: element types.
_REPORTED = ("height", "height_sigma", "covariance", "shape", "radius", "area_cm2",
             "yaw_deg", "size")  # fmt: skip
_REPORTED_KINDS = (*[np.float64] * 3, object, *[np.float64] * 4)
_YAW = _REPORTED.index("yaw_deg")


class _Reports(NamedTuple):
    """:meth:`_Tracked.report` of a frame's solids stacked as :class:`SolidObjects`'
    columns (:data:`_REPORTED`, and ``pending`` all false), read only: shared by the
    frames that hold the same solids."""

    solids: list[_Tracked]
    columns: dict[str, NDArray]

    @classmethod
    def of(cls, solids: list[_Tracked]) -> _Reports:
        cols = zip(*(t.report() for t in solids), strict=True)
        arrays = [np.array(c, dtype=k) for c, k in zip(cols, _REPORTED_KINDS, strict=True)]
        columns = dict(zip(_REPORTED, arrays, strict=True))
        columns["pending"] = np.zeros(len(solids), dtype=bool)
        for a in columns.values():
            a.flags.writeable = False
        return cls(solids, columns)

    def turned(self) -> _Reports:
        """These reports with each solid's yaw as it reports it now (a follow turned
        one); the other columns are the same arrays."""
        yaw = np.array([t.report()[_YAW] for t in self.solids], dtype=np.float64)
        yaw.flags.writeable = False
        return _Reports(self.solids, {**self.columns, "yaw_deg": yaw})


#: The unmarked robot's footprint is within this share of its configured length and
#: width, and its measured height within this (cm) or two of its σ, whichever is more.
ROBOT_SIZE_SHARE = 0.2
ROBOT_HEIGHT_CM = 1.5


def measurable(found: SolidObjects, pose: PoseConfig) -> NDArray[np.bool_]:
    """Which solids' heights count as measured (fitted, σ within the limit)."""
    sigma = np.where(np.isfinite(found.height_sigma), found.height_sigma, np.inf)
    return ~found.pending & (sigma <= pose.height_sigma_max_cm)


def robot_row(found: SolidObjects, pose: PoseConfig) -> int:
    """The solid that is the unmarked robot — the box nearest ``robot_size_cm`` and
    ``robot_height_cm`` within the tolerances above (the height only where measured) —
    or −1."""
    if not found.blob.size:
        return -1
    long, short = max(pose.robot_size_cm), min(pose.robot_size_cm)
    dl = (found.size[:, 0] - long) / (ROBOT_SIZE_SHARE * long)
    dw = (found.size[:, 1] - short) / (ROBOT_SIZE_SHARE * short)
    known = measurable(found, pose)
    tol = np.maximum(ROBOT_HEIGHT_CM, 2.0 * np.where(known, found.height_sigma, 0.0))
    dh = np.where(known, (found.height - pose.robot_height_cm) / tol, 0.0)
    fits = (found.shape == "box") & (np.abs(dl) <= 1) & (np.abs(dw) <= 1) & (np.abs(dh) <= 1)
    score = np.where(fits, dl * dl + dw * dw + dh * dh, np.inf)
    best = int(score.argmin())
    return best if np.isfinite(score[best]) else -1


def with_heights(pose: PoseConfig, heights: str | None, declared: list[str]) -> PoseConfig:
    """``pose`` with a heights mode ("measured" or "configured") and heights declared
    as ``CLASS=CM`` (``robot=5``, ``obstacle=7``: that class's height, not measured) or
    ``marker:ID=CM`` (the marked robot with that marker carries it that high). Raises
    ValueError naming what is wrong."""
    import msgspec

    fields: dict[str, object] = {}
    if heights is not None:
        if heights not in ("measured", "configured"):
            raise ValueError(f"--heights must be 'measured' or 'configured', got {heights!r}")
        fields["heights"] = heights
    classes = list(pose.declared_heights)
    robots = list(pose.robots)
    for text in declared:
        name, sep, value = text.partition("=")
        name = name.strip().lower()
        try:
            cm = float(value)
        except ValueError:
            cm = math.nan
        if not sep or not math.isfinite(cm) or not 0.0 <= cm <= 1e4:
            raise ValueError(
                f"--height takes CLASS=CM (robot=5, obstacle=7) or marker:ID=CM, got {text!r}"
            )
        if name in ("robot", "obstacle"):
            fields[f"{name}_height_cm"] = cm
            if name not in classes:
                classes.append(name)
        elif name.startswith("marker:") and name[7:].isdigit():
            marker = int(name[7:])
            hit = [k for k, r in enumerate(robots) if r.marker_id == marker]
            if not hit:
                known = ", ".join(str(r.marker_id) for r in robots) or "none"
                raise ValueError(
                    f"--height {text}: no robot carries marker {marker} (configured: {known})"
                )
            for k in hit:
                robots[k] = msgspec.structs.replace(robots[k], marker_height_cm=cm)
        else:
            raise ValueError(f"--height takes robot=CM, obstacle=CM or marker:ID=CM, got {text!r}")
    fields["declared_heights"] = classes
    fields["robots"] = robots
    return msgspec.structs.replace(pose, **fields)

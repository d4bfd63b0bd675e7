"""Solids seen by one camera (common/solids, vision/outline): the silhouette's closed form
against OpenCV's convex hull, the fit recovering a known solid from its outline, the
sub-pixel edges of a blurred step, the per-frame footprint from a centroid, a blob's
solids followed along their union's outline and an outline's pixel chain on the floor,
and the height options of ``ovis detect``."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ovis.common.camera.plane_table import PlaneTables
from ovis.common.config import PoseConfig, RobotSpec, load_config
from ovis.common.physical.rigs import rig
from ovis.common.solids.fit import (
    LOSS_PX,
    MAX_OFF_SHARE,
    THIN_WALL_PX,
    FloorOutline,
    Solid,
    fit_piece,
    follow_union,
)
from ovis.common.solids.footprint import PoseMap, centroid_footprints
from ovis.common.solids.outline_floor import chain_floor, floor_outline
from ovis.common.solids.shapes import SHAPES, equal_area_radius, footprint_polygon
from ovis.common.solids.silhouette import (
    Viewpoint,
    hull_edges,
    image_axis,
    image_moments,
    signed_distance,
    signed_distance_few,
    signed_distance_jacobian,
    top_scale,
)
from ovis.common.vision.labeling import label_components
from ovis.common.vision.outline import (
    BlobPatches,
    SmoothedDiff,
    background_spots,
    blob_outline,
    blob_patches,
    chain_normals,
    object_mask,
    patch_outline,
    subpixel_edges,
    wall_tops,
)
from ovis.common.vision.shape import orientation
from ovis.common.world.heights import with_heights

VIEW = Viewpoint(np.array([75.0, -60.0]), 140.0)  # the oblique tripod's centre


def _theta(shape: str, x: float, y: float, h: float, yaw: float = 0.4) -> np.ndarray:
    if shape == "cylinder":
        return np.array([x, y, 4.0, h])
    if shape == "box":
        return np.array([x, y, 9.0, 5.0, yaw, h])
    return np.array([x, y, 5.5, yaw, h])


def _hull_polygon(shape: str, theta: np.ndarray, view: Viewpoint) -> np.ndarray:
    """The silhouette as OpenCV's convex hull of the footprint and its scaled copy."""
    foot = footprint_polygon(shape, theta)
    s = float(top_scale(theta[-1], view))
    pts = np.vstack([foot, view.foot + s * (foot - view.foot)]).astype(np.float32)
    return cv2.convexHull(pts)[:, 0, :].astype(np.float64)


@pytest.mark.parametrize("shape", SHAPES)
def test_the_silhouette_is_the_hull_of_the_footprint_and_the_top_seen_from_the_camera(
    shape: str,
) -> None:
    rng = np.random.default_rng(3)
    for x, y, h in [(30.0, 100.0, 24.0), (120.0, 20.0, 2.0), (75.0, -58.0, 10.0)]:
        theta = _theta(shape, x, y, h, yaw=float(rng.uniform(-3, 3)))
        hull = _hull_polygon(shape, theta, VIEW)
        q = np.array([x, y]) + rng.uniform(-25, 25, (400, 2))
        d = signed_distance(shape, theta, q, VIEW)
        inside = np.array(
            [cv2.pointPolygonTest(hull.astype(np.float32), tuple(p), False) > 0 for p in q]
        )
        assert np.array_equal(d < 0, inside) or np.sum((d < 0) != inside) <= 2  # on the edge
        exact = np.array(
            [abs(cv2.pointPolygonTest(hull.astype(np.float32), tuple(p), True)) for p in q]
        )
        # inside and beside an edge the distance is exact; beyond a corner a lower bound
        assert np.allclose(np.abs(d[inside]), exact[inside], atol=0.02)
        assert (np.abs(d) <= exact + 0.02).all()
        a, b = hull_edges(footprint_polygon(shape, theta), top_scale(theta[-1], VIEW), VIEW)
        shoelace = 0.5 * np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1])
        assert shoelace == pytest.approx(cv2.contourArea(hull.astype(np.float32)), rel=1e-4)
        # a frame's follow: a few silhouettes' edges in plain Python, the same distances
        few = np.repeat(theta[None], 3, axis=0)
        few[1:, 0:2] += rng.uniform(-1, 1, (2, 2))
        q1 = np.column_stack([q, np.ones(len(q))])
        got = signed_distance_few(shape, few.tolist(), q1, VIEW)
        assert np.abs(got - signed_distance(shape, few, q, VIEW)).max() < 1e-9


@pytest.mark.parametrize("shape", [s for s in SHAPES if s != "cylinder"])
def test_a_silhouettes_derivatives_by_centre_and_yaw_are_its_distances_differences(
    shape: str,
) -> None:
    """signed_distance_jacobian: the distances signed_distance_few gives, and their
    derivatives by x, y and yaw equal to central differences wherever a point's nearest
    hull line stays the same for the step (everywhere but beside the hull's corners)."""
    rng = np.random.default_rng(11)
    step = 1e-6
    for x, y, h in [(30.0, 100.0, 24.0), (120.0, 20.0, 2.0), (75.0, -58.0, 10.0)]:
        theta = _theta(shape, x, y, h, yaw=float(rng.uniform(-3, 3)))
        q = np.array([x, y]) + rng.uniform(-25, 25, (400, 2))
        q1 = np.column_stack([q, np.ones(len(q))])
        for turn in (False, True):
            d, jac = signed_distance_jacobian(shape, theta.tolist(), q1, VIEW, turn)
            assert jac.shape == (3 if turn else 2, len(q))
            assert (
                np.abs(d - signed_distance_few(shape, [theta.tolist()], q1, VIEW)[0]).max() < 1e-12
            )
            for p, k in enumerate([0, 1, len(theta) - 2][: len(jac)]):
                moved = [theta.copy(), theta.copy()]
                moved[0][k] += step
                moved[1][k] -= step
                up, down = signed_distance_few(shape, [m.tolist() for m in moved], q1, VIEW)
                differences = (up - down) / (2 * step)
                smooth = np.abs(differences - jac[p]) < 1e-4
                assert smooth.mean() > 0.9, (shape, turn, p)  # corners' neighbours aside
                # where the line switches the one-sided slopes differ: the derivative
                # is one of them
                left = (signed_distance_few(shape, [theta.tolist()], q1, VIEW)[0] - down) / step
                right = (up - signed_distance_few(shape, [theta.tolist()], q1, VIEW)[0]) / step
                one_of = np.minimum(np.abs(jac[p] - left), np.abs(jac[p] - right)) < 1e-3
                assert one_of.all(), (shape, turn, p)


def test_image_moments_are_the_projected_silhouettes_area_and_centroid() -> None:
    camera = rig("oblique", load_config())
    theta = _theta("box", 70.0, 40.0, 12.0)
    hull = _hull_polygon("box", theta, VIEW := Viewpoint.of(camera))
    dense = np.vstack(
        [
            np.linspace(p, q, 40, endpoint=False)
            for p, q in zip(hull, np.roll(hull, -1, 0), strict=True)
        ]
    )
    from ovis.common.camera.projection import project

    p = project(dense[:, 0], dense[:, 1], np.zeros(len(dense)), camera)
    m = cv2.moments(np.column_stack([p.col, p.row]).astype(np.float32))
    area, row, col = image_moments("box", theta[None], VIEW, camera, steps=40)
    assert area[0] == pytest.approx(m["m00"], rel=1e-3)
    assert (row[0], col[0]) == pytest.approx((m["m01"] / m["m00"], m["m10"] / m["m00"]), abs=0.01)
    # its major axis as a blob's (orientation() of its central moments); straight edges
    # (the lens bends them a little: the dense outline's axis within 0.05°)
    mu = (m["mu02"] / m["m00"], m["mu20"] / m["m00"], m["mu11"] / m["m00"])
    a_row, a_col, axis = image_axis("box", theta[None], VIEW, camera)
    assert (a_row[0], a_col[0]) == pytest.approx((row[0], col[0]), abs=0.05)
    assert math.degrees(axis[0] - orientation(*mu)[0]) == pytest.approx(0.0, abs=0.05)


def test_a_turning_box_is_put_where_it_stands_by_its_blobs_centroid_and_axis() -> None:
    """A box moved 0.4 cm and turned 3° from where its pose map was worked out: one
    linear step from its silhouette's image centroid and axis puts its centre within
    0.02 cm and its yaw within 0.1° (the axis turns with the yaw at a rate the map
    knows), and the map itself says where that centroid and axis are; told the yaw
    instead, the centroid alone puts its centre as well."""
    for rig_name, yaw in (("oblique", 0.4), ("oblique", 2.0), ("overhead", 1.0)):
        camera = rig(rig_name, load_config())
        view = Viewpoint.of(camera)
        start = np.array([90.0, 60.0, 16.0, 10.0, yaw, 5.0])
        pose = PoseMap.of("box", start, view, camera)
        assert pose.slope > 0.3
        truth = start + np.array([0.3, -0.27, 0.0, 0.0, math.radians(3.0), 0.0])
        row, col, axis = image_axis("box", truth[None], view, camera)
        seen = pose.image_at(truth[:2], float(truth[4]))  # the map's own linear guess
        assert seen[:2] == pytest.approx((row[0], col[0]), abs=0.02)
        assert math.degrees(seen[2] - axis[0]) == pytest.approx(0.0, abs=0.1)
        x, y, got = pose.solve((float(row[0]), float(col[0]), float(axis[0])), yaw)
        assert math.hypot(x - truth[0], y - truth[1]) < 0.02, rig_name
        assert abs(math.degrees(got - truth[4])) < 0.1, rig_name
        x, y, kept = pose.solve((float(row[0]), float(col[0]), None), float(truth[4]))
        assert kept == truth[4]
        assert math.hypot(x - truth[0], y - truth[1]) < 0.02, rig_name


def _outline(shape: str, theta: np.ndarray) -> FloorOutline:
    """Points on the true silhouette (0.05 cm noise), their outward normals, 3 px per cm
    (as the oblique camera sees there)."""
    hull = _hull_polygon(shape, theta, VIEW)
    rng = np.random.default_rng(11)
    points = np.vstack(
        [
            np.linspace(p, q, 30, endpoint=False)
            for p, q in zip(hull, np.roll(hull, -1, 0), strict=True)
        ]
    )
    edge = np.roll(points, -1, 0) - np.roll(points, 1, 0)
    normals = np.column_stack([edge[:, 1], -edge[:, 0]])
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    if np.sum((points - points.mean(0)) * normals) < 0:
        normals = -normals
    noisy = points + rng.normal(0.0, 0.05, points.shape)
    return FloorOutline(noisy, normals, np.full(len(points), 3.0))


@pytest.mark.parametrize(
    "shape,x,y,h",
    [("cylinder", 40.0, 90.0, 14.0), ("box", 110.0, 30.0, 6.0), ("prism5", 75.0, 60.0, 21.0)],
)
def test_a_fit_finds_a_solids_shape_footprint_and_height_from_its_outline(
    shape: str, x: float, y: float, h: float
) -> None:
    """Points on the true silhouette (0.05 cm noise), px per cm as the oblique camera
    sees there: the shape is found among all five, the footprint within 0.05 cm and the
    height within 0.2 cm."""
    truth = _theta(shape, x, y, h)
    solid = fit_piece(_outline(shape, truth), VIEW)
    assert solid.shape == shape
    assert math.hypot(solid.theta[0] - x, solid.theta[1] - y) < 0.05
    assert abs(solid.theta[-1] - h) < 0.2
    assert float(equal_area_radius(shape, solid.theta)) == pytest.approx(
        float(equal_area_radius(shape, truth)), abs=0.05
    )
    assert 0.0 < math.sqrt(solid.covariance[-1, -1]) < 0.5


def test_a_fits_height_uncertainty_covers_thin_walls_found_at_the_top_s_rim() -> None:
    """Issue 36's overhead seed 1009: a pentagonal prism 3.11 cm tall, 47 cm from the
    camera's foot, its sides nearly along the line of sight. Where its walls are thinner
    in the frame than THIN_WALL_PX, its edges are moved in to the top face's rim (as the
    renders show them; 0.05 cm noise): the height found is off, and within its stated
    1σ (counting those walls' bias: without it, 1.6σ off)."""
    view = Viewpoint(np.array([75.0, 60.0]), 200.0)  # the overhead camera
    truth = np.array([72.5, 13.1, 7.16, math.radians(-16.6), 3.11])
    hull = _hull_polygon("prism5", truth, view)
    points = np.vstack(
        [
            np.linspace(p, q, 30, endpoint=False)
            for p, q in zip(hull, np.roll(hull, -1, 0), strict=True)
        ]
    )
    edge = np.roll(points, -1, 0) - np.roll(points, 1, 0)
    normals = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.hypot(*edge.T)[:, None]
    normals *= np.sign(np.sum((points - points.mean(0)) * normals))
    px = np.full(len(points), 3.43)  # px per cm there
    facing = -(normals * (points - view.foot)).sum(1)
    wall = (float(top_scale(truth[-1], view)) - 1.0) * facing  # cm
    thin = (facing > 0.0) & (wall * px < THIN_WALL_PX)
    assert thin.sum() > 50
    rim = points - np.where(thin, wall, 0.0)[:, None] * normals
    rim += np.random.default_rng(11).normal(0.0, 0.05, rim.shape)
    solid = fit_piece(FloorOutline(rim, normals, px), view)
    error = abs(float(solid.theta[-1]) - 3.11)
    assert 0.2 < error < math.sqrt(solid.covariance[-1, -1])


def test_a_fit_explains_its_outline_with_a_few_points_far_off_not_with_a_wrong_shape() -> None:
    """A box's outline with a run of points 4 cm out (a floor mark fused to it): the fit
    passes them by and explains the outline, though they alone lift its rms residual
    far over a right fit's; the same outline fitted with a cylinder (the wrong shape)
    leaves many points off: not explained."""
    truth = _theta("box", 110.0, 30.0, 6.0)
    outline = _outline("box", truth)
    points = outline.points.copy()
    bump = slice(40, 40 + len(points) // 25)  # 4 % of the points
    points[bump] += 4.0 * outline.normals[bump]
    with_mark = outline._replace(points=points)
    solid = fit_piece(with_mark, VIEW)
    assert solid.shape == "box" and solid.explains
    assert solid.rms_px > 2.0
    assert math.hypot(solid.theta[0] - 110.0, solid.theta[1] - 30.0) < 0.1
    wrong = fit_piece(outline, VIEW, ["cylinder"])
    assert not wrong.explains and wrong.off_share > 2 * MAX_OFF_SHARE


def _imaged_disc(wall: float, wall_level: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """D of a bright disc (120 levels, radius 20 px, centred at col 40.2, row 39.7) in a
    ring of ``wall`` px at ``wall_level``, as a camera sees it (each pixel the mean over
    its area, a slight blur, sensor noise of 1.5 levels), and its outline's pixel chain."""
    size, k = 80, 8
    yy, xx = (np.mgrid[0 : size * k, 0 : size * k] + 0.5) / k - 0.5  # pixel centres
    r = np.hypot(xx - 40.2, yy - 39.7)
    fine = np.where(r <= 20.0, 120.0, np.where(r <= 20.0 + wall, wall_level, 0.0))
    image = cv2.resize(fine, (size, size), interpolation=cv2.INTER_AREA)
    noise = np.random.default_rng(seed).normal(0, 1.5, image.shape)
    diff = (cv2.GaussianBlur(image, (0, 0), 0.3) + noise).astype(np.float32)
    mask = (cv2.GaussianBlur(diff, (0, 0), 0.8) >= 3).astype(np.uint8)
    chain = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0][0][:, 0, :]
    return diff, chain


@pytest.mark.parametrize("wall", [0.0, 4.0])
def test_subpixel_edges_find_the_silhouette_of_a_blurred_disc_with_or_without_a_dark_wall(
    wall: float,
) -> None:
    """A bright disc of radius 20 px (and a dark ring of ``wall`` px around it, 6 levels
    above the floor: a wall lit only by the room) as a camera sees it (each pixel the
    mean over its area, a slight blur, sensor noise of 1.5 levels): the edges lie on the
    outer circle, the median within 0.1 px and the mean within 0.12 px; with no wall, 95 %
    of them within 0.5 px. (A ring of 2.5 px or less at 4 times the noise is not yet told
    from the disc's own edge on most profiles: then the edge is the top's.)"""
    diff, chain = _imaged_disc(wall, wall_level=6.0, seed=2)
    edges, _, usable = subpixel_edges(diff, (0, 0), chain, blur_px=0.6, noise=1.5)
    off = np.hypot(edges[usable, 0] - 40.2, edges[usable, 1] - 39.7) - (20.0 + wall)
    assert usable.mean() > 0.9
    assert abs(float(np.median(off))) < 0.1
    assert abs(float(np.mean(off))) < 0.12
    if wall == 0.0:
        assert float(np.percentile(np.abs(off), 95)) < 0.5


@pytest.mark.parametrize("wall", [0.0, 1.6])
def test_wall_tops_find_a_tops_edge_over_a_wall_too_thin_for_a_look(wall: float) -> None:
    """A bright disc of radius 20 px (a top face) in a ring of ``wall`` px at 30 levels
    (a low solid's wall seen from above, lit), imaged as in the test above: where the
    wall shows, the top's edge is found at the silhouette's second step on most of the
    outline, the median within 0.15 px of the disc's circle; with no wall, on under a
    tenth of it (a plain edge now and then fitted with two steps: a solid's look asks
    for a wall along most of its side facing the camera, ``WALL_SHARE``)."""
    diff, chain = _imaged_disc(wall, wall_level=30.0, seed=3)
    tops, _, found = wall_tops(diff, (0, 0), chain, blur_px=0.6, noise=1.5)
    if wall == 0.0:
        assert found.mean() < 0.1
        return
    off = np.hypot(tops[found, 0] - 40.2, tops[found, 1] - 39.7) - 20.0
    assert found.mean() > 0.8
    assert abs(float(np.median(off))) < 0.15


def test_a_footprint_follows_its_blobs_centroid() -> None:
    """Move a known box by 1.5 cm: the centre whose silhouette's image centroid is the
    moved one's is the moved centre."""
    camera = rig("overhead", load_config())
    view = Viewpoint.of(camera)
    truth = np.array([[100.0, 80.0, 9.0, 5.0, 0.3, 12.0], [40.0, 30.0, 6.0, 4.0, -1.0, 3.0]])
    _, row, col = image_moments("box", truth, view, camera)
    start = truth.copy()
    start[:, 0:2] += [[1.0, -1.1], [-0.5, 0.8]]
    found = centroid_footprints("box", start, np.column_stack([row, col]), view, camera)
    assert np.abs(found[:, 0:2] - truth[:, 0:2]).max() < 1e-3


def test_a_blobs_solids_follow_its_outline_as_one_gauss_newton_step_puts_them() -> None:
    """A box and a cylinder side by side, their union's outline seen, both moved off it
    and the box turned (a robot turns as it drives): :func:`follow_union`'s steps bring
    them back, each step the Gauss–Newton step of the union's residuals (LAPACK's
    solve), every point moving with the solid nearest it: by the box's centre and yaw
    (central differences of :func:`signed_distance`, which the closed form matches) and
    the cylinder's centre (forward differences, as the follow takes them)."""
    truth = [_theta("box", 60.0, 40.0, 8.0), _theta("cylinder", 68.0, 46.0, 15.0)]
    points = []
    for k, theta in enumerate(truth):
        hull = _hull_polygon(("box", "cylinder")[k], theta, VIEW)
        ring = np.vstack(
            [
                np.linspace(p, q, 40, endpoint=False)
                for p, q in zip(hull, np.roll(hull, -1, 0), strict=True)
            ]
        )
        other = truth[1 - k]
        points.append(ring[signed_distance(("box", "cylinder")[1 - k], other, ring, VIEW) > 0])
    q = np.vstack(points)
    floor = FloorOutline(q, np.zeros_like(q), np.full(len(q), 3.0))
    solids = [
        Solid(shape, theta.copy(), np.zeros((0, 0)), 0.0, 0, np.zeros(0))
        for shape, theta in zip(("box", "cylinder"), truth, strict=True)
    ]
    solids[0].theta[0:2] += [0.4, -0.3]
    solids[0].theta[4] += math.radians(4.0)
    solids[1].theta[0:2] += [-0.2, 0.35]
    offsets = np.zeros(2)
    free = ([0, 1, 4], [0, 1])  # the box's centre and yaw, the cylinder's centre
    kept = ([2, 3, 5], [2, 3])
    for _ in range(4):
        here = np.stack([3.0 * signed_distance(s.shape, s.theta, q, VIEW) for s in solids])
        nearest = here.argmin(0)
        r = here.min(0)
        rows = []
        for k, (s, idx) in enumerate(zip(solids, free, strict=True)):
            for i in idx:
                if s.shape == "cylinder":
                    moved = s.theta.copy()
                    moved[i] += 1e-3
                    slope = (3.0 * signed_distance(s.shape, moved, q, VIEW) - here[k]) / 1e-3
                else:
                    up, down = s.theta.copy(), s.theta.copy()
                    up[i] += 1e-7
                    down[i] -= 1e-7
                    d = signed_distance(s.shape, np.stack([up, down]), q, VIEW)
                    slope = 3.0 * (d[0] - d[1]) / 2e-7
                rows.append(np.where(nearest == k, slope, 0.0))
        jac = np.vstack(rows)
        w = 1.0 / np.sqrt(1.0 + (r / LOSS_PX) ** 2)
        a = (jac * w) @ jac.T + 1e-9 * np.eye(len(jac))
        step = -np.linalg.solve(a, (jac * w) @ r)
        moved = follow_union(solids, offsets, floor, VIEW)
        expected = np.concatenate([s.theta[idx] for s, idx in zip(solids, free, strict=True)])
        got = np.concatenate([t[idx] for t, idx in zip(moved, free, strict=True)])
        assert np.abs(got - (expected + step)).max() < 1e-6
        for s, t, idx in zip(solids, moved, kept, strict=True):  # sizes and heights kept
            assert np.array_equal(t[idx], s.theta[idx])
        solids = [s._replace(theta=t) for s, t in zip(solids, moved, strict=True)]
    for s, t in zip(solids, truth, strict=True):
        assert np.abs(s.theta[0:2] - t[0:2]).max() < 0.01
    assert abs(math.degrees(solids[0].theta[4] - truth[0][4])) < 0.1


def test_an_outlines_pixel_chain_is_read_off_the_floor_table_as_its_points_would_be() -> None:
    """An outline's pixel chain on the floor (:func:`chain_floor`: the floor table read at
    whole pixels) is :func:`floor_outline` of its points and normals; the floor normals
    and pixels per cm are J⁻ᵀ·m normalised and 1 / |Jᵀ·n| of each point's Jacobian J,
    the same in closed form (a follow's) to the last bits."""
    camera = rig("oblique", load_config())
    image = np.zeros((camera.rows, camera.cols), np.uint8)
    cv2.ellipse(image, (300, 200), (40, 25), 30.0, 0, 360, 255, -1)
    image[0:30, 0:50] = 255  # one at the frame's corner: read by back-projection there
    tables = PlaneTables()
    for contour in cv2.findContours(image, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)[0]:
        chain = contour[:, 0, :]
        got = chain_floor(chain, camera, tables)
        points, normals = chain_normals(chain)
        want = floor_outline(points, normals, camera, tables)
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
        j = tables.jacobian(points[:, 1], points[:, 0], camera, 0.0)
        jac = np.array([[j.dx_dcol, j.dx_drow], [j.dy_dcol, j.dy_drow]]).transpose(2, 0, 1)
        n = np.einsum("nji,nj->ni", np.linalg.inv(jac), normals)
        n /= np.linalg.norm(n, axis=1)[:, None]
        assert np.abs(got.normals - n).max() < 1e-9
        across = np.linalg.norm(np.einsum("nji,nj->ni", jac, n), axis=1)
        assert np.abs(got.px_per_cm * across - 1.0).max() < 1e-9
        closed = chain_floor(chain, camera, tables, closed_form=True)
        assert np.array_equal(closed.points, got.points)
        assert np.abs(closed.normals - got.normals).max() < 1e-12
        assert np.abs(closed.px_per_cm / got.px_per_cm - 1.0).max() < 1e-12
        outward = np.sum((got.points - got.points.mean(0)) * got.normals, axis=1)
        assert np.mean(outward > 0) > 0.9


def test_heights_declared_on_the_command_line() -> None:
    pose = PoseConfig(
        robots=[
            RobotSpec(
                id=1, name="a", marker_id=3, marker_side_cm=6.0, marker_height_cm=5.0, radius_cm=9.0
            )
        ]
    )
    out = with_heights(pose, "measured", ["obstacle=12.5", "marker:3=6.25", "robot=5"])
    assert out.heights == "measured"
    assert out.obstacle_height_cm == 12.5 and out.robot_height_cm == 5.0
    assert out.declared_heights == ["obstacle", "robot"]
    assert out.robots[0].marker_height_cm == 6.25
    for bad, needle in [
        (["chair=3"], "robot=CM, obstacle=CM or marker:ID=CM"),
        (["obstacle"], "CLASS=CM"),
        (["obstacle=-1"], "CLASS=CM"),
        (["marker:7=4"], "no robot carries marker 7"),
    ]:
        with pytest.raises(ValueError, match=needle):
            with_heights(pose, None, bad)
    with pytest.raises(ValueError, match="'measured' or 'configured'"):
        with_heights(pose, "guessed", [])


def test_measuring_heights_needs_the_empty_floor() -> None:
    from ovis.common.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError, match=r"needs image\.background"):
        config_from_dict({"pose": {"heights": "measured"}})


def test_a_floor_marks_mask_is_the_same_from_its_kept_level_and_cut_patches_are_the_frames() -> (
    None
):
    """The object mask over a floor mark (a bright spot of the empty floor): a shadow on
    it is no object, a dark solid hiding it is; the whole floor image's spot level is
    kept between frames (read-only, by identity) and gives the mask a fresh copy of the
    spots gives, as does a whole frame's mask in kept buffers (:class:`SmoothedDiff`, frame
    after frame, on a rough D too, the empty floor's smoothing kept where it is read-only
    and the level the same). Patches cut when asked for are :func:`blob_patches`' of the
    same boxes; cut with the frame's mask, each keeps its slice (a copy) and outlines
    as its own smoothing does, and with the label stage's borders a blob's outline is its
    outer border's where that holds its centroid (the cut patch's, no patch cut)."""
    floor = np.full((60, 80), 40, np.uint8)
    floor[20:30, 30:40] = 120  # a floor mark
    spots = background_spots(floor)
    assert not spots.flags.writeable and spots is background_spots(floor.copy())
    frame = floor.copy()
    frame[20:30, 30:35] = 90  # a dark solid over the mark's left half: 30 below the mark
    frame[20:30, 35:40] = 110  # a light shadow over its right half: 10 below it
    frame[45:55, 5:15] = 70  # a solid on the bare floor
    diff = np.subtract(frame, floor, dtype=np.int16)
    kept = object_mask(diff, 20.0, spots)
    assert np.array_equal(kept, object_mask(diff, 20.0, spots.copy()))
    frames = SmoothedDiff()
    rough = np.random.default_rng(1).integers(0, 256, floor.shape, dtype=np.uint8)
    kept_floor = floor.copy()
    kept_floor.setflags(write=False)  # as the configured one: its smoothing kept
    for image in (frame, rough, frame):
        d = np.subtract(image, floor, dtype=np.int16)
        want = object_mask(d, 20.0, spots)
        assert np.array_equal(frames.mask(image, floor, 20.0, spots), want)
        assert np.array_equal(frames.mask(image, kept_floor, 20.0, spots), want)
    assert np.array_equal(frames.mask(frame, kept_floor, 25.0), object_mask(diff, 25.0))
    for d in (diff, np.subtract(rough, floor, dtype=np.int16)):  # the spot rule, in full
        smooth = cv2.GaussianBlur(d.astype(np.float32), (0, 0), 0.8)
        lift = cv2.GaussianBlur(spots.astype(np.float32), (0, 0), 0.8)
        hidden = (spots > 0) & (np.abs(smooth) >= 20.0) & (smooth + lift >= 20.0)
        assert np.array_equal(object_mask(d, 20.0, spots), (smooth >= 20.0) | hidden)
        for _ in range(2):  # a patch's slice of the spots: the second time, as kept
            here, cut = spots[12:40, 22:50], d[12:40, 22:50]
            assert np.array_equal(object_mask(cut, 20.0, here), object_mask(cut, 20.0, +here))
    assert kept[22:28, 31:33].all() and not kept[22:28, 37:40].any()
    assert kept[47:53, 7:13].all() and kept.sum() < 200
    boxes = np.array([[20, 30, 10, 10], [45, 5, 10, 10], [0, 70, 5, 10]])
    cut = BlobPatches(frame, floor, boxes)
    whole = blob_patches(frame, floor, *boxes.T)
    assert len(cut) == 3
    for k in (2, 0, 1, -1):
        a, b = cut[k], whole[k]
        assert (a.top, a.left) == (b.top, b.left) and np.array_equal(a.diff, b.diff)
    with pytest.raises(IndexError):
        cut[3]
    # with the frame's mask, each patch carries its slice (a copy) and its outline is
    # the one its own smoothing gives (the frame's mask is reused by the next frame)
    mask = frames.mask(frame, floor, 20.0, spots)
    masked = BlobPatches(frame, floor, boxes, mask=mask)
    for k in (0, 1):
        a = masked[k]
        here = spots[a.top : a.top + a.diff.shape[0], a.left : a.left + a.diff.shape[1]]
        assert a.mask is not None and np.array_equal(a.mask, object_mask(a.diff, 20.0, here))
        own = patch_outline(whole[k], 20.0, spots=spots)
        assert own is not None and np.array_equal(patch_outline(a, 20.0).chain, own.chain)
    # with the label stage's borders too, a blob's outline where its centroid lies inside
    # it is its outer border's, the one its cut patch gives, without cutting it
    comp = label_components(mask)
    box = np.column_stack([comp.top, comp.left, comp.height, comp.width])
    traced = BlobPatches(frame, floor, box, mask=mask, borders=comp.borders, border=comp.border)
    assert comp.count == 2
    for k in range(comp.count):
        at = (float(comp.filled[k, 1]), float(comp.filled[k, 2]))
        own, cut = traced.own_outline(k, at), patch_outline(traced[k], 20.0, at, spots)
        assert own is not None and cut is not None and np.array_equal(own.chain, cut.chain)
        assert (own.area_px, own.row, own.col) == (cut.area_px, cut.row, cut.col)
        again = blob_outline(traced, k, 20.0, at, spots)
        assert again is not None and np.array_equal(again.chain, own.chain)
    away = (float(comp.top[0]) - 3.0, float(comp.left[0]) - 3.0)  # outside: the patch's
    assert traced.own_outline(0, away) is None
    assert np.array_equal(
        blob_outline(traced, 0, 20.0, away, spots).chain,
        patch_outline(traced[0], 20.0, away, spots).chain,
    )
    kept_mask = masked[0].mask.copy()
    frames.mask(rough, floor, 20.0, spots)
    assert np.array_equal(masked[0].mask, kept_mask)

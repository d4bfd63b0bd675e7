"""The per-frame fusion path from tables (issue 19): the border test from per-height pixel
tables agrees with projecting the rim (``disks_in_image``), and one pass over every
camera's tables gives what each camera's direct computation gives."""

from __future__ import annotations

import numpy as np
import pytest

from ovis.common.analysis.multicam import as_detections
from ovis.common.camera.projection import disks_in_image, project
from ovis.common.config import FusionConfig
from ovis.common.fusion.accuracy import (
    CUT_MARGIN_PX,
    AccuracyMap,
    detection_columns,
    sightings_of,
)
from ovis.common.fusion.border import BorderTable
from ovis.common.fusion.merge import fuse
from ovis.common.fusion.sightings import CXX, CYY, Sightings
from ovis.common.fusion.tables import TableSet
from ovis.common.sim.multiview import GridScene, camera_grid, grid_arena, measure

CELL = (100.0, 75.0)
SEED = 9190  # the benchmark's grid


def _grid():
    specs = camera_grid(2, 2, cell_cm=CELL, seed=SEED)
    scene = GridScene(*grid_arena(2, 2, CELL), robots=4, obstacles=10, seed=SEED)
    return specs, scene


def _measured_frames(seed: int, alter, step: int = 6):
    """Every ``step``-th frame of the benchmark's grid: per camera, its spec and what it
    measured (detections, each changed by ``alter(detection, rng)``)."""
    specs, scene = _grid()
    rng = np.random.default_rng(seed)
    for f in range(0, 600, step):
        truth = scene.objects(f)
        measured = [(s, as_detections(measure(s.camera, truth, 0.3, rng))) for s in specs]
        for _, found in measured:
            for d in found:
                alter(d, rng)
        yield measured


def _enlarged(d: dict, rng: np.random.Generator) -> None:
    d["radius_cm"] *= rng.uniform(1.0, 1.6)  # some disks now reach the border


def _headed(d: dict, rng: np.random.Generator) -> None:
    if d["kind"] == "robot":
        d["heading_deg"] = float(rng.uniform(-179.0, 180.0))


def _exact_room(x, y, z, r, cam, margin):
    """disks_in_image's own numbers: the smallest distance (px) of the 16 rim points'
    pixels inside the margin (negative: outside)."""
    ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    p = project(x[:, None] + r[:, None] * np.cos(ang), y[:, None] + r[:, None] * np.sin(ang),
                np.broadcast_to(z[:, None], (len(x), 16)), cam)  # fmt: skip
    room = np.minimum(np.minimum(p.row, cam.rows - 1 - p.row),
                      np.minimum(p.col, cam.cols - 1 - p.col)) - margin  # fmt: skip
    return np.where(p.valid, room, -np.inf).min(axis=1)


def test_the_border_table_decides_as_disks_in_image_on_random_disks() -> None:
    specs, _ = _grid()
    rng = np.random.default_rng(19)
    n = 20000
    for spec in specs:
        table = BorderTable(spec.camera)
        table.prepare(5.0, 7.0)
        # the interpolation error the table measured: a small fraction of a pixel
        assert 0 < table.band_px < 0.05
        x, y = rng.uniform(-30, 230, n), rng.uniform(-30, 180, n)
        z = np.where(rng.random(n) < 0.5, 5.0, 7.0)
        r = rng.uniform(0.5, 20.0, n)
        expected = disks_in_image(x, y, z, r, spec.camera, CUT_MARGIN_PX)
        assert 0.2 < expected.mean() < 0.8  # both answers are well represented
        assert np.array_equal(table.whole(x, y, z, r, CUT_MARGIN_PX), expected)
        # the table alone (no re-check by projection) errs only within the band: disks
        # whose rim comes within band_px of the margin
        room = _exact_room(x, y, z, r, spec.camera, CUT_MARGIN_PX)
        band, table._band = table.band_px, 0.0
        alone = table.whole(x, y, z, r, CUT_MARGIN_PX)
        wrong = alone != expected
        assert (np.abs(room[wrong]) <= band).all()
        table._band = None


def test_the_border_table_handles_bad_numbers_and_unknown_heights() -> None:
    cam = camera_grid(2, 2, cell_cm=CELL, seed=SEED)[0].camera
    table = BorderTable(cam)
    got = table.whole([np.nan, 50.0, np.inf, 50.0], [40.0, np.nan, 40.0, 40.0],
                      [7.0, 7.0, 7.0, 7.0], [3.0, 3.0, 3.0, np.nan])  # fmt: skip
    assert not got.any()
    # an unusual height: tabulated on first use, same answers as projecting
    x, y, r = np.linspace(-10, 130, 200), np.full(200, 40.0), np.full(200, 4.0)
    assert np.array_equal(table.whole(x, y, 11.5, r, 0.5), disks_in_image(x, y, 11.5, r, cam, 0.5))


def test_one_pass_over_every_camera_gives_what_each_camera_gives_directly() -> None:
    """The benchmark's frames: every camera's detections resolved together from the laid
    end to end tables keep exactly the detections the direct computation keeps (border
    test by projection, covariance by the Jacobian), with covariances within 1 %."""
    specs, _ = _grid()
    cfg = FusionConfig()
    maps = {s.name: AccuracyMap(s.camera, cfg.pixel_sigma_px) for s in specs}
    for m in maps.values():
        m.prepare(5.0, 7.0)
    tables = TableSet()
    kept = 0
    for measured in _measured_frames(3, _enlarged):
        parts = [detection_columns(s.name, found) for s, found in measured]
        together = tables.resolve(parts, maps, CUT_MARGIN_PX)
        direct = Sightings.joined(
            [
                sightings_of(s.name, s.camera, p, cfg.pixel_sigma_px)
                for s, p in zip(specs, parts, strict=True)
            ]
        )
        key = np.lexsort(together.data[:, :4].T)
        want = np.lexsort(direct.data[:, :4].T)
        assert np.array_equal(together.data[key, :4], direct.data[want, :4])
        assert [together.cameras[c] for c in together.cam[key]] == [
            direct.cameras[c] for c in direct.cam[want]
        ]
        a, b = together.data[key, CXX : CYY + 1], direct.data[want, CXX : CYY + 1]
        assert (np.abs(a - b) <= 0.01 * np.abs(b).max(axis=1, keepdims=True)).all()
        kept += len(together)
        # and the merge of either is the same world
        assert len(fuse(together, cfg)) == len(fuse(direct, cfg))
    assert kept > 1000


def test_bad_detections_are_left_out_not_raised() -> None:
    spec = camera_grid(2, 2, cell_cm=CELL, seed=SEED)[0]
    m = AccuracyMap(spec.camera, 0.3)
    m.prepare(7.0)
    good = {"kind": "obstacle", "x_cm": 40.0, "y_cm": 40.0, "z_cm": 7.0, "radius_cm": 4.0}
    bad = [dict(good, x_cm=float("nan")), dict(good, radius_cm=float("inf")),
           dict(good, z_cm=float("nan")), dict(good, x_cm=1e9)]  # fmt: skip
    out = TableSet().resolve([detection_columns("cam00", [good, *bad])], {"cam00": m}, 0.5)
    assert len(out) == 1 and out.data[0, 0] == 40.0


@pytest.mark.parametrize("height", [5.0, 7.0])
def test_the_table_set_follows_a_recalibrated_camera(height: float) -> None:
    spec = camera_grid(2, 2, cell_cm=CELL, seed=SEED)[0]
    sharp = AccuracyMap(spec.camera, 0.3)
    sharp.prepare(height)
    blurred = AccuracyMap(spec.camera, 0.6)
    blurred.prepare(height)
    found = detection_columns("cam00", [{"kind": "obstacle", "x_cm": 40.0, "y_cm": 40.0,
                                         "z_cm": height, "radius_cm": 4.0}])  # fmt: skip
    tables = TableSet()
    a = tables.resolve([found], {"cam00": sharp}, 0.5).data[0, CXX]
    b = tables.resolve([found], {"cam00": blurred}, 0.5).data[0, CXX]
    assert b == pytest.approx(4 * a)  # twice the pixel error: four times the variance


def _reference_merge(group: list) -> tuple:
    """One group merged the direct way (per group, numpy.linalg): the information-
    weighted mean, sigma from eigvalsh, weighted circular mean of the headings."""
    pts = np.array([[s.x_cm, s.y_cm] for s in group])
    covs = np.array([[[s.cov_cm2[0], s.cov_cm2[1]], [s.cov_cm2[1], s.cov_cm2[2]]] for s in group])
    info = np.linalg.inv(covs)
    P = np.linalg.inv(info.sum(axis=0))
    mean = P @ np.einsum("nij,nj->i", info, pts)
    w = 1.0 / np.trace(covs, axis1=1, axis2=2)
    h = [(np.radians(s.heading_deg), wi) for s, wi in zip(group, w, strict=True)
         if s.heading_deg is not None]  # fmt: skip
    heading = None
    if h:
        a, ww = np.array([v for v, _ in h]), np.array([v for _, v in h])
        heading = float(np.degrees(np.arctan2(ww @ np.sin(a), ww @ np.cos(a))))
    return (float(mean[0]), float(mean[1]), float(np.average([s.z_cm for s in group], weights=w)),
            float(np.average([s.radius_cm for s in group], weights=w)),
            float(np.sqrt(np.linalg.eigvalsh(P)[-1])), heading)  # fmt: skip


def test_every_group_merged_at_once_equals_merging_each_group_directly() -> None:
    """The benchmark's frames (robots with headings): each fused object equals its
    sightings merged one group at a time with numpy.linalg, to 1e-9."""
    cfg = FusionConfig()
    merged = 0
    for measured in _measured_frames(5, _headed):
        sightings = [x for s, found in measured
                     for x in sightings_of(s.name, s.camera, found, 0.3).to_list()]  # fmt: skip
        for obj in fuse(sightings, cfg):
            group = [s for s in sightings if s.camera in obj.cameras and (
                s.marker_id == obj.marker_id if obj.marker_id is not None
                else s.marker_id is None and np.hypot(s.x_cm - obj.x_cm, s.y_cm - obj.y_cm) < 3.0
            )]  # fmt: skip
            assert sorted(s.camera for s in group) == obj.cameras
            x, y, z, r, sigma, heading = _reference_merge(group)
            got = (obj.x_cm, obj.y_cm, obj.z_cm, obj.radius_cm, obj.sigma_cm)
            assert np.allclose(got, (x, y, z, r, sigma), rtol=0, atol=1e-9)
            if heading is None:
                assert obj.heading_deg is None
            else:
                assert abs((obj.heading_deg - heading + 180.0) % 360.0 - 180.0) < 1e-9
            merged += len(group) > 1
    assert merged > 300  # many objects were seen by two cameras or more

"""Simulated arena: determinism, motion invariants, truth consistency, clutter, data sets."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest

from ovis.common.camera.paper_model import back_project, pixel_footprint_cm2, project
from ovis.common.config import OvisConfig, config_from_dict, load_config, load_points
from ovis.common.sim.arena import (
    IMAGE_MARGIN_PX,
    MIN_GAP_CM,
    Arena,
    FrameTruth,
    SimObject,
    write_dataset,
)

PRESETS = ("default", "paper")
CONFIGS = {p: load_config(preset=p) for p in PRESETS}


def _with_sim(config: OvisConfig, **changes: object) -> OvisConfig:
    sim = msgspec.structs.replace(config.simulator, **changes)
    return msgspec.structs.replace(config, simulator=sim)


# --------------------------------------------------------------------- helpers (independent)
def _outline(o: SimObject, n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """World points on the outline of a top face (rectangle edges or circle)."""
    if o.shape == "rect":
        t = np.linspace(-0.5, 0.5, n // 4, endpoint=False)
        one = np.full_like(t, 0.5)
        u = np.concatenate([t, one, -t, -one]) * o.length_cm
        v = np.concatenate([-one, t, one, -t]) * o.width_cm
    else:
        a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        u, v = o.radius_cm * np.cos(a), o.radius_cm * np.sin(a)
    h = math.radians(o.heading_deg)
    return o.x_cm + u * math.cos(h) - v * math.sin(h), o.y_cm + u * math.sin(h) + v * math.cos(h)


def _gap(a: SimObject, b: SimObject) -> float:
    """Edge-to-edge world distance between a disk and a disk or a rectangle (cm)."""
    if a.shape == "rect":
        a, b = b, a
    assert a.shape == "disk"
    if b.shape == "disk":
        return math.hypot(a.x_cm - b.x_cm, a.y_cm - b.y_cm) - a.radius_cm - b.radius_cm
    h = math.radians(b.heading_deg)
    dx, dy = a.x_cm - b.x_cm, a.y_cm - b.y_cm
    u, v = dx * math.cos(h) + dy * math.sin(h), -dx * math.sin(h) + dy * math.cos(h)
    du, dv = max(abs(u) - b.length_cm / 2, 0.0), max(abs(v) - b.width_cm / 2, 0.0)
    return math.hypot(du, dv) - a.radius_cm


def _check_frame(config: OvisConfig, truth: FrameTruth) -> None:
    cam, sim = config.camera, config.simulator
    (x0, x1), (y0, y1) = sim.arena_x_cm, sim.arena_y_cm
    for o in truth.objects:
        px, py = _outline(o)
        assert px.min() >= x0 - 1e-9 and px.max() <= x1 + 1e-9, o
        assert py.min() >= y0 - 1e-9 and py.max() <= y1 + 1e-9, o
        q = project(px, py, o.z_cm, cam)
        m = IMAGE_MARGIN_PX - 0.5  # the simulator checks a polygon, this a finer one
        assert q.valid.all()
        assert q.row.min() >= m and q.row.max() <= cam.rows - 1 - m, o
        assert q.col.min() >= m and q.col.max() <= cam.cols - 1 - m, o
    objs = truth.objects
    for i in range(len(objs)):
        for j in range(i + 1, len(objs)):
            assert _gap(objs[i], objs[j]) >= MIN_GAP_CM - 1e-9, (objs[i], objs[j])


def _object_labels(labels: np.ndarray, truth: FrameTruth, config: OvisConfig) -> list[int]:
    """Label of the blob under each object's projected top-face centre."""
    out = []
    for o in truth.objects:
        q = project(o.x_cm, o.y_cm, o.z_cm, config.camera)
        out.append(int(labels[round(float(q.row)), round(float(q.col))]))
    return out


# --------------------------------------------------------------------- determinism
def test_same_seed_same_bytes_other_seed_differs() -> None:
    config = CONFIGS["paper"]
    a = [(img.tobytes(), t) for img, t in Arena(config, 5).frames(4)]
    b = [(img.tobytes(), t) for img, t in Arena(config, 5).frames(4)]
    c = [(img.tobytes(), t) for img, t in Arena(config, 6).frames(4)]
    assert a == b
    assert all(x[0] != y[0] for x, y in zip(a, c, strict=True))
    assert a[0][1] != c[0][1]


def test_render_does_not_change_the_state() -> None:
    arena = Arena(CONFIGS["default"], 3)
    img1, t1 = arena.render()
    img2, t2 = arena.render()
    assert img1.tobytes() == img2.tobytes() and t1 == t2
    assert img1.shape == (480, 640) and img1.dtype == np.uint8
    assert arena.truth_camera == CONFIGS["default"].camera


@pytest.mark.parametrize("preset", ["default", "pinhole"])
def test_the_kept_plane_samples_change_no_frame(
    preset: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frames painted from the planes' kept samples (PlaneTiles) are byte for byte those
    painted by back-projecting every shape's samples as it is drawn, over frames that
    reuse tiles and reach new ones (and clutter on the floor)."""
    config = load_config(preset=preset)
    kept = [img.tobytes() for img, _ in Arena(config, 11).frames(12)]
    monkeypatch.setattr(Arena, "_plane", lambda self, z: None)
    drawn = [img.tobytes() for img, _ in Arena(config, 11).frames(12)]
    assert kept == drawn


def test_plane_tiles_hold_the_back_projection_of_any_window() -> None:
    """A window across tiles and the image's last, ragged ones: the samples' plane points
    and validity as back_project gives them."""
    from ovis.common.camera.projection import back_project as any_back_project
    from ovis.common.sim.painting import PlaneTiles

    cam = CONFIGS["default"].camera
    tiles = PlaneTiles(cam, 7.0, 3)
    for r0, r1, c0, c1 in ((20, 90, 25, 70), (int(cam.rows) - 5, int(cam.rows), 600, 640)):
        x, y, valid = tiles.window(r0, r1, c0, c1)
        off = (np.arange(3) + 0.5) / 3 - 0.5
        rr = (np.arange(r0, r1)[:, None] + off).reshape(-1, 1)
        cc = (np.arange(c0, c1)[:, None] + off).reshape(1, -1)
        bp = any_back_project(rr, cc, cam, 7.0)
        assert x.shape == (3 * (r1 - r0), 3 * (c1 - c0))
        assert np.array_equal(x, bp.x_cm) and np.array_equal(y, bp.y_cm)
        assert np.array_equal(valid, bp.valid)
    assert 0 < tiles.done.sum() < tiles.done.size  # only the tiles painted over


def test_bad_seed_and_impossible_arena_are_reported() -> None:
    with pytest.raises(ValueError, match="non-negative"):
        Arena(CONFIGS["paper"], -1)
    tiny = _with_sim(CONFIGS["paper"], arena_x_cm=(60.0, 70.0), arena_y_cm=(60.0, 70.0))
    with pytest.raises(ValueError, match="cannot place"):
        Arena(tiny, 0)


# --------------------------------------------------------------------- motion
@pytest.mark.parametrize(
    ("preset", "changes"),
    [
        ("default", {}),
        ("paper", {}),
        ("paper", {"n_obstacles": 8, "speed_cm_per_frame": 4.0}),  # crowded and fast
    ],
)
def test_motion_keeps_every_invariant(preset: str, changes: dict[str, object]) -> None:
    config = _with_sim(CONFIGS[preset], **changes)
    sim = config.simulator
    arena = Arena(config, 11)
    first = arena.truth()
    assert [o.id for o in first.objects] == list(range(1 + sim.n_obstacles))
    assert [o.kind for o in first.objects] == ["robot"] + ["obstacle"] * sim.n_obstacles
    assert first.objects[0].z_cm == config.pose.robot_height_cm
    assert all(o.z_cm == config.pose.obstacle_height_cm for o in first.objects[1:])
    robot = first.objects[0]
    assert (robot.shape, robot.length_cm, robot.width_cm) == ("rect", *sim.robot_size_cm)
    assert math.pi * robot.radius_cm**2 == pytest.approx(robot.length_cm * robot.width_cm)
    for o in first.objects[1:]:
        lo, hi = sim.obstacle_radius_cm
        assert o.shape == "disk" and lo <= o.radius_cm <= hi
        assert o.length_cm == o.width_cm == 2 * o.radius_cm and o.heading_deg == 0.0

    prev = first
    robot_moves = 0
    total_path = np.zeros(len(first.objects))
    for k in range(200):
        arena.step()
        cur = arena.truth()
        assert cur.index == k + 1
        _check_frame(config, cur)
        for a, b in zip(prev.objects, cur.objects, strict=True):
            assert (a.id, a.kind, a.shape, a.radius_cm) == (b.id, b.kind, b.shape, b.radius_cm)
        for i, (a, b) in enumerate(zip(prev.objects, cur.objects, strict=True)):
            step = math.hypot(b.x_cm - a.x_cm, b.y_cm - a.y_cm)
            assert step <= 1.2 * sim.speed_cm_per_frame + 1e-9
            total_path[i] += step
        r0, r1 = prev.objects[0], cur.objects[0]
        dx, dy = r1.x_cm - r0.x_cm, r1.y_cm - r0.y_cm
        if math.hypot(dx, dy) > 1e-9:  # the robot's long axis follows its motion
            robot_moves += 1
            diff = (r1.heading_deg - math.degrees(math.atan2(dy, dx)) + 180.0) % 360.0 - 180.0
            assert abs(diff) < 1e-6
        else:
            assert r1.heading_deg == r0.heading_deg
        prev = cur
    assert robot_moves >= 150  # nobody gets stuck for long
    assert (total_path >= 0.6 * 200 * sim.speed_cm_per_frame).all()


# --------------------------------------------------------------------- rendering
@pytest.mark.parametrize("preset", PRESETS)
def test_scene_is_separable(preset: str) -> None:
    config = CONFIGS[preset]
    sim = config.simulator
    arena = Arena(config, 0)
    light = arena.lighting
    obj_min = sim.object_level * float(light.min())
    floor_max = sim.floor_level * float(light.max())
    assert obj_min - floor_max >= 40.0
    lo, hi = config.calibration.threshold
    assert max(lo, floor_max + 1) < min(hi, obj_min - 1)  # a threshold in range splits them
    # The same on a rendered frame: fully covered object pixels vs floor pixels.
    img, truth = arena.render(clean=True)
    objects = np.zeros(img.shape, dtype=bool)
    for o in truth.objects:
        q = project(*_outline(o), o.z_cm, config.camera)
        pts = np.stack([q.col, q.row], axis=1).round().astype(np.int32)
        cv2.fillPoly(objects.view(np.uint8), [pts], 1)
    kernel = np.ones((5, 5), np.uint8)
    inner = cv2.erode(objects.view(np.uint8), kernel).astype(bool)
    floor = ~cv2.dilate(objects.view(np.uint8), kernel).astype(bool)
    assert inner.sum() > 100
    assert int(img[inner].min()) - int(img[floor].max()) >= 40


@pytest.mark.parametrize("preset", PRESETS)
def test_blobs_match_truth(preset: str) -> None:
    """Midpoint threshold of the clean render → 8-connected blobs → the true objects."""
    config = CONFIGS[preset]
    cam, sim = config.camera, config.simulator
    worst_cm = worst_area = 0.0
    for seed in range(3):
        arena = Arena(config, seed)
        midpoint = arena.lighting * (0.5 * (sim.floor_level + sim.object_level))
        for _ in range(4):
            img, truth = arena.render(clean=True)
            binary = (img > midpoint).astype(np.uint8)
            n, labels, stats, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
            assert n - 1 == len(truth.objects)
            ids = _object_labels(labels, truth, config)
            assert sorted(ids) == list(range(1, n))
            for o, k in zip(truth.objects, ids, strict=True):
                col, row = centroids[k]  # OpenCV gives (x, y) = (col, row)
                bp = back_project(row, col, cam, o.z_cm)
                worst_cm = max(worst_cm, math.hypot(bp.x_cm - o.x_cm, bp.y_cm - o.y_cm))
                area = stats[k, cv2.CC_STAT_AREA] * pixel_footprint_cm2(row, col, cam, o.z_cm)
                worst_area = max(worst_area, abs(area / (math.pi * o.radius_cm**2) - 1.0))
            for _ in range(9):
                arena.step()
    assert worst_cm < 0.3
    assert worst_area < 0.03


@pytest.mark.parametrize("preset", PRESETS)
def test_clutter_is_small_and_apart(preset: str) -> None:
    """Clutter passes the lowest threshold, but the size filter removes all of it."""
    config = CONFIGS[preset]
    cam, sim = config.camera, config.simulator
    threshold = config.calibration.threshold[0]
    a_min = config.calibration.size_filter_cm2[0]
    assert sim.clutter_area_cm2[1] < a_min
    n_clutter = 0
    for seed in range(2):
        arena = Arena(config, seed)
        for _ in range(2):
            clean, truth = arena.render(clean=True)
            cluttered, _ = arena.render(clean=True, clutter=True)
            noisy, _ = arena.render()
            for img in (cluttered, noisy):
                n, labels, _, _ = cv2.connectedComponentsWithStats(
                    (img >= threshold).astype(np.uint8), connectivity=8
                )
                ids = set(_object_labels(labels, truth, config))
                assert 0 not in ids and len(ids) == len(truth.objects)
                for k in set(range(1, n)) - ids:
                    rr, cc = np.nonzero(labels == k)
                    assert pixel_footprint_cm2(rr, cc, cam, 0.0).sum() < a_min
                    n_clutter += img is cluttered
            # Clutter never touches an object's blob: object blobs are unchanged by it.
            _, labels, _, _ = cv2.connectedComponentsWithStats(
                (cluttered >= threshold).astype(np.uint8), connectivity=8
            )
            ids = _object_labels(labels, truth, config)
            np.testing.assert_array_equal(np.isin(labels, ids), clean >= threshold)
            arena.step()
    assert n_clutter >= 2 * 2 * sim.clutter_count // 2  # most specks are placed


def test_paper_scene_points_project_inside_the_paper_image() -> None:
    cam = CONFIGS["paper"].camera
    control = [(31, 21, 5), (95, 24, 7), (39, 71, 8), (102, 77, 6.5)]
    robot = [(98.241, 30.626), (88.829, 50.936), (79.721, 70.979), (70.892, 92.205)]
    obstacles = [
        (28.715, 26.300), (96.862, 132.382), (40.496, 60.470), (85.215, 108.946),
        (50.221, 95.894), (74.491, 85.831), (60.948, 127.329), (63.028, 62.831),
    ]  # fmt: skip
    pts = np.array(control + [(x, y, 5.0) for x, y in robot] + [(x, y, 7.0) for x, y in obstacles])
    q = project(pts[:, 0], pts[:, 1], pts[:, 2], cam)
    assert q.valid.all()
    assert (q.row >= 0).all() and (q.row <= cam.rows - 1).all()
    assert (q.col >= 0).all() and (q.col <= cam.cols - 1).all()


# --------------------------------------------------------------------- data sets
@pytest.mark.parametrize(
    ("preset", "changes"),
    [("paper", {}), ("default", {"n_obstacles": 2, "noise_sigma": 0.0})],
)
def test_write_dataset_round_trip(tmp_path: Path, preset: str, changes: dict[str, object]) -> None:
    config = _with_sim(CONFIGS[preset], **changes)
    info = write_dataset(tmp_path / "ds", config, frames=3, seed=4)
    names = sorted(p.name for p in info.out_dir.iterdir())
    assert names == [
        "checks.toml",  # the last frame's objects, for `ovis calibrate --check`
        "frame_0000.png",
        "frame_0001.png",
        "frame_0002.png",
        "points.toml",
        "truth.json",
    ]
    assert [p.name for p in info.frames] == names[1:4]
    assert info.checks == info.out_dir / "checks.toml"

    expected = list(Arena(config, 4).frames(3))
    for path, (img, _) in zip(info.frames, expected, strict=True):
        np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), img)

    data = msgspec.json.decode(info.truth.read_bytes())
    assert (data["seed"], data["preset"]) == (4, preset)
    assert data["camera"] == msgspec.to_builtins(config.camera)
    assert [f["file"] for f in data["frames"]] == names[1:4]
    for record, (_, truth) in zip(data["frames"], expected, strict=True):
        assert record["index"] == truth.index
        assert msgspec.convert(record["objects"], list[SimObject]) == truth.objects

    points = load_points(info.points)
    first = expected[0][1].objects
    assert [p.name for p in points.points] == ["R"] + [f"O{i}" for i in range(1, len(first))]
    for p, o in zip(points.points, first, strict=True):
        assert (p.x_cm, p.y_cm, p.z_cm) == (o.x_cm, o.y_cm, o.z_cm)
    assert points.config is not None
    assert config_from_dict(points.config) == config
    assert not list(info.out_dir.glob(".*"))  # no temporary files left behind


def test_write_dataset_needs_a_frame(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="at least 1"):
        write_dataset(tmp_path, CONFIGS["paper"], frames=0, seed=0)

"""Detection on real photos (skimage's coins): one blob per coin, checked against an
independent segmentation, on canvases of any size; adaptive threshold and background
subtraction where a fixed threshold fails; plain photos (skimage's camera, moon, page)
whose background is never an object."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
from cli_helpers import assert_one_line_error, ovis
from scipy import ndimage as ndi

# long: minutes of work, started early so the run ends with both workers busy
pytestmark = pytest.mark.long

skimage = pytest.importorskip("skimage")
from skimage import data, filters, segmentation  # noqa: E402


def reference_coins(image: np.ndarray) -> np.ndarray:
    """scikit-image's own coin segmentation (its watershed tutorial): (H, W) labels."""
    elevation = filters.sobel(image)
    markers = np.zeros_like(image)
    markers[image < 30], markers[image > 150] = 1, 2
    coins = ndi.binary_fill_holes(segmentation.watershed(elevation, markers) - 1)
    labels, n = ndi.label(coins)
    sizes = ndi.sum(coins, labels, range(1, n + 1))
    for k in np.flatnonzero(sizes < 100) + 1:  # specks, not coins
        labels[labels == k] = 0
    return labels


def check_one_blob_per_coin(objects: list[dict], labels: np.ndarray) -> None:
    """Every coin has exactly one blob within 3 px of its centre, every blob is one coin's,
    no blob is much larger than its coin (a coin merged with the floor), none a sliver."""
    ids = [k for k in np.unique(labels) if k]
    centres = np.array(ndi.center_of_mass(labels > 0, labels, ids))
    areas = np.array(ndi.sum(labels > 0, labels, ids))
    assert len(ids) == 24 and len(objects) == 24
    found = np.array([[o["row"], o["col"]] for o in objects])
    d = np.linalg.norm(centres[:, None] - found[None], axis=2)
    near = d < 3.0
    assert (near.sum(axis=1) == 1).all(), d.min(axis=1)
    assert (near.sum(axis=0) == 1).all()
    coin_of_blob = near.argmax(axis=0)
    blob_area = np.array([o["area_px"] for o in objects])
    ratio = blob_area / areas[coin_of_blob]
    assert ratio.max() < 1.15 and ratio.min() > 0.5, ratio


def is_correct(objects: list[dict], labels: np.ndarray) -> bool:
    try:
        check_one_blob_per_coin(objects, labels)
    except AssertionError:
        return False
    return True


@pytest.fixture(scope="module")
def coins(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    path = tmp_path_factory.mktemp("coins") / "coins.png"
    cv2.imwrite(str(path), data.coins())
    return path, reference_coins(data.coins())


def test_detect_coins_with_no_flag_one_blob_per_coin(coins) -> None:
    path, labels = coins
    out = json.loads(ovis("detect", str(path), "--json").stdout)
    check_one_blob_per_coin(out["objects"], labels)


def on_canvas(
    image: np.ndarray, labels: np.ndarray, cols: int, rows: int, at: tuple[int, int] = (0, 0)
):
    """The photo and its reference labels pasted with their top-left corner at ``at``
    (row, col) on a canvas of the photo's median grey (its floor): a wider view of the
    same coins."""
    canvas = np.full((rows, cols), int(np.median(image)), np.uint8)
    where = np.zeros((rows, cols), labels.dtype)
    inside = np.s_[at[0] : at[0] + image.shape[0], at[1] : at[1] + image.shape[1]]
    canvas[inside], where[inside] = image, labels
    return canvas, where


def evenly_lit(image: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The photo with its own uneven light taken out, on its median grey: its floor (the
    coins painted out by cv2.inpaint, blurred) subtracted. Pasted anywhere on a canvas of
    that grey it draws no edge: its top is brighter than the canvas, its bottom darker, as
    taken, and the local contrast sees those steps as light bands."""
    mask = cv2.dilate((labels > 0).astype(np.uint8), np.ones((9, 9), np.uint8))
    floor = cv2.inpaint(image, mask, 7, cv2.INPAINT_TELEA)
    light = cv2.GaussianBlur(floor.astype(np.float32), (0, 0), 15)
    return np.clip(image - light + np.median(image), 0, 255).astype(np.uint8)


CANVASES = [(384, 303), (512, 400), (640, 480), (1024, 768), (1280, 960), (1920, 1440)]


def places(cols: int, rows: int) -> dict[str, tuple[int, int]]:
    """Where the photo goes on a canvas: its corner, its centre, an offset drawn at random
    (seeded by the canvas's size)."""
    free_r, free_c = rows - 303, cols - 384
    rng = np.random.default_rng(cols * rows)
    return {
        "corner": (0, 0),
        "centre": (free_r // 2, free_c // 2),
        "random": (int(rng.integers(0, free_r + 1)), int(rng.integers(0, free_c + 1))),
    }


def detect_on(canvas: np.ndarray, tmp_path: Path) -> dict:
    path = tmp_path / "canvas.png"
    cv2.imwrite(str(path), canvas)
    return json.loads(ovis("detect", str(path), "--json").stdout)


def window_follows_the_coins(out: dict, labels: np.ndarray) -> None:
    """About four coin widths (√ area), whatever the canvas."""
    areas = np.bincount(labels.ravel())[1:]
    widths = np.sqrt(areas[areas > 0])
    assert 4 * widths.min() <= out["window_px"] <= 4 * widths.max(), out["window_px"]


@pytest.mark.parametrize("cols, rows", CANVASES)
def test_coins_on_any_canvas_give_24_of_24_at_defaults(
    coins, tmp_path: Path, cols: int, rows: int
) -> None:
    """The smallest object follows the objects, not the frame's area (a fixed fraction of
    the frame dropped coins on the larger canvases)."""
    _, labels = coins
    canvas, where = on_canvas(data.coins(), labels, cols, rows)
    out = detect_on(canvas, tmp_path)
    check_one_blob_per_coin(out["objects"], where)
    assert out["background_blobs"] == 0
    smallest = min(o["area_px"] for o in out["objects"])
    assert 16 <= out["min_area_px"] < smallest / 5  # far below the smallest coin
    window_follows_the_coins(out, labels)


#: Every canvas with some placements, every placement on small and large canvases, the
#: smallest and largest with all three.
SPREAD = [
    (384, 303, "corner"), (384, 303, "centre"), (384, 303, "random"),
    (512, 400, "random"), (640, 480, "corner"), (1024, 768, "centre"),
    (1280, 960, "random"),
    (1920, 1440, "corner"), (1920, 1440, "centre"), (1920, 1440, "random"),
]  # fmt: skip


@pytest.mark.parametrize("cols, rows, place", SPREAD)
def test_coins_anywhere_on_any_canvas_give_24_of_24_at_defaults(
    coins, tmp_path: Path, cols: int, rows: int, place: str
) -> None:
    """The local-contrast window and the auto level follow the objects, not the frame (a
    third of the frame's side and Otsu's level of the whole frame found 20 to 23 of the 24
    coins on every canvas larger than the photo)."""
    _, labels = coins
    photo = evenly_lit(data.coins(), labels)
    canvas, where = on_canvas(photo, labels, cols, rows, places(cols, rows)[place])
    out = detect_on(canvas, tmp_path)
    check_one_blob_per_coin(out["objects"], where)
    window_follows_the_coins(out, labels)


@pytest.mark.parametrize("place", ["centre", "random"])
@pytest.mark.parametrize("cols, rows", CANVASES[1:])
def test_coins_as_taken_within_a_canvas_one_blob_per_coin(
    coins, tmp_path: Path, cols: int, rows: int, place: str
) -> None:
    """The photo as taken, inside a canvas: every coin one blob (a coin merged with the
    floor on 1920×1440 before); what else is found is the photo's own bright top edge
    against the canvas, a real step of some 40 grey levels, no coin's."""
    _, labels = coins
    top, left = places(cols, rows)[place]
    canvas, where = on_canvas(data.coins(), labels, cols, rows, (top, left))
    out = detect_on(canvas, tmp_path)
    ids = [k for k in np.unique(where) if k]
    centres = np.array(ndi.center_of_mass(where > 0, where, ids))
    found = np.array([[o["row"], o["col"]] for o in out["objects"]])
    on_coin = np.linalg.norm(centres[:, None] - found[None], axis=2).min(axis=0) < 3.0
    check_one_blob_per_coin([o for o, c in zip(out["objects"], on_coin, strict=True) if c], where)
    edge = found[~on_coin]
    assert len(edge) <= 3
    assert ((edge[:, 0] >= top) & (edge[:, 0] < top + 15)).all(), edge
    assert ((edge[:, 1] >= left) & (edge[:, 1] < left + 384)).all(), edge


@pytest.mark.parametrize("name", ["camera", "moon", "page"])
def test_the_background_of_a_plain_photo_is_not_an_object(name: str, tmp_path: Path) -> None:
    """skimage's camera, moon and page: the blob that touches the border and covers most
    of the frame is left out, and said so."""
    image = getattr(data, name)()
    path = tmp_path / f"{name}.png"
    cv2.imwrite(str(path), image)
    out = json.loads(ovis("detect", str(path), "--json").stdout)
    assert out["background_blobs"] == 1
    frame = image.shape[0] * image.shape[1]
    assert all(o["area_px"] < 0.5 * frame for o in out["objects"])
    text = " ".join(ovis("detect", str(path)).stdout.split())  # the title may wrap
    assert "1 background blob left out" in text


def test_otsu_finds_24_blobs_but_a_wrong_segmentation(coins) -> None:
    """A count of 24 is not enough: global Otsu merges a coin with the uneven background."""
    path, labels = coins
    out = json.loads(ovis("detect", str(path), "--threshold", "otsu", "--json").stdout)
    assert len(out["objects"]) == 24 and not is_correct(out["objects"], labels)


def lit_unevenly(image: np.ndarray) -> np.ndarray:
    """The photo under a strong left-to-right light falloff (×0.45 … ×1.35)."""
    ramp = np.linspace(0.45, 1.35, image.shape[1])[None, :]
    return np.clip(image * ramp, 0, 255).astype(np.uint8)


def _fixed_never_works(path: Path, labels: np.ndarray) -> None:
    """No fixed level 0..255 segments the photo one blob per coin."""
    from ovis.common.config import ImageParams
    from ovis.common.world.pixels import detect_pixels

    frame = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    for level in range(256):
        objs = detect_pixels(frame, ImageParams(median="ordinary", threshold=level)).objects
        assert not is_correct([msgspec.structs.asdict(o) for o in objs], labels), level


def test_adaptive_threshold_where_every_fixed_level_fails(coins, tmp_path: Path) -> None:
    _, labels = coins
    path = tmp_path / "uneven.png"
    cv2.imwrite(str(path), lit_unevenly(data.coins()))
    _fixed_never_works(path, labels)
    for flag in ("adaptive:140", "auto"):
        out = json.loads(ovis("detect", str(path), "--threshold", flag, "--json").stdout)
        check_one_blob_per_coin(out["objects"], labels)


def test_background_subtraction_where_every_fixed_level_fails(coins, tmp_path: Path) -> None:
    """The empty floor: the same photo with the coins painted out (cv2.inpaint), under the
    same light; subtracted, a fixed level (128 + 17, mid-band of 136..154) finds every coin."""
    _, labels = coins
    coins_img = data.coins()
    mask = cv2.dilate((labels > 0).astype(np.uint8), np.ones((9, 9), np.uint8))
    floor = cv2.inpaint(coins_img, mask, 7, cv2.INPAINT_TELEA)
    path, bg = tmp_path / "uneven.png", tmp_path / "floor.png"
    cv2.imwrite(str(path), lit_unevenly(coins_img))
    cv2.imwrite(str(bg), lit_unevenly(floor))
    _fixed_never_works(path, labels)
    out = json.loads(
        ovis("detect", str(path), "--threshold", "145", "--background", str(bg), "--json").stdout
    )
    check_one_blob_per_coin(out["objects"], labels)


def test_roi_and_size_flags(coins, tmp_path: Path) -> None:
    path, _ = coins
    roi = np.zeros(data.coins().shape, np.uint8)
    roi[:, : roi.shape[1] // 2] = 255
    cv2.imwrite(str(tmp_path / "roi.png"), roi)
    out = json.loads(ovis("detect", str(path), "--roi", str(tmp_path / "roi.png"), "--json").stdout)
    assert 0 < len(out["objects"]) < 24
    assert all(o["col"] < roi.shape[1] / 2 for o in out["objects"])
    out = json.loads(ovis("detect", str(path), "--max-size", "1500", "--json").stdout)
    assert 0 < len(out["objects"]) < 24 and all(o["area_px"] <= 1500 for o in out["objects"])
    for args, needle in (
        (["--threshold", "300"], "--threshold must be"),
        (["--background", str(tmp_path / "missing.png")], "does not exist"),
        (["--roi", str(Path(__file__))], "cannot read the region-of-interest image"),
    ):
        proc = ovis("detect", str(path), *args, check=False)
        assert_one_line_error(proc, needle)
        assert proc.returncode == 2


def test_ga_tunes_the_threshold_on_the_local_contrast(tmp_path: Path) -> None:
    """`threshold_mode = "adaptive"`: the GA's threshold gene ranges over the local-contrast
    level, and the calibration keeps the mode for detection."""
    data_dir = tmp_path / "sim"
    ovis("simulate", "--out", str(data_dir), "--frames", "1")
    cfg = tmp_path / "adaptive.toml"
    cfg.write_text(
        'preset = "default"\n[image]\nthreshold_mode = "adaptive"\n'
        "[calibration]\nthreshold = [135.0, 250.0]\n"
    )
    out = tmp_path / "calib.json"
    calib = json.loads(
        ovis(
            "calibrate",
            str(data_dir / "frame_0000.png"),
            "--points",
            str(data_dir / "points.toml"),
            "--config",
            str(cfg),
            "--out",
            str(out),
            "--quiet",
            "--restarts",
            "0",
            "--json",
        ).stdout
    )
    assert calib["image"]["threshold_mode"] == "adaptive"
    assert 135 <= calib["image"]["threshold"] <= 250 and calib["dipe_px"] < 1.0
    found = json.loads(
        ovis("detect", str(data_dir / "frame_0000.png"), "--calibration", str(out), "--json").stdout
    )
    assert len(found["objects"]) == len(calib["points"])

"""Heights in fusion (issue 36): the footprint and height of an object seen by several
cameras combined by their information (each camera's 3 × 3 covariance of (x, y, z)),
a camera whose height is not measured giving x, y only, disagreeing heights left out
and named, and what the fusion service carries in and out."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ovis.common.config import FusionConfig
from ovis.common.fusion.merge import UNMEASURED_Z_INFO, fuse
from ovis.common.fusion.sightings import Sighting, Sightings, detection_row
from ovis.common.messages import ObstacleFrame, WorldFrame, decode, encode
from ovis.common.world.detection import DetectedObject

#: no bias floor: the covariances as given (the default's floor is checked on its own)
CFG = FusionConfig(footprint_bias_cm=0.0)


def _cov(c: np.ndarray) -> dict:
    """A Sighting's covariance fields from a 3 × 3 matrix (None: height not measured)."""
    return {"cov_cm2": (c[0, 0], c[0, 1], c[1, 1]), "cov_z_cm2": (c[0, 2], c[1, 2], c[2, 2])}


def _seen(camera: str, p: tuple[float, float, float], c: np.ndarray | None = None,
          *, xy_var: float = 0.01, source: str = "one camera") -> Sighting:  # fmt: skip
    """An obstacle sighting at ``p`` with covariance ``c`` (None: its height configured)."""
    cov = _cov(c) if c is not None else {"cov_cm2": (xy_var, 0.0, xy_var)}
    if c is None:
        source = "configured"
    return Sighting(camera=camera, kind="obstacle", x_cm=p[0], y_cm=p[1], z_cm=p[2],
                    radius_cm=5.0, z_source=source, **cov)  # fmt: skip


def _ray_covariance(along: np.ndarray, sigma_along: float, sigma_across: float) -> np.ndarray:
    """A camera's covariance of a solid's top: long along its ray, short across."""
    u = along / np.linalg.norm(along)
    return sigma_across**2 * np.eye(3) + (sigma_along**2 - sigma_across**2) * np.outer(u, u)


def test_two_cameras_give_the_information_weighted_answer() -> None:
    """Two cameras whose covariances lie along their rays (from either side): the
    merged point is (Σ Cᵢ⁻¹)⁻¹ Σ Cᵢ⁻¹ pᵢ, its height's σ √P_zz, far below either
    camera's own, and its source "cameras"."""
    ca = _ray_covariance(np.array([0.4, 0.0, -1.0]), 0.5, 0.05)
    cb = _ray_covariance(np.array([-0.3, 0.1, -1.0]), 0.4, 0.05)
    pa, pb = np.array([50.0, 40.0, 12.2]), np.array([50.1, 40.05, 11.9])
    (out,) = fuse([_seen("a", tuple(pa), ca), _seen("b", tuple(pb), cb)], CFG)
    ia, ib = np.linalg.inv(ca), np.linalg.inv(cb)
    p = np.linalg.inv(ia + ib)
    want = p @ (ia @ pa + ib @ pb)
    assert (out.x_cm, out.y_cm, out.z_cm) == pytest.approx(tuple(want), abs=1e-9)
    assert out.z_sigma_cm == pytest.approx(math.sqrt(p[2, 2]), rel=1e-9)
    assert out.z_sigma_cm < 0.5 * min(math.sqrt(ca[2, 2]), math.sqrt(cb[2, 2]))
    assert out.sigma_cm == pytest.approx(math.sqrt(np.linalg.eigvalsh(p[:2, :2]).max()))
    assert (out.z_source, out.cameras, out.disagreeing) == ("cameras", ["a", "b"], [])
    # the default: each camera's (x, y) variance raised by the footprint bias²
    cfg = FusionConfig()
    (biased,) = fuse([_seen("a", tuple(pa), ca), _seen("b", tuple(pb), cb)], cfg)
    raise_xy = np.diag([cfg.footprint_bias_cm**2] * 2 + [0.0])
    ia, ib = np.linalg.inv(ca + raise_xy), np.linalg.inv(cb + raise_xy)
    p = np.linalg.inv(ia + ib)
    want = p @ (ia @ pa + ib @ pb)
    assert (biased.x_cm, biased.y_cm, biased.z_cm) == pytest.approx(tuple(want), abs=1e-9)
    assert biased.z_sigma_cm == pytest.approx(math.sqrt(p[2, 2]), rel=1e-9)


def test_one_camera_passes_through_unchanged() -> None:
    c = _ray_covariance(np.array([0.2, -0.3, -1.0]), 0.3, 0.04)
    (out,) = fuse([_seen("a", (10.0, 20.0, 8.5), c)], CFG)
    assert (out.x_cm, out.y_cm, out.z_cm) == (10.0, 20.0, 8.5)
    assert out.z_sigma_cm == pytest.approx(math.sqrt(c[2, 2]))
    assert out.z_source == "one camera"
    (plain,) = fuse([_seen("a", (10.0, 20.0, 7.0))], CFG)
    assert (plain.z_cm, plain.z_sigma_cm, plain.z_source) == (7.0, None, "configured")


def test_a_camera_without_a_measured_height_gives_x_y_only() -> None:
    """Its configured 7 cm does not move the measured 15 cm (its weight on z is
    :data:`UNMEASURED_Z_INFO`); its (x, y) counts by its 2 × 2 information."""
    c = np.diag([0.04, 0.04, 0.09])
    (out,) = fuse([_seen("a", (30.0, 30.0, 15.0), c), _seen("b", (30.3, 30.0, 7.0))], CFG)
    assert out.z_cm == pytest.approx(15.0, abs=1e-6)
    assert out.z_sigma_cm == pytest.approx(0.3, rel=1e-6)
    assert out.x_cm == pytest.approx((30.0 / 0.04 + 30.3 / 0.01) / (1 / 0.04 + 1 / 0.01))
    assert out.z_source == "one camera" and out.cameras == ["a", "b"]
    # neither measured: the configured height, no σ
    (none,) = fuse([_seen("a", (30.0, 30.0, 7.0)), _seen("b", (30.3, 30.0, 7.0))], CFG)
    assert (none.z_cm, none.z_sigma_cm, none.z_source) == (pytest.approx(7.0), None, "configured")
    assert UNMEASURED_Z_INFO < 1e-6


def test_disagreeing_heights_are_named_not_averaged() -> None:
    """Two cameras 4 cm apart in height with 0.2 cm σ each: far beyond their combined
    uncertainty, so the less certain one's height is left out and named; of three, the
    one unlike the two others."""
    sharp, loose = np.diag([0.01, 0.01, 0.04]), np.diag([0.01, 0.01, 0.09])
    (two,) = fuse([_seen("a", (0.0, 0.0, 10.0), sharp), _seen("b", (0.0, 0.0, 14.0), loose)], CFG)
    assert two.z_cm == pytest.approx(10.0, abs=1e-6) and two.z_source == "one camera"
    assert two.disagreeing == ["b"] and two.cameras == ["a", "b"]
    three = fuse(
        [_seen("a", (0.0, 0.0, 10.0), sharp), _seen("b", (0.0, 0.0, 14.0), sharp),
         _seen("c", (0.0, 0.0, 10.2), sharp)],
        CFG,
    )  # fmt: skip
    (out,) = three
    assert out.z_cm == pytest.approx(10.1, abs=1e-6) and out.z_source == "cameras"
    assert out.disagreeing == ["b"]
    # within their uncertainty (1.2 σ of the difference): averaged, nobody named
    (agree,) = fuse([_seen("a", (0.0, 0.0, 10.0), sharp), _seen("b", (0.0, 0.0, 10.6), loose)],
                    CFG)  # fmt: skip
    assert agree.disagreeing == [] and agree.z_cm == pytest.approx(10.0 + 0.6 * 4 / 13)


def test_heights_too_uncertain_for_one_camera_are_measured_by_two() -> None:
    """Two cameras whose fits leave the height 0.5 cm uncertain each (over the 0.35 cm
    a height must reach; each reports the configured 7 cm and its fit's height apart),
    along rays from either side: together they pin it, well within 0.35 cm, "cameras".
    One alone stays as its camera reported it; a second camera's plain (x, y) does
    not make a height of it either when the merged σ stays above the limit."""
    ca = _ray_covariance(np.array([0.5, 0.0, -1.0]), 0.5, 0.05)
    cb = _ray_covariance(np.array([-0.5, 0.0, -1.0]), 0.5, 0.05)

    def weak(camera: str, x: float, c: np.ndarray) -> Sighting:
        return Sighting(camera=camera, kind="obstacle", x_cm=x, y_cm=40.0, z_cm=7.0,
                        radius_cm=5.0, z_fit_cm=15.0, **_cov(c))  # fmt: skip

    (both,) = fuse([weak("a", 60.0, ca), weak("b", 60.0, cb)], CFG)
    assert both.z_source == "cameras" and both.z_cm == pytest.approx(15.0)
    assert both.z_sigma_cm < 0.35 / 2
    (alone,) = fuse([weak("a", 60.0, ca)], CFG)
    assert (alone.z_cm, alone.z_source, alone.z_sigma_cm) == (7.0, "configured", None)
    loose = np.diag([0.01, 0.01, 0.25])  # no correlation: the other's (x, y) adds nothing
    (flat,) = fuse([weak("a", 60.0, loose), _seen("b", (60.0, 40.0, 7.0))], CFG)
    assert (flat.z_cm, flat.z_source, flat.z_sigma_cm) == (pytest.approx(7.0), "configured", None)
    row = detection_row(1.0, 2.0, 7.0, 4.0, covariance_cm2=loose.ravel().tolist(),
                        z_unmeasured="not measurable", z_fit_cm=15.0)  # fmt: skip
    assert Sightings((("a",)), np.array([row]), np.zeros(1, bool)).to_list()[0].z_fit_cm == 15.0


_SPD = st.lists(st.floats(-1.0, 1.0), min_size=9, max_size=9).map(
    lambda v: np.array(v).reshape(3, 3) @ np.array(v).reshape(3, 3).T * 0.05 + 0.01 * np.eye(3)
)


@settings(max_examples=60, deadline=None)
@given(
    covs=st.lists(_SPD, min_size=2, max_size=4),
    offsets=st.lists(st.tuples(*[st.floats(-0.05, 0.05)] * 3), min_size=4, max_size=4),
)
def test_merging_is_order_free_and_never_less_certain(covs, offsets) -> None:
    """Any 2–4 cameras agreeing within their errors: the answer does not depend on
    their order, lies within the box of their points, and its covariance is no larger
    than any one camera's (Cᵢ − P is positive semi-definite)."""
    # nothing named, every merged height measured: the properties of the mean
    cfg = FusionConfig(disagree_p=1e-12, footprint_bias_cm=0.0, height_sigma_max_cm=100.0)
    seen = [_seen(f"c{k}", (20.0 + o[0], 30.0 + o[1], 9.0 + o[2]), c)
            for k, (c, o) in enumerate(zip(covs, offsets, strict=False))]  # fmt: skip
    (a,) = fuse(seen, cfg)
    (b,) = fuse(seen[::-1], cfg)
    assert (a.x_cm, a.y_cm, a.z_cm) == pytest.approx((b.x_cm, b.y_cm, b.z_cm), abs=1e-9)
    info = sum(np.linalg.inv(c) for c in covs)
    p = np.linalg.inv(info)
    for c in covs:
        assert np.linalg.eigvalsh(c - p).min() >= -1e-9
    assert a.z_sigma_cm == pytest.approx(math.sqrt(p[2, 2]), rel=1e-6)
    assert a.z_source == "cameras" and a.disagreeing == []


def _detected(x: float, y: float, z: float, cov: list[float] | None, source: str,
              unmeasured: str = "") -> DetectedObject:  # fmt: skip
    return DetectedObject(0, "obstacle", 100.0, 100.0, 400.0, 70.0, 0.8, x, y, z, 4.0, 50.0,
                          z_source=source, z_sigma_cm=None if cov is None else 0.3,
                          z_unmeasured=unmeasured, covariance_cm2=cov)  # fmt: skip


def test_the_service_carries_covariances_in_and_heights_out() -> None:
    """An obstacle frame's fitted solids come into fusion with their covariance (the
    height's part only where it is measured), and the world frame says the merged
    height, its σ, its source and the disagreeing cameras, through its encoding."""
    from ovis.services.fusion import frame_columns, world_message

    c = np.diag([0.01, 0.02, 0.09]).ravel().tolist()
    msg = ObstacleFrame(
        seq=1, stamp_ns=1, published_ns=1, frame_age_ms=0.0, calibration_version=1,
        robot=None, planner=[],
        obstacles=[_detected(10.0, 20.0, 12.0, c, "one camera"),
                   _detected(40.0, 20.0, 7.0, c, "configured", "not measurable"),
                   _detected(70.0, 20.0, 7.0, None, "configured")],
    )  # fmt: skip
    cols = frame_columns("a", msg).to_list()
    assert cols[0].cov_cm2 == (0.01, 0.0, 0.02) and cols[0].cov_z_cm2 == (0.0, 0.0, 0.09)
    assert cols[0].z_source == "one camera"
    assert cols[1].cov_cm2 == (0.01, 0.0, 0.02) and cols[1].cov_z_cm2 is None
    assert math.isnan(cols[2].cov_cm2[0]) and cols[2].cov_z_cm2 is None
    assert detection_row(1.0, 2.0, 3.0, 4.0)[:4] == (1.0, 2.0, 3.0, 4.0)

    from ovis.common.fusion.tracks import Tracked
    from ovis.common.fusion.world import WorldFrameResult

    fused = fuse(
        [_seen("a", (0.0, 0.0, 10.0), np.diag([0.01, 0.01, 0.04])),
         _seen("b", (0.0, 0.0, 14.0), np.diag([0.01, 0.01, 0.09]))],
        CFG,
    )  # fmt: skip
    result = WorldFrameResult(stamp_ns=5, objects=[Tracked(id=1000, obj=fused[0])],
                              cameras=["a", "b"], missing=[])  # fmt: skip
    out = decode(encode(world_message(result, 0, "default", {}, "s")), WorldFrame)
    (o,) = out.objects
    assert (o.z_cm, o.z_source, o.disagreeing) == (pytest.approx(10.0), "one camera", ["b"])
    assert o.z_sigma_cm == pytest.approx(0.2)
    assert Sightings.of([_seen("a", (0.0, 0.0, 7.0))]).to_list()[0].z_source == "configured"


def test_the_live_score_splits_height_errors_by_what_they_rest_on() -> None:
    """``ovis up --cameras``' world score: the height error per ``z_source``."""
    from ovis.common.fusion.scoring import WorldScorer

    scorer = WorldScorer()
    scorer.add(
        [(1000, 0.0, 0.0, ("a", "b")), (1001, 50.0, 0.0, ("a",)), (1002, 90.0, 0.0, ("b",))],
        [(1, 0.0, 0.0), (2, 50.0, 0.0), (3, 90.0, 0.0)],
        None,
        ([12.2, 7.0, 9.5], [12.0, 9.0, 9.0]),
        ["cameras", "configured", "cameras"],
    )
    score = scorer.score()
    assert score.height_error_by_source_cm == {
        "cameras": [2.0, pytest.approx(0.35), pytest.approx(0.5)],
        "configured": [1.0, 2.0, 2.0],
    }
    assert score.height_error_cm_max == pytest.approx(2.0)

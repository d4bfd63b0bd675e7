"""Configuration: presets, overrides, validation errors that name the field."""

from __future__ import annotations

import tomllib
from pathlib import Path

import msgspec
import pytest

from ovis.common.config import (
    ConfigError,
    OvisConfig,
    Ros2Config,
    config_from_dict,
    dump_toml,
    load_config,
    load_points,
    preset_text,
)


def test_paper_preset_has_the_papers_values() -> None:
    cfg = load_config(preset="paper")
    cam = cfg.camera
    assert (cam.d_x_mm, cam.N_fx, cam.c_x, cam.Y0_cm, cam.theta_deg) == (0.264, 192, 96, 113, 70)
    assert (cam.lam_mm, cam.k1, cam.s_x, cam.s_y) == (3.6, -9.57e-7, 0.134, 0.100)
    assert (cfg.image.threshold, cfg.image.size_filter_cm2) == (168, 38.0)
    r = cfg.calibration
    assert r.threshold == (100, 230) and r.size_filter_cm2 == (20, 50) and r.Z0_cm == (125, 150)
    assert r.lam_mm == (3.5, 8) and r.k1 == (-1e-6, 1e-6) and r.s_x == (0.1, 1.0)
    assert (cfg.ga.population, cfg.ga.generations, cfg.ga.pc, cfg.ga.pm, cfg.ga.bits) == (
        100,
        90,
        0.9,
        0.005,
        10,
    )
    assert cfg.pose.goal_cm == (65.0, 105.0) and cfg.pose.goal_angle_deg == 116.0
    text = preset_text("paper")
    assert "[paper]" in text and "[chosen]" in text and "[probable]" in text


def test_override_on_top_of_a_preset(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text('preset = "paper"\n[ga]\ngenerations = 10\n[image]\npolarity = "dark"\n')
    cfg = load_config(f)
    assert cfg.ga.generations == 10 and cfg.ga.population == 100
    assert cfg.image.polarity == "dark" and cfg.camera.rows == 192


@pytest.mark.parametrize(
    "text,needle",
    [
        ("[ga]\npm = -0.1\n", "Expected `float` >= 0.0 - at `$.ga.pm`"),
        ("[camera]\ntheta_deg = 95\n", "Expected `float` <= 90.0 - at `$.camera.theta_deg`"),
        ("[camera]\nlam_mm = nan\n", "at `$.camera.lam_mm`"),
        ("[calibration]\nZ0_cm = [150.0, 125.0]\n", "lower bound 150.0 is above upper bound"),
        ("[calibration]\nthreshold = [100.0, 300.0]\n", "must lie within [0.0, 255.0]"),
        ('[image]\npolarity = "up"\n', "at `$.image.polarity`"),
        ("[ga]\npopulaton = 10\n", "unknown field `populaton`"),
        ('preset = "nope"\n', "unknown preset 'nope'"),
        ("[ros2]\nmarkers_rate_hz = -1.0\n", "at `$.ros2.markers_rate_hz`"),
        ("[ros2]\nimage_rate_hz = 2000.0\n", "<= 1000.0 - at `$.ros2.image_rate_hz`"),
        ("[ga\n", "not valid TOML"),
    ],
)
def test_errors_name_the_field_and_the_range(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(f)
    assert needle in str(err.value)
    assert str(f) in str(err.value)


def test_presets_ship_the_ros2_rates_the_benchmark_measures() -> None:
    """benchmarks/ros2.py measures Ros2Config's defaults: every preset ships them."""
    for preset in ("default", "paper", "pinhole"):
        ros2 = load_config(preset=preset).ros2
        assert (ros2.markers_rate_hz, ros2.image_rate_hz) == (2.0, 1.0), preset
        assert ros2 == Ros2Config(), preset


def test_missing_file() -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config("/nonexistent/ovis.toml")


def test_dump_and_reload_round_trip() -> None:
    for preset in ("default", "paper"):
        cfg = load_config(preset=preset)
        again = config_from_dict(tomllib.loads(dump_toml(cfg)))
        assert msgspec.to_builtins(again) == msgspec.to_builtins(cfg)
        assert isinstance(again, OvisConfig)


def test_points_file(tmp_path: Path) -> None:
    f = tmp_path / "p.toml"
    f.write_text(
        '[[points]]\nname = "R"\nx_cm = 31\ny_cm = 21\nz_cm = 5\n'
        '[[points]]\nname = "O1"\nx_cm = 95\ny_cm = 24\nz_cm = 7\n'
    )
    pts = load_points(f)
    assert [p.name for p in pts.points] == ["R", "O1"] and pts.config is None
    f.write_text(
        '[[points]]\nname = "R"\nx_cm = 1\ny_cm = 2\nz_cm = 3\n'
        '[[points]]\nname = "R"\nx_cm = 1\ny_cm = 2\nz_cm = 3\n'
    )
    with pytest.raises(ConfigError, match="unique"):
        load_points(f)
    f.write_text("points = []\n")
    with pytest.raises(ConfigError, match="at least one"):
        load_points(f)
    f.write_text(
        '[[points]]\nname = "R"\nx_cm = 1\ny_cm = 2\nz_cm = 3\n[config]\n[config.ga]\npc = 2.0\n'
    )
    with pytest.raises(ConfigError, match=r"\$\.ga\.pc"):
        load_points(f)

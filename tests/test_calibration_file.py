"""Calibration files: self-contained, atomic, validated on load."""

from __future__ import annotations

import json
import os
from pathlib import Path

import msgspec
import pytest

from ovis.common.atomic import write_atomic
from ovis.common.calibration.file import (
    Calibration,
    CalibrationFileError,
    load_calibration,
    save_calibration,
)
from ovis.common.config import load_config


def _calibration(**kw) -> Calibration:
    cfg = load_config()
    fields = dict(
        dipe_px=0.5,
        dipe_mm=0.132,
        dipe_max_px=0.8,
        dipe_max_mm=0.2,
        camera=cfg.camera,
        image=cfg.image,
        pose=cfg.pose,
    )
    fields.update(kw)
    return Calibration(**fields)


def test_save_load_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    c = _calibration()
    save_calibration(path, c)
    assert load_calibration(path) == c
    raw = json.loads(path.read_text())
    assert raw["dipe_px"] == 0.5 and raw["dipe_mm"] == 0.132 and raw["camera"]["s_x"] == 0.12
    assert [p.name for p in tmp_path.iterdir()] == ["c.json"]  # no temp files left


def test_atomic_write_keeps_the_old_file_on_failure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "c.json"
    save_calibration(path, _calibration())
    before = path.read_bytes()

    def boom(fd: int) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", boom)  # fail after the new bytes were written
    with pytest.raises(OSError, match="disk full"):
        write_atomic(path, b"half a calibration")
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["c.json"]


@pytest.mark.parametrize(
    "mutate,needle",
    [
        (lambda d: d.pop("camera"), "missing required field `camera`"),
        (lambda d: d.update(dipe_px="x"), "Expected `float`, got `str` - at `$.dipe_px`"),
        (lambda d: d["camera"].update(s_x=-1), "at `$.camera.s_x`"),
        (lambda d: d.update(dipe_mm=-1.0), "dipe_mm must be a finite non-negative number"),
        (lambda d: d.update(extra=1), "unknown field `extra`"),
    ],
)
def test_bad_files_are_refused_with_the_reason(tmp_path: Path, mutate, needle: str) -> None:
    data = msgspec.to_builtins(_calibration())
    mutate(data)
    path = tmp_path / "c.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError) as err:
        load_calibration(path)
    assert needle in str(err.value) and str(path) in str(err.value)


def test_not_json_and_missing(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    path.write_text("{truncated")
    with pytest.raises(CalibrationFileError, match="not valid JSON"):
        load_calibration(path)
    with pytest.raises(CalibrationFileError, match="ovis calibrate"):
        load_calibration(tmp_path / "missing.json")

"""The calibrator's store (common/calibration/store.py): it keeps the newest N versions,
falls back to the newest one that is valid, and says why it cannot write (the problem
it remembers until a write works again). The full and read-only disks of real
filesystems are in tests/test_disk_faults.py."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from ovis.common.calibration.file import Calibration, calibration_from_config
from ovis.common.calibration.store import PROBE_BYTES, CalibrationStore, StoreWriteError
from ovis.common.calibration.validity import calibration_problem
from ovis.common.config import KEEP_CALIBRATIONS, ConfigError, config_from_dict, load_config
from ovis.common.messages import ServiceStatus
from ovis.common.pipeline.saving import cannot_save_status, cannot_save_text

CFG = load_config(preset="paper")


def _nominal() -> Calibration:
    return calibration_from_config(CFG)


def test_the_store_keeps_the_newest_versions_and_numbering_goes_on(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path, keep=3)
    for _ in range(7):
        store.save(_nominal())
    assert store.versions() == [5, 6, 7]
    assert store.latest()[0].version == 7
    assert CalibrationStore(tmp_path, keep=3).save(_nominal()).version == 8
    assert store.versions() == [6, 7, 8]
    with pytest.raises(ValueError, match="at least 1"):
        CalibrationStore(tmp_path, keep=0)


def test_an_old_version_that_cannot_be_deleted_is_named_not_silently_kept(
    tmp_path: Path,
) -> None:
    """A version that cannot be deleted (here a folder in its place) stays, named with
    why; once it can be deleted the next save deletes it and names nothing."""
    store = CalibrationStore(tmp_path, keep=2)
    stuck = store.path(1)
    stuck.mkdir()
    (stuck / "inside").write_text("x")
    store.save(_nominal())
    assert store.versions() == [1, 2] and store.not_deleted == []
    store.save(_nominal())
    assert store.versions() == [1, 2, 3]
    assert len(store.not_deleted) == 1 and store.not_deleted[0].startswith(f"{stuck}: ")
    (stuck / "inside").unlink()
    stuck.rmdir()
    store.save(_nominal())
    assert store.versions() == [3, 4] and store.not_deleted == []


def test_keep_calibrations_is_a_validated_service_setting() -> None:
    assert CFG.service.keep_calibrations == KEEP_CALIBRATIONS == 20
    assert CalibrationStore("anywhere").keep == KEEP_CALIBRATIONS
    kept = config_from_dict({"service": {"keep_calibrations": 3}})
    assert kept.service.keep_calibrations == 3
    with pytest.raises(ConfigError, match="keep_calibrations"):
        config_from_dict({"service": {"keep_calibrations": 0}})


def test_an_invalid_newest_version_falls_back_to_the_newest_valid_one(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    store.save(_nominal())
    good = store.save(_nominal())
    below = msgspec.structs.replace(good.camera, Z0_cm=-500.0)  # loads, but is impossible
    store.save(msgspec.structs.replace(good, camera=below))
    store.path(4).write_text('{"format": "ovis-calibration", "version": 4, "dip')  # cut off
    calib, problems = store.latest(lambda c: calibration_problem(c, CFG))
    assert calib == good
    assert len(problems) == 2
    assert "calibration-v0004.json is not valid JSON" in problems[0]
    assert problems[1].startswith(f"{store.path(3)}: calibration v3 refused: the camera is at")
    # without a check only the file itself counts
    assert store.latest()[0].version == 3


def test_a_folder_that_cannot_be_made_is_a_clear_problem_and_nothing_is_saved(
    tmp_path: Path,
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    store = CalibrationStore(blocker / "state")
    assert store.writable() == f"Not a directory in {blocker / 'state'}"
    assert store.problem == store.writable()
    with pytest.raises(StoreWriteError, match=r"^Not a directory in "):
        store.save(_nominal())
    with pytest.raises(StoreWriteError):
        store.epoch()
    assert store.versions() == []
    # once the folder can be made, the problem is gone and saving works
    blocker.unlink()
    assert store.writable() is None and store.problem is None
    assert store.save(_nominal()).version == 1
    assert sorted(p.name for p in (blocker / "state").iterdir()) == [
        "calibration-v0001.json",
        "current.json",
        "epoch",
    ]


def test_the_write_probe_is_room_for_a_calibration_and_its_copy(tmp_path: Path) -> None:
    saved = CalibrationStore(tmp_path).save(_nominal())
    size = CalibrationStore(tmp_path).path(saved.version).stat().st_size
    assert 2 * size < PROBE_BYTES


def test_the_calibrator_status_and_reply_say_cannot_save() -> None:
    status = ServiceStatus(service="calibrator", pid=1, host="h", started_ns=0, state="ok")
    assert cannot_save_status(status, None) is status
    said = cannot_save_status(status, "No space left on device in /x")
    assert (said.state, said.reason) == (
        "cannot save: No space left on device in /x",
        "No space left on device in /x",
    )
    text = cannot_save_text("Read-only file system in /x", "v3@1a2b3c4d")
    assert text.startswith("cannot save: Read-only file system in /x: free space there")
    assert text.endswith("the calibration in use stays v3@1a2b3c4d")

"""Handing a recording's calibration to a fresh pipeline: the calibrator's state folder
gets the calibration the recorded system used, under the same version, so that the
replayed frames are processed exactly as they were."""

from __future__ import annotations

from pathlib import Path

from ovis.common.calibration.file import save_calibration
from ovis.common.calibration.store import CalibrationStore
from ovis.common.recording.session import recorded_calibration

__all__ = ["adopt_recorded_calibration"]


def adopt_recorded_calibration(recording: Path | str, state_dir: Path | str) -> str:
    """Put the recording's calibration in ``state_dir`` unless it holds one already;
    return a sentence saying which calibration the pipeline will use."""
    store = CalibrationStore(state_dir)
    current, _ = store.latest()
    if current is not None:
        return (
            f"using calibration v{current.version} of {store.folder} (not the recording's: "
            "give an empty --state-dir to use that one)"
        )
    calib = recorded_calibration(recording)
    if calib is None:
        return f"{recording} holds no calibration: the calibrator calibrates on its frames"
    save_calibration(store.path(calib.version), calib)
    save_calibration(store.folder / "current.json", calib)
    return f"using the recording's calibration v{calib.version} (saved in {store.folder})"

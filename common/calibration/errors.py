"""The error a GA calibration raises when no string is feasible: on its own, so that a
program that only reports it (the CLI's entry point) need not load the calibration."""

from __future__ import annotations

__all__ = ["InfeasibleCalibrationError"]


class InfeasibleCalibrationError(RuntimeError):
    """No string in the ranges sees exactly one object per control point."""

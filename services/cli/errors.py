"""Errors the user can act on, shown as one line by the `ovis` entry point."""

from __future__ import annotations

__all__ = ["UserError"]


class UserError(Exception):
    """A failure caused by the command's input; the message says what to do."""

    def __init__(self, message: str, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code

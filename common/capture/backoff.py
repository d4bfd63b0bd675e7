"""The retry schedule of a source that fails: short waits first (a network camera that
blinks is back at once), longer ones while it stays away (a camera unplugged for good
is not hammered), and short again once it has delivered."""

from __future__ import annotations

__all__ = ["FIRST_S", "LONGEST_S", "Backoff"]

#: The first wait after a failure, seconds.
FIRST_S = 0.5
#: The longest wait between two attempts, seconds.
LONGEST_S = 4.0


class Backoff:
    """Waits that double from ``first_s`` up to ``longest_s``; :meth:`reset` after a
    success starts again from ``first_s``."""

    def __init__(self, first_s: float = FIRST_S, longest_s: float = LONGEST_S) -> None:
        if not 0 < first_s <= longest_s:
            raise ValueError(f"need 0 < first_s <= longest_s, got {first_s} and {longest_s}")
        self.first_s = first_s
        self.longest_s = longest_s
        self._next = first_s

    def next_wait(self) -> float:
        """The wait before the next attempt (each call doubles the following one)."""
        wait = self._next
        self._next = min(2 * wait, self.longest_s)
        return wait

    def reset(self) -> None:
        """The source delivered: the next failure waits ``first_s`` again."""
        self._next = self.first_s

"""Typed errors for bad input: one line naming the thing and the reason."""

from __future__ import annotations


class MotionDataError(ValueError):
    """A clip, file or config that cannot be used, with where it came from and why.

    ``str(err)`` is the one line shown to users: ``<source>: <reason>``.
    """

    def __init__(self, source: str, reason: str) -> None:
        self.source = str(source)
        self.reason = reason
        super().__init__(f"{self.source}: {reason}")

"""Typed errors for bad input: one line naming the thing and the reason."""

from __future__ import annotations

from pydantic import ValidationError


class MotionDataError(ValueError):
    """A clip, file or config that cannot be used, with where it came from and why.

    ``str(err)`` is the one line shown to users: ``<source>: <reason>``.
    """

    def __init__(self, source: str, reason: str) -> None:
        self.source = str(source)
        self.reason = reason
        super().__init__(f"{self.source}: {reason}")

    def __reduce__(self) -> tuple[type[MotionDataError], tuple[str, str]]:
        """Pickle as (source, reason): Ray carries an error raised in a task back to the driver this way."""
        return (type(self), (self.source, self.reason))


class MotionConfigError(MotionDataError):
    """A ``MotionDataError`` about the run config or the command line (exit 2), even when a Ray task meets it."""


def first_error(err: ValidationError, whole: str) -> tuple[str, str]:
    """(dotted field path, message) of a pydantic error's first problem; ``whole`` when it is about the whole."""
    first = err.errors()[0]
    return ".".join(str(part) for part in first["loc"]) or whole, first["msg"]

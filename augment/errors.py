"""Kept for imports written before the error moved to schemas/ (the lowest layer, so models/ can raise it)."""

from schemas.errors import MotionDataError

__all__ = ["MotionDataError"]

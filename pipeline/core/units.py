"""Units shared by every stage (docs/conventions.md#time: time is int64 nanoseconds inside)."""

NS = 1_000_000_000
"""Nanoseconds per second."""

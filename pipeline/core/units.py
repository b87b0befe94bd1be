"""Units shared by every stage (DESIGN.md, Conventions: time is int64 nanoseconds inside)."""

NS = 1_000_000_000
"""Nanoseconds per second."""

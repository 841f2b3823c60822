"""Errors raised by the recording package."""

from __future__ import annotations


class RecordingError(RuntimeError):
    """A bag cannot be created, written, read or recovered; the message says why."""

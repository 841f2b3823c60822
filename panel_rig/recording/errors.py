"""Errors raised by the recording package."""

from __future__ import annotations

from typing import Any


class RecordingError(RuntimeError):
    """A bag cannot be created, written, read or recovered; the message says why."""


class CorruptBagError(RecordingError):
    """The bag's MCAP is damaged or incomplete; `panel-rig bag recover` rebuilds it.

    `scan` is the :class:`panel_rig.recording.integrity.McapScan` that found it (None if the
    damage showed while decoding)."""

    def __init__(self, message: str, scan: Any = None) -> None:
        super().__init__(message)
        self.scan = scan


class BagInUseError(RecordingError):
    """Another process holds the bag's lock: it is being recorded (or recovered); `pid` if known."""

    def __init__(self, message: str, pid: int | None = None) -> None:
        super().__init__(message)
        self.pid = pid


class MetadataError(RecordingError):
    """The bag's metadata.yaml cannot be parsed or is not rosbag2 metadata; `panel-rig bag recover` rebuilds it."""

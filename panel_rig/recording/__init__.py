"""rosbag2-compatible MCAP recording: writer, reader and crash recovery."""

from panel_rig.recording.errors import BagInUseError, CorruptBagError, RecordingError
from panel_rig.recording.integrity import McapScan, scan_mcap
from panel_rig.recording.reader import find_mcap, has_summary, read_bag, topic_counts, verify_bag
from panel_rig.recording.recover import RecoverReport, main_bag_recover, recover_bag
from panel_rig.recording.writer import BagWriter, fresh_bag_dir

__all__ = [
    "BagWriter",
    "BagInUseError",
    "CorruptBagError",
    "McapScan",
    "RecordingError",
    "RecoverReport",
    "find_mcap",
    "fresh_bag_dir",
    "has_summary",
    "main_bag_recover",
    "read_bag",
    "recover_bag",
    "scan_mcap",
    "topic_counts",
    "verify_bag",
]

"""rosbag2 `metadata.yaml` (version 9, as ROS 2 Jazzy writes it)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from panel_rig.recording.errors import MetadataError, RecordingError

METADATA_FILE = "metadata.yaml"
METADATA_VERSION = 9
ROS_DISTRO = "jazzy"
ROOT_KEY = "rosbag2_bagfile_information"


@dataclass
class TopicInfo:
    """One recorded topic and how many messages it holds."""

    name: str
    type: str
    offered_qos_profiles: list[dict[str, Any]]
    type_description_hash: str
    message_count: int = 0


@dataclass
class BagSummary:
    """What metadata.yaml describes: one MCAP file, its topics and time span."""

    file_name: str
    topics: list[TopicInfo] = field(default_factory=list)
    start_ns: int | None = None
    end_ns: int | None = None
    custom_data: dict[str, str] = field(default_factory=dict)

    @property
    def message_count(self) -> int:
        return sum(t.message_count for t in self.topics)

    def note_stamp(self, stamp_ns: int) -> None:
        """Widen the time span to include `stamp_ns`."""
        self.start_ns = stamp_ns if self.start_ns is None else min(self.start_ns, stamp_ns)
        self.end_ns = stamp_ns if self.end_ns is None else max(self.end_ns, stamp_ns)


def build_metadata(summary: BagSummary) -> dict[str, Any]:
    """The metadata.yaml document for `summary`."""
    start_ns = summary.start_ns or 0
    duration_ns = (summary.end_ns or start_ns) - start_ns
    count = summary.message_count
    return {
        ROOT_KEY: {
            "version": METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration_ns},
            "starting_time": {"nanoseconds_since_epoch": start_ns},
            "message_count": count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.type,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": t.offered_qos_profiles,
                        "type_description_hash": t.type_description_hash,
                    },
                    "message_count": t.message_count,
                }
                for t in summary.topics
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [summary.file_name],
            "files": [
                {
                    "path": summary.file_name,
                    "starting_time": {"nanoseconds_since_epoch": start_ns},
                    "duration": {"nanoseconds": duration_ns},
                    "message_count": count,
                }
            ],
            "custom_data": dict(summary.custom_data) or None,
            "ros_distro": ROS_DISTRO,
        }
    }


def dump_metadata(summary: BagSummary) -> str:
    """metadata.yaml text."""
    return yaml.safe_dump(build_metadata(summary), sort_keys=False, default_flow_style=False)


def write_metadata(bag_dir: Path, summary: BagSummary) -> Path:
    """Write `bag_dir/metadata.yaml` atomically (temp file + rename)."""
    path = Path(bag_dir) / METADATA_FILE
    tmp = path.with_suffix(".yaml.tmp")
    try:
        tmp.write_text(dump_metadata(summary), encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        raise RecordingError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path


def read_metadata(bag_dir: Path) -> dict[str, Any]:
    """The `rosbag2_bagfile_information` mapping of a bag directory.

    MetadataError (one line, naming `panel-rig bag recover`) if the file does not parse or is not rosbag2
    metadata; RecordingError if it cannot be read."""
    path = Path(bag_dir) / METADATA_FILE
    hint = f"run `panel-rig bag recover {bag_dir}` to rebuild it from the .mcap"
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MetadataError(f"{path} is damaged ({_one_line(exc)}); {hint}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get(ROOT_KEY), dict):
        raise MetadataError(f"{path} is not rosbag2 metadata (no {ROOT_KEY} mapping); {hint}")
    return doc[ROOT_KEY]


def _one_line(exc: Exception) -> str:
    """A YAML (or decoding) error in one line: `expected the node content ... at line 1, column 11`."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if problem and mark is not None:
        return f"{problem} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split()) or type(exc).__name__

"""Rebuild a readable bag from an MCAP whose writer died (SIGKILL: no summary, no footer).

Every complete record is read in file order (chunks are checked against their CRC); what follows
the first damaged or truncated record is unrecoverable and dropped. The original file is kept as
`<file>.broken`; a new complete MCAP takes its name and metadata.yaml is (re)written.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from panel_rig.recording.errors import RecordingError
from panel_rig.recording.metadata import (
    BagSummary,
    TopicInfo,
    dump_metadata,
    write_metadata,
)
from panel_rig.recording.reader import find_mcap, has_summary
from panel_rig.recording.writer import (
    LIBRARY,
    PARAMETERS_KEY,
    PARAMETERS_RECORD,
    PROFILE,
)


@dataclass
class RecoverReport:
    """What `recover_bag` found and wrote."""

    bag_dir: Path
    mcap_path: Path
    was_complete: bool
    broken_path: Path | None = None
    messages: int = 0
    chunks: int = 0
    topic_counts: dict[str, int] = field(default_factory=dict)
    skipped_messages: int = 0
    bytes_discarded: int = 0
    stop_reason: str = ""

    def line(self) -> str:
        """One-line human summary."""
        if self.was_complete:
            return f"{self.mcap_path}: already complete, {self.messages} messages; metadata ok"
        return (
            f"{self.mcap_path}: recovered {self.messages} messages in {len(self.topic_counts)} "
            f"topics from {self.chunks} chunks; discarded {self.bytes_discarded} trailing bytes "
            f"({self.stop_reason}); original kept as {self.broken_path}"
        )


@dataclass
class _Scan:
    profile: str = PROFILE
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    chunks: int = 0
    good_end: int = 0
    complete: bool = False
    stop_reason: str = "end of file"


def _take(scan: _Scan, record: Any) -> None:
    if isinstance(record, Header):
        scan.profile = record.profile or PROFILE
    elif isinstance(record, Schema):
        scan.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        scan.channels.setdefault(record.id, record)
    elif isinstance(record, Message):
        scan.messages.append(record)
    elif isinstance(record, Metadata) and record.name != "rosbag2":
        scan.metadata.append(record)


def _scan(path: Path) -> _Scan:
    """Read every intact record; stop at the first truncated or corrupt one."""
    scan = _Scan()
    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True, record_size_limit=256 * 2**20)
        try:
            for record in reader.records:
                if isinstance(record, Chunk):
                    for inner in breakup_chunk(record, validate_crc=True):
                        _take(scan, inner)
                    scan.chunks += 1
                elif isinstance(record, (DataEnd, Footer)):
                    scan.complete = scan.complete or isinstance(record, Footer)
                else:
                    _take(scan, record)
                scan.good_end = f.tell()
        except Exception as exc:  # noqa: BLE001 - any parse failure marks the damaged tail
            scan.stop_reason = f"{type(exc).__name__}: {exc}".strip().rstrip(":")
    return scan


def _topic_info(channel: Channel, schema: Schema) -> TopicInfo:
    qos_text = channel.metadata.get("offered_qos_profiles", "")
    try:
        qos = yaml.safe_load(qos_text) or []
    except yaml.YAMLError:
        qos = []
    return TopicInfo(
        name=channel.topic,
        type=schema.name,
        offered_qos_profiles=qos if isinstance(qos, list) else [],
        type_description_hash=channel.metadata.get("topic_type_hash", ""),
    )


def _write_recovered(scan: _Scan, out_path: Path, summary: BagSummary) -> tuple[int, int]:
    """Write every recovered message into a new MCAP; returns (written, skipped)."""
    written = skipped = 0
    with open(out_path, "xb") as stream:
        writer = Writer(stream, chunk_size=1024 * 1024, compression=CompressionType.NONE)
        writer.start(profile=scan.profile, library=f"{LIBRARY}; recovered")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, tuple[int, TopicInfo]] = {}
        for cid, channel in scan.channels.items():
            schema = scan.schemas.get(channel.schema_id)
            if schema is None:
                continue
            if schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            new_id = writer.register_channel(
                channel.topic, channel.message_encoding, schema_ids[schema.id], dict(channel.metadata)
            )
            info = _topic_info(channel, schema)
            summary.topics.append(info)
            channel_ids[cid] = (new_id, info)
        for meta in scan.metadata:
            writer.add_metadata(meta.name, dict(meta.metadata))
            if meta.name == PARAMETERS_RECORD:
                params = {k: json.loads(v) for k, v in meta.metadata.items()}
                summary.custom_data[PARAMETERS_KEY] = json.dumps(params, sort_keys=True)
        for msg in sorted(scan.messages, key=lambda m: m.log_time):
            target = channel_ids.get(msg.channel_id)
            if target is None:
                skipped += 1
                continue
            writer.add_message(target[0], msg.log_time, msg.data, msg.publish_time, msg.sequence)
            target[1].message_count += 1
            summary.note_stamp(msg.log_time)
            written += 1
        writer.add_metadata("rosbag2", {"serialized_metadata": dump_metadata(summary)})
        writer.finish()
    return written, skipped


def _free_name(path: Path) -> Path:
    if not path.exists():
        return path
    for i in range(1, 1000):
        candidate = path.with_name(f"{path.name}.{i}")
        if not candidate.exists():
            return candidate
    raise RecordingError(f"too many old copies next to {path}")


def recover_bag(bag_dir: Path) -> RecoverReport:
    """Make `bag_dir` a complete, readable bag again; never deletes the original data."""
    bag_dir = Path(bag_dir)
    mcap_path = find_mcap(bag_dir)
    if has_summary(mcap_path):
        scan = _scan(mcap_path)
        report = RecoverReport(bag_dir, mcap_path, was_complete=True, messages=len(scan.messages))
        if not (bag_dir / "metadata.yaml").is_file():
            summary = _summary_from_scan(scan, mcap_path.name)
            write_metadata(bag_dir, summary)
        return report
    scan = _scan(mcap_path)
    if scan.good_end == 0:
        raise RecordingError(f"{mcap_path} is not an MCAP file (no valid header)")
    summary = BagSummary(file_name=mcap_path.name)
    tmp = _free_name(mcap_path.with_name(mcap_path.name + ".recovering"))
    try:
        written, skipped = _write_recovered(scan, tmp, summary)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise RecordingError(f"cannot write recovered bag in {bag_dir}: {exc.strerror or exc}") from None
    broken = _free_name(mcap_path.with_name(mcap_path.name + ".broken"))
    size = mcap_path.stat().st_size
    os.replace(mcap_path, broken)
    os.replace(tmp, mcap_path)
    write_metadata(bag_dir, summary)
    return RecoverReport(
        bag_dir=bag_dir, mcap_path=mcap_path, was_complete=False, broken_path=broken,
        messages=written, chunks=scan.chunks,
        topic_counts={t.name: t.message_count for t in summary.topics},
        skipped_messages=skipped, bytes_discarded=size - scan.good_end,
        stop_reason=scan.stop_reason,
    )


def _summary_from_scan(scan: _Scan, file_name: str) -> BagSummary:
    summary = BagSummary(file_name=file_name)
    infos: dict[int, TopicInfo] = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        if schema is not None:
            infos[cid] = _topic_info(channel, schema)
            summary.topics.append(infos[cid])
    for msg in scan.messages:
        if msg.channel_id in infos:
            infos[msg.channel_id].message_count += 1
            summary.note_stamp(msg.log_time)
    return summary


def main_bag_recover(path: str) -> int:
    """CLI: `panel-rig bag recover BAG`. 0 ok, 2 bad input (one stderr line), 1 write failure."""
    bag_dir = Path(path)
    if not bag_dir.is_dir():
        print(f"panel-rig bag recover: {path}: not a bag directory", file=sys.stderr)
        return 2
    try:
        report = recover_bag(bag_dir)
    except RecordingError as exc:
        print(f"panel-rig bag recover: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"panel-rig bag recover: {path}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(report.line())
    return 0

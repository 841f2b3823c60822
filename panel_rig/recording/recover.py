"""Rebuild a readable bag from a damaged MCAP: a killed writer (no summary) or corrupt bytes.

The file is scanned by :func:`panel_rig.recording.integrity.scan_mcap`: every chunk is checked
against its CRC, broken record framing is skipped up to the next chunk that verifies, a truncated
tail is dropped. Every message of the intact chunks is written into a new complete MCAP (schemas and
channels from the intact chunks, or from the summary if its CRC holds); what was dropped (chunks,
their byte offsets, time ranges and message counts, unreadable byte ranges) is reported. The
original file is kept as `<file>.broken`; the new one takes its name and metadata.yaml is rewritten.
A bag whose lock is held (see :mod:`panel_rig.recording.lock`) is still being recorded and is not touched.
"""

from __future__ import annotations

import errno
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.records import Channel, Schema
from mcap.writer import CompressionType, Writer

from panel_rig.processes import TERMINATED_STATUS, signals_deferred, sigterm_exits
from panel_rig.recording.errors import BagInUseError, MetadataError, RecordingError
from panel_rig.recording.integrity import McapScan, messages_in_time_order, scan_mcap
from panel_rig.recording.lock import BagLock, lock_holder
from panel_rig.recording.metadata import (
    METADATA_FILE,
    BagSummary,
    TopicInfo,
    dump_metadata,
    read_metadata,
    write_metadata,
)
from panel_rig.recording.reader import find_mcap, not_a_recording, require_bag_dir, single_mcap
from panel_rig.recording.writer import (
    CHUNK_SIZE_BYTES,
    LIBRARY,
    PARAMETERS_KEY,
    PARAMETERS_RECORD,
    PROFILE,
)

#: what the damaged original of a recovered file is renamed to: `<file>.broken`
BROKEN_SUFFIX = ".broken"


@dataclass
class RecoverReport:
    """What `recover_bag` found and wrote."""

    bag_dir: Path
    mcap_path: Path
    was_complete: bool
    broken_path: Path | None = None
    messages: int = 0
    chunks: int = 0  # intact chunks the messages came from
    topic_counts: dict[str, int] = field(default_factory=dict)
    skipped_messages: int = 0  # in intact chunks, but of a channel whose definition was lost
    bytes_discarded: int = 0  # truncated tail
    stop_reason: str = ""
    dropped: list[str] = field(default_factory=list)  # one line per dropped chunk / byte range / record
    dropped_chunks: int = 0
    dropped_messages: int = 0  # as listed by the message indexes of the dropped chunks
    uncounted_chunks: int = 0  # dropped chunks no message index counted (their messages are in unaccounted_messages)
    dropped_topic_counts: dict[str, int] = field(default_factory=dict)
    #: messages the original's summary counted that no chunk accounts for: in unreadable bytes (broken framing);
    #: None when that summary is unreadable (a truncated file has none)
    unaccounted_messages: int | None = None
    notes: list[str] = field(default_factory=list)  # what was cleaned up first (damaged metadata.yaml, stale output)
    metadata_written: bool = False  # a complete MCAP whose metadata.yaml was missing or unreadable

    def line(self) -> str:
        """One-line human summary."""
        if self.was_complete:
            metadata = "metadata.yaml written" if self.metadata_written else "metadata ok"
            return f"{self.mcap_path}: already complete, {self.messages} messages; {metadata}"
        text = (f"{self.mcap_path}: recovered {self.messages} messages in {len(self.topic_counts)} "
                f"topics from {self.chunks} chunks")
        if self.dropped_chunks:
            text += f"; dropped {self.dropped_chunks} corrupt chunk{'s' if self.dropped_chunks > 1 else ''} ({self._dropped_count()})"
        if self.skipped_messages:
            text += f"; skipped {self.skipped_messages} messages of lost channels"
        if self.unaccounted_messages:
            where = "in uncounted chunks or unreadable bytes" if self.uncounted_chunks else "in unreadable bytes"
            text += (f"; lost {self.unaccounted_messages} messages {where} (the original's summary "
                     f"counted {self.unaccounted_messages + self.messages + self.skipped_messages + self.dropped_messages})")
        if self.bytes_discarded:
            text += f"; discarded {self.bytes_discarded} trailing bytes ({self.stop_reason})"
        return text + f"; original kept as {self.broken_path}"

    def _dropped_count(self) -> str:
        """The dropped chunks' messages as their message indexes list them; a chunk none lists is 'uncounted'."""
        if not self.uncounted_chunks:
            return f"{self.dropped_messages} messages"
        if self.uncounted_chunks == self.dropped_chunks:
            return "no message index counts their messages" if self.dropped_chunks > 1 else \
                "no message index counts its messages"
        counted = self.dropped_chunks - self.uncounted_chunks
        return f"{self.dropped_messages} messages in the {counted} their message indexes count, {self.uncounted_chunks} uncounted"

    def lines(self) -> list[str]:
        """The notes, the summary line, then one line per dropped chunk or byte range."""
        return [*self.notes, self.line(), *(f"  dropped {d}" for d in self.dropped)]


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


def _write_recovered(scan: McapScan, out_path: Path, summary: BagSummary) -> tuple[int, int]:
    """Write every recovered message into a new MCAP; returns (written, skipped)."""
    written = skipped = 0
    with open(out_path, "xb") as stream:
        # the recorder's chunks (mcap's default of 1 MiB made a recovered bag lose 16x more to the next damage)
        writer = Writer(stream, chunk_size=CHUNK_SIZE_BYTES, compression=CompressionType.NONE)
        writer.start(profile=scan.profile or PROFILE, library=f"{LIBRARY}; recovered")
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
            if meta.name == "rosbag2":
                continue
            writer.add_metadata(meta.name, dict(meta.metadata))
            if meta.name == PARAMETERS_RECORD:
                try:
                    params = {k: json.loads(v) for k, v in meta.metadata.items()}
                except ValueError:  # damaged beyond what a CRC covers: keep the record, skip the copy
                    continue
                summary.custom_data[PARAMETERS_KEY] = json.dumps(params, sort_keys=True)
        for msg in messages_in_time_order(scan):  # chunk by chunk: a long bag is not held in memory
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


def _put_in_place(tmp: Path, mcap_path: Path, broken: Path) -> None:
    """The original keeps its data as `broken`, the recovered `tmp` takes its name. The original is first given
    its second name as a hard link, so the bag has its .mcap at every instant (a recover killed by SIGKILL, which
    no handler can hold, between two renames left a bag without one); where the file system has no hard links, two
    renames, undone on an error."""
    try:
        os.link(mcap_path, broken)
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EXDEV, errno.EOPNOTSUPP, errno.EMLINK):
            tmp.unlink(missing_ok=True)
            raise
    else:
        try:
            os.replace(tmp, mcap_path)
        except BaseException:
            broken.unlink(missing_ok=True)
            tmp.unlink(missing_ok=True)
            raise
        return
    try:
        os.replace(mcap_path, broken)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        os.replace(tmp, mcap_path)
    except BaseException:
        os.replace(broken, mcap_path)
        tmp.unlink(missing_ok=True)
        raise


def _remove_leftovers(mcap_path: Path) -> list[str]:
    """Remove what a killed recover leaves next to `mcap_path`: its partial `.recovering` output, and a `.broken`
    that is only a second name of the .mcap itself (killed before the recovered file took its place); one note
    each."""
    notes = []
    for stale in sorted(mcap_path.parent.glob(mcap_path.name + ".recovering*")):
        stale.unlink()
        notes.append(f"removed {stale.name}, the partial output of an interrupted recover")
    for link in sorted(mcap_path.parent.glob(mcap_path.name + BROKEN_SUFFIX + "*")):
        if link.is_file() and os.path.samefile(link, mcap_path):
            link.unlink()
            notes.append(f"removed {link.name}, a second name of {mcap_path.name} left by an interrupted recover")
    return notes


def _lock(bag_dir: Path) -> BagLock | None:
    """Hold the bag's lock while recovering (a second recover, or a writer, is refused); None in a directory we
    cannot write (then nothing there is changed either, unless a write fails with its own error)."""
    holder = lock_holder(bag_dir)  # creates nothing: a live bag is not touched at all
    if holder is not None:
        raise BagInUseError(f"{bag_dir} is {holder.describe()}; not touched (recover it once that has stopped)",
                            holder.pid)
    try:
        return BagLock(bag_dir, "recover")
    except BagInUseError as exc:
        raise BagInUseError(f"{exc}; not touched (recover it once that has stopped)", exc.pid) from None
    except OSError as exc:
        if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            return None
        raise


def recover_bag(bag_dir: Path) -> RecoverReport:
    """Make `bag_dir` a complete, intact, readable bag again; never deletes the original data.

    Refuses (BagInUseError, nothing touched) a bag whose lock is held: it is still being recorded. A damaged
    metadata.yaml is kept as metadata.yaml.broken and rebuilt; a partial `<file>.recovering` left by an
    interrupted recover is removed; this run's own partial output is removed if it fails or is interrupted."""
    bag_dir = Path(bag_dir)
    require_bag_dir(bag_dir)
    lock = _lock(bag_dir)
    try:
        return _recover_locked(bag_dir)
    finally:
        if lock is not None:
            lock.release()


def _recover_locked(bag_dir: Path) -> RecoverReport:
    notes: list[str] = []
    try:
        mcap_path, bad_metadata = find_mcap(bag_dir), None
    except MetadataError as exc:
        mcap_path, bad_metadata = single_mcap(bag_dir), exc
    scan = scan_mcap(mcap_path)
    if not scan.recoverable:
        raise RecordingError(f"{not_a_recording(mcap_path, scan)}: nothing to rebuild")
    if bad_metadata is not None:
        damaged = _free_name(bag_dir / (METADATA_FILE + ".broken"))
        os.replace(bag_dir / METADATA_FILE, damaged)
        notes.append(f"{bag_dir / METADATA_FILE} was unreadable: kept as {damaged.name}, rebuilt from {mcap_path.name}")
    notes += _remove_leftovers(mcap_path)
    if scan.ok:
        missing = not (bag_dir / METADATA_FILE).is_file()
        if missing:
            write_metadata(bag_dir, _summary_from_scan(scan, mcap_path.name))
            if bad_metadata is None:
                notes.append(f"{bag_dir / METADATA_FILE} was missing: written from {mcap_path.name}")
        return RecoverReport(bag_dir, mcap_path, was_complete=True, messages=scan.message_count, notes=notes,
                             metadata_written=missing)
    summary = BagSummary(file_name=mcap_path.name)
    tmp = mcap_path.with_name(mcap_path.name + ".recovering")
    try:
        written, skipped = _write_recovered(scan, tmp, summary)
    except BaseException as exc:  # an error or Ctrl-C: leave no partial output behind
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise RecordingError(f"cannot write recovered bag in {bag_dir}: {exc.strerror or exc}") from None
        raise
    kept = [] if bad_metadata is not None else _keep_custom_data(bag_dir, summary)
    if kept:
        notes.append(f"{', '.join(kept)} kept from the previous {METADATA_FILE} (the recovered part of "
                     f"{mcap_path.name} does not hold {'it' if len(kept) == 1 else 'them'})")
    broken = _free_name(mcap_path.with_name(mcap_path.name + BROKEN_SUFFIX))
    with signals_deferred():  # the original under its new name, the recovered file in its place, metadata.yaml
        _put_in_place(tmp, mcap_path, broken)
        write_metadata(bag_dir, summary)
    report = RecoverReport(
        bag_dir=bag_dir, mcap_path=mcap_path, was_complete=False, broken_path=broken,
        messages=written, chunks=sum(1 for c in scan.chunks if c.ok),
        topic_counts={t.name: t.message_count for t in summary.topics if t.message_count},
        skipped_messages=skipped, notes=notes,
    )
    for p in scan.problems:
        if scan.truncated and p is scan.problems[-1] and "file ends" in p.what:
            report.bytes_discarded, report.stop_reason = scan.size - p.offset, "truncated record"
        if p.chunk is not None:
            report.dropped_chunks += 1
            report.dropped_messages += max(p.chunk.messages, 0)
            report.uncounted_chunks += p.chunk.messages < 0
            for cid, n in p.chunk.topic_counts.items():
                topic = scan.channel_topic(cid)
                report.dropped_topic_counts[topic] = report.dropped_topic_counts.get(topic, 0) + n
            topics = ", ".join(f"{scan.channel_topic(c)} {n}" for c, n in sorted(p.chunk.topic_counts.items()))
            report.dropped.append(scan.describe(p) + (f" [{topics}]" if topics else ""))
        elif p.length:
            report.dropped.append(scan.describe(p))
    if scan.summary_message_count is not None:
        report.unaccounted_messages = max(0, scan.summary_message_count - written - skipped - report.dropped_messages)
    return report


def _keep_custom_data(bag_dir: Path, summary: BagSummary) -> list[str]:
    """Copy into ``summary`` the custom_data entries (the run's parameters) of the bag's readable metadata.yaml
    that the recovered MCAP lost with its damaged part; returns their keys. (A bag cut early lost its parameters
    record, and the rewrite replaced a good metadata.yaml's parameters with none.)"""
    if not (bag_dir / METADATA_FILE).is_file():
        return []
    try:
        custom = read_metadata(bag_dir).get("custom_data")
    except RecordingError:  # MetadataError too: nothing readable to keep
        return []
    if not isinstance(custom, dict):
        return []
    kept = [k for k, v in custom.items() if isinstance(k, str) and isinstance(v, str) and k not in summary.custom_data]
    for k in kept:
        summary.custom_data[k] = custom[k]
    return kept


def _summary_from_scan(scan: McapScan, file_name: str) -> BagSummary:
    summary = BagSummary(file_name=file_name)
    infos: dict[int, TopicInfo] = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        if schema is not None:
            infos[cid] = _topic_info(channel, schema)
            summary.topics.append(infos[cid])
    for msg in messages_in_time_order(scan):
        if msg.channel_id in infos:
            infos[msg.channel_id].message_count += 1
            summary.note_stamp(msg.log_time)
    for meta in scan.metadata:
        if meta.name == PARAMETERS_RECORD:
            try:
                params = {k: json.loads(v) for k, v in meta.metadata.items()}
            except ValueError:
                continue
            summary.custom_data[PARAMETERS_KEY] = json.dumps(params, sort_keys=True)
    return summary


def main_bag_recover(path: str) -> int:
    """CLI: `panel-rig bag recover BAG`. 0 ok, 2 bad input (one stderr line), 1 write failure."""
    bag_dir = Path(path)
    try:
        with sigterm_exits():  # a `kill` leaves the bag as it was, as Ctrl-C does (it left the partial copy and lock)
            report = recover_bag(bag_dir)
    except SystemExit as exc:
        if exc.code != TERMINATED_STATUS:
            raise
        print(f"panel-rig bag recover: stopped by SIGTERM; {path} is as it was", file=sys.stderr)
        return TERMINATED_STATUS
    except RecordingError as exc:
        print(f"panel-rig bag recover: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"panel-rig bag recover: {path}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print("\n".join(report.lines()))
    return 0

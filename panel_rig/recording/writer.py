"""`BagWriter`: a rosbag2-compatible (Jazzy, MCAP storage) bag written from rclpy messages."""

from __future__ import annotations

import contextlib
import functools
import json
import struct
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Self

import mcap
import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import CompressionType, Writer

from panel_rig.recording import schemas
from panel_rig.recording.cdr import ends_with_empty_sequence, trim_trailing_padding
from panel_rig.recording.errors import RecordingError
from panel_rig.recording.lock import BagLock
from panel_rig.recording.metadata import (
    BagSummary,
    TopicInfo,
    dump_metadata,
    write_metadata,
)
from panel_rig.recording.qos import offered_qos, qos_yaml

PROFILE = "ros2"
LIBRARY = f"panel_rig recorder (rosbag2-compatible); mcap-python {mcap.__version__}"
MESSAGE_ENCODING = "cdr"
MESSAGE_OPCODE = 0x05  # MCAP Message record: opcode u8, length u64, channel u16, sequence u32, log u64, publish u64
MESSAGE_HEADER_BYTES = 22  # channel id + sequence + log time + publish time
PARAMETERS_RECORD = "panel_rig/parameters"
PARAMETERS_KEY = "panel_rig.parameters"
#: a command the rig refused is recorded on its topic + this suffix (``/rig/airspeed_cmd/rejected``)


def _serialize(msg: Any) -> bytes:
    from rclpy.serialization import serialize_message

    return serialize_message(msg)


class _Channel:
    """A registered topic: MCAP channel id, type, schema text and running sequence number."""

    __slots__ = ("channel_id", "info", "schema", "sequence", "msg_class", "may_end_empty")

    def __init__(self, channel_id: int, info: TopicInfo, schema: str, msg_class: type) -> None:
        self.channel_id = channel_id
        self.info = info
        self.schema = schema
        self.sequence = 0
        self.msg_class = msg_class
        self.may_end_empty = _may_end_in_sequence(msg_class)


def _may_end_in_sequence(msg_class: type) -> bool:
    """False if the last leaf field of this message type is never a sequence (no padding to trim, ever)."""
    fields = getattr(msg_class, "_fields_and_field_types", None)
    if not fields:
        return True
    last = list(fields.values())[-1]
    if "sequence" in last or "[" in last:
        return True
    if "/" in last:  # a nested message: look at its last field
        pkg, _, name = last.partition("/")
        try:
            import importlib

            return _may_end_in_sequence(getattr(importlib.import_module(f"{pkg}.msg"), name))
        except (ImportError, AttributeError):
            return True
    return False


class _PackedMessageIndex(MessageIndex):
    """``mcap.records.MessageIndex`` writing its (log time, offset) pairs in one buffer (the same bytes;
    ``MessageIndex.write`` packs them one integer at a time: ~4 us per recorded message)."""

    def write(self, stream: Any) -> None:
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.records) * 16)
        if self.records:
            stream.write(np.array(self.records, dtype="<u8").tobytes())
        stream.finish_record()


class _McapInternals:
    """Block writes into an ``mcap.writer.Writer``'s open chunk: the Message records of N samples built with
    numpy and appended as one buffer, with the chunk's message index, times and the file statistics updated
    exactly as ``Writer.add_message`` does per message (chunks are closed at the same message). Uses the
    writer's private fields (mcap-python 1.5-1.6); :meth:`of` returns None when they are not there, and the
    caller writes message by message."""

    __slots__ = ("writer", "chunk", "stats", "chunk_size", "finalize")

    def __init__(self, writer: Writer, chunk: Any, stats: Any, chunk_size: int, finalize: Any) -> None:
        self.writer, self.chunk, self.stats, self.chunk_size, self.finalize = writer, chunk, stats, chunk_size, finalize

    @staticmethod
    def of(writer: Writer) -> _McapInternals | None:
        chunk = getattr(writer, "_Writer__chunk_builder", None)
        stats = getattr(writer, "_Writer__statistics", None)
        size = getattr(writer, "_Writer__chunk_size", None)
        finalize = getattr(writer, "_Writer__finalize_chunk", None)
        needed = ("message_indices", "record_writer", "num_messages", "message_start_time", "message_end_time")
        if chunk is None or stats is None or not isinstance(size, int) or finalize is None or \
                not all(hasattr(chunk, a) for a in needed) or not hasattr(stats, "channel_message_counts"):
            return None
        return _McapInternals(writer, chunk, stats, size, finalize)

    def add_block(self, channels: Sequence[_Channel], stamps: np.ndarray, payloads: Sequence[np.ndarray]) -> None:
        n, k_topics = stamps.shape[0], len(channels)
        layout = _row_layout(tuple(c.channel_id for c in channels), tuple(p.shape[1] for p in payloads))
        template, at_seq, at_data, row_bytes = layout
        raw = np.empty((n, row_bytes), dtype=np.uint8)  # one sample's K records per row
        raw[:] = template  # opcodes, lengths, channel ids
        stamp_bytes = stamps.astype("<u8").view(np.uint8).reshape(n, 8)
        for k, (c, payload) in enumerate(zip(channels, payloads)):
            seq = ((c.sequence + np.arange(n)) & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
            a = at_seq[k]
            raw[:, a:a + 4] = seq
            raw[:, a + 4:a + 12] = stamp_bytes  # log time
            raw[:, a + 12:a + 20] = stamp_bytes  # publish time
            raw[:, at_data[k]:at_data[k] + payload.shape[1]] = payload
        blob = raw.tobytes()
        sizes = np.tile([9 + MESSAGE_HEADER_BYTES + p.shape[1] for p in payloads], n)
        ends = np.cumsum(sizes)  # end of message j in blob
        log = np.repeat(stamps, k_topics)
        channel_ids = [c.channel_id for c in channels]
        stats = self.stats
        for k, cid in enumerate(channel_ids):
            stats.channel_message_counts[cid] += n
        first, last = int(stamps.min()), int(stamps.max())
        stats.message_start_time = first if stats.message_count == 0 else min(stats.message_start_time, first)
        stats.message_end_time = max(stats.message_end_time, last)
        stats.message_count += n * k_topics
        j, total = 0, n * k_topics
        while j < total:
            chunk = self.chunk
            base = chunk.record_writer.count
            start = int(ends[j - 1]) if j else 0
            # the chunk closes after the first message that takes it over chunk_size (Writer.__maybe_finalize_chunk)
            over = int(np.searchsorted(ends, start + self.chunk_size - base, side="right"))
            stop = min(max(over + 1, j + 1), total)
            seg_log = log[j:stop]
            lo, hi = int(seg_log.min()), int(seg_log.max())
            chunk.message_start_time = lo if chunk.num_messages == 0 else min(chunk.message_start_time, lo)
            chunk.message_end_time = max(chunk.message_end_time, hi)
            offsets_in_chunk = (base - start) + np.concatenate(([start], ends[j:stop - 1]))
            indices = chunk.message_indices
            for m in range(j, min(j + k_topics, stop)):  # channels in order of first appearance in the chunk
                cid = channel_ids[m % k_topics]
                index = indices.get(cid)
                if index is None:
                    indices[cid] = _PackedMessageIndex(channel_id=cid, records=[])
                elif type(index) is MessageIndex:  # same records, same place in the chunk's index order
                    indices[cid] = _PackedMessageIndex(channel_id=cid, records=index.records)
            for k, cid in enumerate(channel_ids):
                sel = slice((k - j) % k_topics, None, k_topics)
                if seg_log[sel].size:
                    indices[cid].records.extend(zip(seg_log[sel].tolist(), offsets_in_chunk[sel].tolist()))
            chunk.num_messages += stop - j
            chunk.record_writer.write(blob[start:int(ends[stop - 1])])
            if chunk.record_writer.count > self.chunk_size:
                self.finalize()
            j = stop


@functools.lru_cache(maxsize=64)
def _row_layout(channel_ids: tuple[int, ...], sizes: tuple[int, ...]) -> tuple[np.ndarray, list[int], list[int], int]:
    """One sample's K MCAP Message records side by side: the constant bytes (opcode, record length, channel id),
    the offsets of each record's sequence number (then log and publish time) and data, and the row length."""
    parts, at_seq, at_data, at = [], [], [], 0
    for cid, size in zip(channel_ids, sizes):
        header = struct.pack("<BQHIQQ", MESSAGE_OPCODE, MESSAGE_HEADER_BYTES + size, cid, 0, 0, 0)
        at_seq.append(at + 11)
        at_data.append(at + len(header))
        parts.append(header + bytes(size))
        at += len(header) + size
    return np.frombuffer(b"".join(parts), dtype=np.uint8), at_seq, at_data, at


def fresh_bag_dir(parent: Path, prefix: str, when_s: float | None = None) -> Path:
    """Create and return a new empty bag directory `parent/<prefix>_%Y%m%d_%H%M%S` (local time `when_s`, default
    now), or, if that exists, the first of `..._2`, `..._3`, ... that does not: a node restarted within the same
    second, or two nodes sharing `parent`, each get their own (mkdir is atomic: a name taken meanwhile is skipped)."""
    parent = Path(parent)
    stamp = time.strftime(f"{prefix}_%Y%m%d_%H%M%S", time.localtime(when_s))
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"cannot create bag directory {parent}: {exc.strerror or exc}") from None
    for n in range(1, 10000):
        path = parent / (stamp if n == 1 else f"{stamp}_{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            raise RecordingError(f"cannot create bag directory {path}: {exc.strerror or exc}") from None
        return path
    raise RecordingError(f"no free bag directory name {stamp}_N in {parent}")


def _prepare_dir(bag_dir: Path) -> Path:
    """Create the bag directory; refuse a non-empty existing one or one we cannot write."""
    bag_dir = Path(bag_dir)
    if bag_dir.exists():
        if not bag_dir.is_dir():
            raise RecordingError(f"bag path {bag_dir} exists and is not a directory")
        if any(bag_dir.iterdir()):
            raise RecordingError(f"bag directory {bag_dir} already exists and is not empty")
    try:
        bag_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"cannot create bag directory {bag_dir}: {exc.strerror or exc}") from None
    return bag_dir


#: the recorder's chunk size: a damaged chunk loses its messages only (``bag recover`` writes the same size)
CHUNK_SIZE_BYTES = 64 * 1024


class BagWriter:
    """Write rclpy messages into `bag_dir/<name>_0.mcap` and, on close, `metadata.yaml`.

    Chunks of about `chunk_size_bytes` (no compression); everything buffered is flushed to the OS
    at least every `flush_period_s` (on the next write, or by a background flusher when idle), so
    a SIGKILL loses at most about one flush period. Thread-safe. Writes after `close()` are
    dropped and counted in `dropped_after_close` (shutdown races in callbacks must not crash).
    The bag's lock (:mod:`panel_rig.recording.lock`) is held from construction to `close()`, so
    `bag recover` and the readers see that the bag is still being recorded.
    """

    def __init__(
        self,
        bag_dir: Path,
        *,
        chunk_size_bytes: int = CHUNK_SIZE_BYTES,
        flush_period_s: float = 0.5,
    ) -> None:
        if chunk_size_bytes <= 0 or not flush_period_s > 0:
            raise RecordingError("chunk_size_bytes and flush_period_s must be positive")
        self.bag_dir = _prepare_dir(Path(bag_dir))
        self.mcap_path = self.bag_dir / f"{self.bag_dir.name}_0.mcap"
        try:  # held until close (or the death of this process): `bag recover` and readers see a live bag
            self._bag_lock = BagLock(self.bag_dir, "record")
        except OSError as exc:
            raise RecordingError(f"cannot lock bag directory {self.bag_dir}: {exc.strerror or exc}") from None
        self.flush_period_s = float(flush_period_s)
        self.dropped_after_close = 0
        self._lock = threading.Lock()
        self._inside = threading.local()  # .held: this thread is in the critical section (acquiring and releasing included)
        self._close_requested = False
        self._closed = False
        self._dirty = False
        self._last_flush_s = time.monotonic()
        self._channels: dict[str, _Channel] = {}
        self._schema_ids: dict[str, int] = {}
        self._summary = BagSummary(file_name=self.mcap_path.name)
        try:
            self._stream = self._open_stream()
        except BaseException:
            self._bag_lock.release()
            raise
        self._writer = Writer(
            self._stream, chunk_size=chunk_size_bytes, compression=CompressionType.NONE
        )
        self._writer.start(profile=PROFILE, library=LIBRARY)
        self._stream.flush()
        self._stop = threading.Event()
        self._flusher = threading.Thread(
            target=self._flush_loop, name=f"bag-flush-{self.bag_dir.name}", daemon=True
        )
        self._flusher.start()

    # ----------------------------------------------------------------- public API
    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def message_count(self) -> int:
        return self._summary.message_count

    def topic_counts(self) -> dict[str, int]:
        """Messages written so far per topic."""
        return {t.name: t.message_count for t in self._summary.topics}

    def write(self, topic: str, msg: Any, stamp_ns: int, *, qos: str = "sensor", data: bytes | None = None) -> bool:
        """Record `msg` on `topic` at `stamp_ns` (log and publish time). False if closed.

        `data`: `msg` already serialised (`rclpy.serialization.serialize_message(msg)`), e.g. the bytes just
        published, so the message is serialised once; `msg` is still needed for its type.
        """
        if not isinstance(topic, str) or not topic.startswith("/") or len(topic) < 2:
            raise RecordingError(f"topic must be an absolute ROS name like '/rig/x', got {topic!r}")
        if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, int) or stamp_ns < 0:
            raise RecordingError(f"stamp_ns must be a non-negative int, got {stamp_ns!r}")
        with self._critical():
            if self._closed:
                self.dropped_after_close += 1
                return False
            channel = self._channel(topic, msg, qos)
            self._add_locked(channel, msg, stamp_ns, _serialize(msg) if data is None else data)
            self._dirty = True
            if time.monotonic() - self._last_flush_s >= self.flush_period_s:
                self._flush_locked()
        return True

    def write_block(self, topics: Sequence[tuple[str, Any]], stamps_ns: np.ndarray, payloads: Sequence[np.ndarray],
                    *, qos: str = "sensor") -> bool:
        """Record N samples of several fixed-size topics at once: for each sample i, for each topic k in order,
        the message ``payloads[k][i]`` (an (N, size_k) uint8 array of CDR) on ``topics[k] = (name, msg)``
        (``msg`` gives the type) at ``stamps_ns[i]``. The bag is byte for byte what ``write`` called per
        message in that order gives (same records, sequence numbers, chunk boundaries and indexes), but the
        MCAP records are built with numpy. False if closed."""
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        n, k_topics = stamps.shape[0], len(topics)
        arrays = [np.asarray(p) for p in payloads]
        if len(arrays) != k_topics or any(a.ndim != 2 or a.dtype != np.uint8 or a.shape[0] != n for a in arrays):
            raise RecordingError("write_block: one (N, size) uint8 payload array per topic expected")
        for name, _ in topics:
            if not isinstance(name, str) or not name.startswith("/") or len(name) < 2:
                raise RecordingError(f"topic must be an absolute ROS name like '/rig/x', got {name!r}")
        if n and int(stamps.min()) < 0:
            raise RecordingError("stamp_ns must be non-negative")
        with self._critical():
            if self._closed:
                self.dropped_after_close += n * k_topics
                return False
            if not n:
                return True
            channels = [self._channel(name, msg, qos) for name, msg in topics]
            fast = _McapInternals.of(self._writer)
            if fast is None or any(c.may_end_empty and ends_with_empty_sequence(msg)
                                   for c, (_, msg) in zip(channels, topics)):
                for i in range(n):  # the per-message path (a trimmed tail, or an mcap without the internals)
                    for (name, msg), a, c in zip(topics, arrays, channels):
                        self._add_locked(c, msg, int(stamps[i]), a[i].tobytes())
            else:
                fast.add_block(channels, stamps, arrays)
                for c in channels:
                    c.sequence += n
                    c.info.message_count += n
                self._summary.note_stamp(int(stamps.min()))
                self._summary.note_stamp(int(stamps.max()))
            self._dirty = True
            if time.monotonic() - self._last_flush_s >= self.flush_period_s:
                self._flush_locked()
        return True

    def write_parameters(self, params: dict[str, Any]) -> None:
        """Record run parameters: MCAP metadata `panel_rig/parameters` + metadata.yaml custom_data.

        Values are stored as JSON text (non-JSON values via `str`).
        """
        if not isinstance(params, dict):
            raise RecordingError(f"parameters must be a dict, got {type(params).__name__}")
        record = {str(k): json.dumps(v, default=str) for k, v in params.items()}
        with self._critical():
            if self._closed:
                raise RecordingError("bag is closed")
            self._writer.add_metadata(PARAMETERS_RECORD, record)
            self._summary.custom_data[PARAMETERS_KEY] = json.dumps(
                params, default=str, sort_keys=True
            )
            self._dirty = True

    def flush(self) -> None:
        """Finish the open chunk and hand everything to the OS now."""
        with self._critical():
            if not self._closed:
                self._flush_locked()

    def close(self) -> None:
        """Finish the MCAP (summary, footer) and write metadata.yaml. Idempotent.

        Safe from a signal handler: if the signal interrupted this same thread inside `write`,
        the close is deferred to the end of that call instead of deadlocking. The handler should
        call `close()` and return (let the main loop see `closed` and stop) rather than raise,
        so that an interrupted write completes before the file is finished.
        """
        if self._closed:
            return
        if getattr(self._inside, "held", False):
            self._close_requested = True
            return
        with self._critical():
            self._close_locked()
        self._stop.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join(timeout=2.0)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _open_stream(self) -> BinaryIO:
        try:
            return open(self.mcap_path, "xb")
        except OSError as exc:
            raise RecordingError(f"cannot create {self.mcap_path}: {exc.strerror or exc}") from None

    class _Critical:
        def __init__(self, owner: BagWriter) -> None:
            self.owner = owner

        # The thread's mark covers the lock's whole tenure, acquiring and releasing included: a close() from a signal
        # handler landing there is deferred; set after acquire (or cleared before release), a signal in between
        # made close() take the lock this thread held: a deadlock (a CI run hung in the SIGTERM test).
        def __enter__(self) -> None:
            self.owner._inside.held = True
            self.owner._lock.acquire()

        def __exit__(self, *exc: object) -> None:
            owner = self.owner
            try:
                if owner._close_requested and not owner._closed:
                    owner._close_locked()
            finally:
                owner._lock.release()
                owner._inside.held = False
            if owner._close_requested and not owner._closed:  # requested after the check above
                owner.close()
            if owner._closed:
                owner._stop.set()

    def _critical(self) -> BagWriter._Critical:
        return BagWriter._Critical(self)

    def _channel(self, topic: str, msg: Any, qos: str) -> _Channel:
        channel = self._channels.get(topic)
        if channel is not None and type(msg) is channel.msg_class:
            return channel
        type_name = schemas.type_name_of(msg)
        if channel is not None:
            if channel.info.type != type_name:
                raise RecordingError(
                    f"topic {topic} was recorded as {channel.info.type}, not {type_name}"
                )
            return channel
        profiles = offered_qos(qos)
        schema = schemas.schema_text(type_name)
        info = TopicInfo(topic, type_name, profiles, schemas.type_hash(type_name))
        schema_id = self._schema_ids.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                type_name, schemas.SCHEMA_ENCODING, schema.encode("utf-8")
            )
            self._schema_ids[type_name] = schema_id
        channel_id = self._writer.register_channel(
            topic, MESSAGE_ENCODING, schema_id,
            {"offered_qos_profiles": qos_yaml(profiles), "topic_type_hash": info.type_description_hash},
        )
        channel = _Channel(channel_id, info, schema, type(msg))
        self._channels[topic] = channel
        self._summary.topics.append(info)
        return channel

    def _add_locked(self, channel: _Channel, msg: Any, stamp_ns: int, data: bytes) -> None:
        if channel.may_end_empty:
            data = trim_trailing_padding(channel.info.type, channel.schema, msg, data)
        self._writer.add_message(
            channel.channel_id, log_time=stamp_ns, data=data,
            publish_time=stamp_ns, sequence=channel.sequence,
        )
        channel.sequence += 1
        channel.info.message_count += 1
        self._summary.note_stamp(stamp_ns)

    def _flush_locked(self) -> None:
        try:
            self._writer.flush()
        except OSError as exc:
            raise RecordingError(f"cannot write {self.mcap_path}: {exc.strerror or exc}") from None
        self._dirty = False
        self._last_flush_s = time.monotonic()

    def _close_locked(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            try:
                self._writer.add_metadata("rosbag2", {"serialized_metadata": dump_metadata(self._summary)})
                self._writer.finish()
                self._stream.close()
            except OSError as exc:
                with contextlib.suppress(OSError):  # the file's descriptor, not left open (a full disk fails twice)
                    self._stream.close()
                raise RecordingError(f"cannot finish {self.mcap_path}: {exc.strerror or exc}") from None
            write_metadata(self.bag_dir, self._summary)
        finally:
            self._bag_lock.release()

    def _flush_loop(self) -> None:
        while not self._stop.wait(self.flush_period_s):
            if not self._lock.acquire(timeout=self.flush_period_s):
                continue
            try:
                if not self._closed and self._dirty and (
                    time.monotonic() - self._last_flush_s >= self.flush_period_s * 0.9
                ):
                    self._flush_locked()
            except RecordingError:
                return
            finally:
                self._lock.release()

"""Reading bags written by `BagWriter` (or rosbag2): decoded messages, counts, integrity."""

from __future__ import annotations

import contextlib
import re
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Schema
from mcap.stream_reader import get_chunk_data_stream

from panel_rig.recording.errors import BagInUseError, CorruptBagError, RecordingError
from panel_rig.recording.integrity import McapScan, chunk_records, scan_mcap
from panel_rig.recording.lock import lock_holder
from panel_rig.recording.metadata import METADATA_FILE, read_metadata


def find_mcap(bag_dir: Path) -> Path:
    """The bag's MCAP file: from metadata.yaml if present, else the single `*.mcap` in the dir."""
    bag_dir = Path(bag_dir)
    require_bag_dir(bag_dir)
    if (bag_dir / METADATA_FILE).is_file():
        files = read_metadata(bag_dir).get("relative_file_paths") or []
        if isinstance(files, list) and files and isinstance(files[0], str) and (bag_dir / files[0]).is_file():
            return bag_dir / files[0]
    return single_mcap(bag_dir)


def require_bag_dir(bag_dir: Path) -> None:
    """Raise RecordingError unless ``bag_dir`` is a directory, saying what it is instead: a bag's own .mcap file
    (`analyze bags/x/x_0.mcap`) names the directory to give, a missing path says so."""
    bag_dir = Path(bag_dir)
    if bag_dir.is_dir():
        return
    if not bag_dir.exists():
        raise RecordingError(f"{bag_dir} is not a bag directory: it does not exist")
    if bag_dir.suffix == ".mcap":
        raise RecordingError(f"{bag_dir} is not a bag directory: it is a bag's MCAP file; give the directory that "
                             f"holds it ({bag_dir.parent})")
    raise RecordingError(f"{bag_dir} is not a bag directory: it is a file")


def single_mcap(bag_dir: Path) -> Path:
    """The one `*.mcap` file in `bag_dir` (metadata.yaml not consulted)."""
    candidates = sorted(Path(bag_dir).glob("*.mcap"))
    if len(candidates) != 1:
        hint = _bags_inside(bag_dir) or _analysis_output(bag_dir)
        raise RecordingError(f"expected one .mcap file in {bag_dir}, found {len(candidates)}{hint}")
    return candidates[0]


def _analysis_output(directory: Path) -> str:
    """"; it holds an analysis's output (analysis.json) of the bag X: give that" when ``directory`` is where an
    analysis wrote (`make run`'s out/demo), else ""."""
    import json

    try:
        bag = json.loads((Path(directory) / "analysis.json").read_text()).get("bag")
    except (OSError, ValueError, AttributeError):
        return ""
    return f"; it holds an analysis's output (analysis.json) of the bag {bag}: give that" if bag else ""


def _bags_inside(directory: Path) -> str:
    """", it holds the bag(s) NAME: give that directory" when ``directory`` has bag directories (a flutter test's run
    directory holds its node's bag), else ""."""
    bags = sorted(p.name for p in Path(directory).iterdir()
                  if p.is_dir() and ((p / METADATA_FILE).is_file() or any(p.glob("*.mcap"))))
    if not bags:
        return ""
    shown = ", ".join(bags[:3]) + (f" and {len(bags) - 3} more" if len(bags) > 3 else "")
    return f"; it holds the bag{'s' if len(bags) > 1 else ''} {shown}: give {'one' if len(bags) > 1 else 'it'}"


def has_summary(mcap_path: Path) -> bool:
    """True if the MCAP file is complete (footer and summary readable)."""
    try:
        with open(mcap_path, "rb") as f:
            return make_reader(f).get_summary() is not None
    except (McapError, OSError, ValueError, EOFError, IndexError):
        return False
    except Exception:  # noqa: BLE001 - a truncated file can fail in struct/parse code
        return False


def read_bag(
    bag_dir: Path, topics: list[str] | None = None
) -> Iterator[tuple[str, str, int, Any]]:
    """Yield (topic, type, stamp_ns, decoded message) in log-time order; chunk CRCs are checked.

    Decoding goes through `mcap.reader.make_reader` with the mcap-ros2 `DecoderFactory`. A damaged
    file raises RecordingError (never a parser exception); `verify_bag` says what is damaged.
    """
    from mcap_ros2.decoder import DecoderFactory

    path = find_mcap(bag_dir)
    with _reading(bag_dir, path), open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
            yield channel.topic, schema.name if schema else "", message.log_time, decoded


#: what a raw reader yields per message: (topic, type, stamp_ns, CDR bytes, decode)
RawMessage = tuple[str, str, int, bytes, Callable[[bytes], Any]]


class ChunkMessages:
    """The messages of the wanted ``topics`` (None: all) among a chunk's records, as :data:`RawMessage`; the schema
    and channel records met on the way are kept for the messages that follow them (MCAP writes them first)."""

    def __init__(self, path: Path, topics: list[str] | None = None, channels: dict[int, Channel] | None = None,
                 schemas: dict[int, Schema] | None = None) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self.path, self.topics = path, topics
        self.channels, self.schemas = dict(channels or {}), dict(schemas or {})
        self._factory = DecoderFactory()
        self._decoders: dict[int, Callable[[bytes], Any]] = {}  # per channel: a lookup per message took a sixth

    def __call__(self, records: list[Any]) -> Iterator[RawMessage]:
        for record in records:
            if isinstance(record, Schema):
                self.schemas[record.id] = record
            elif isinstance(record, Channel):
                self.channels[record.id] = record
            elif self.topics is None or self.channels[record.channel_id].topic in self.topics:
                channel = self.channels[record.channel_id]
                schema = self.schemas.get(channel.schema_id)
                decode = self._decoders.get(record.channel_id)
                if decode is None:
                    decode = self._decoders[record.channel_id] = _decoder(self._factory, channel, schema, self.path)
                yield (channel.topic, schema.name if schema else "", record.log_time, record.data, decode)


def read_bag_raw(bag_dir: Path, topics: list[str] | None = None) -> Iterator[RawMessage]:
    """Yield (topic, type, stamp_ns, CDR bytes, decode) in the file's order (not sorted by log time: the caller
    sorts), for a bag :func:`verify_bag` has just checked (chunk CRCs are not checked again). ``decode(bytes)`` is the
    mcap-ros2 decoder of the message's type, for what the caller does not read itself. Errors as :func:`read_bag`.

    The chunks are found through the summary's chunk index and their records read by
    :func:`~panel_rig.recording.integrity.chunk_records`: mcap's record parser and its merge into log-time order
    took two thirds of reading a flutter test's bag. A file without chunk index is read by mcap's own reader.
    :func:`read_verified` checks and reads in one pass."""
    from mcap_ros2.decoder import DecoderFactory

    path = find_mcap(bag_dir)
    with _reading(bag_dir, path), open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=False)
        summary = reader.get_summary()
        if summary is None or not summary.chunk_indexes:
            factory = DecoderFactory()
            for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=False):
                yield (channel.topic, schema.name if schema else "", message.log_time, message.data,
                       _decoder(factory, channel, schema, path))
            return
        messages = ChunkMessages(path, topics, dict(summary.channels), dict(summary.schemas))
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 9)
            stream, size = get_chunk_data_stream(Chunk.read(ReadDataStream(f)), validate_crc=False)
            yield from messages(chunk_records(stream.read(size)))


def read_verified(bag_dir: Path, topics: list[str] | None, take: Callable[[RawMessage], None]) -> bool:
    """:func:`verify_bag` and :func:`read_bag_raw` in one pass over the file: ``take(message)`` for each message of
    ``topics`` (None: all) in the file's order, as the integrity scan parses its chunk (each chunk was parsed twice,
    half of reading a flutter test's bag). Raises as :func:`verify_bag` after the scan: what ``take`` got from a bag
    found damaged must be dropped. False for an intact file with messages outside chunks (not the rig writer's):
    ``take`` did not get those, and the caller reads the file with :func:`read_bag_raw` instead."""
    path = find_mcap(bag_dir)
    messages = ChunkMessages(path, topics)

    def on_chunk(records: list[Any], scan: McapScan) -> None:
        for key, channel in scan.channels.items():  # those written outside chunks too (other writers than ours)
            messages.channels.setdefault(key, channel)
        for key, schema in scan.schemas.items():
            messages.schemas.setdefault(key, schema)
        for message in messages(records):
            take(message)

    with _reading(bag_dir, path):
        scan = verify_bag(bag_dir, on_chunk)
    return not scan.loose_messages


def _decoder(factory: Any, channel: Channel, schema: Schema | None, path: Path) -> Callable[[bytes], Any]:
    decode = factory.decoder_for(channel.message_encoding, schema)
    if decode is None:
        raise RecordingError(f"{path}: not a ROS 2 recording (messages in {channel.message_encoding}, not cdr); "
                             "panel_rig reads rosbag2 MCAP")
    return decode


@contextlib.contextmanager
def _reading(bag_dir: Path, path: Path) -> Iterator[None]:
    """Parser and decoder errors of reading ``path`` as one-line RecordingErrors."""
    try:
        yield
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - corrupt bytes fail anywhere in the parser/decoder
        _refuse_live(bag_dir)
        if type(exc).__name__ == "DecoderNotFoundError":  # intact, but not ROS 2 CDR: recover cannot help
            found = re.search(r"message encoding (\w+)", str(exc))
            encoding = found[1] if found else "another encoding"
            raise RecordingError(f"{path}: not a ROS 2 recording (messages in {encoding}, not cdr); panel_rig "
                                 "reads rosbag2 MCAP") from None
        raise CorruptBagError(
            f"cannot read {path} ({type(exc).__name__}); run `panel-rig bag recover {bag_dir}`"
        ) from None


def not_a_recording(path: Path, scan: McapScan) -> str:
    """What an MCAP file with no header and no chunk (``scan.recoverable`` false) is: empty, or not MCAP."""
    return f"{path} is empty (0 bytes)" if scan.size == 0 else f"{path} is not an MCAP file (no valid header, no chunk)"


def verify_bag(bag_dir: Path, on_chunk: Callable[[list[Any], McapScan], None] | None = None) -> McapScan:
    """Scan the bag's MCAP (every chunk CRC, summary, index); raise CorruptBagError if not intact.

    The error is one line: the first problem (chunk index, byte offset, time range), how many more,
    and the `panel-rig bag recover` command that rebuilds the bag from its intact chunks; for a bag whose
    lock is held (still being recorded), BagInUseError saying so. ``on_chunk``: as :func:`scan_mcap`'s.
    """
    path = find_mcap(bag_dir)
    scan = scan_mcap(path, on_chunk)
    if not scan.ok:
        _refuse_live(bag_dir)
        if not scan.recoverable:  # `bag recover` would refuse it too: no header and no chunk to rebuild from
            raise RecordingError(f"{not_a_recording(path, scan)}: no recording in it to read or to rebuild")
        if scan.truncated and not scan.bad_chunks:
            what = f"{path} has no summary (recorder killed?)"
        else:
            what = scan.summary_line().replace(f"{path}: ", f"{path} is corrupt: ", 1)
        raise CorruptBagError(f"{what}; run `panel-rig bag recover {bag_dir}`", scan)
    return scan


def _refuse_live(bag_dir: Path) -> None:
    """Raise BagInUseError if a process holds the bag's lock (its MCAP has no summary yet: not damaged)."""
    holder = lock_holder(bag_dir)
    if holder is not None:
        raise BagInUseError(f"{bag_dir} is still {holder.describe()}: read it when that has finished", holder.pid)


def topic_counts(bag_dir: Path) -> dict[str, int]:
    """Messages per topic, counted by decoding every message."""
    return dict(Counter(topic for topic, _, _, _ in read_bag(bag_dir)))


def summary_counts(mcap_path: Path) -> dict[str, int]:
    """Messages per topic from the MCAP summary statistics (no decoding)."""
    with open(mcap_path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        raise RecordingError(f"{mcap_path} has no summary statistics")
    counts = summary.statistics.channel_message_counts
    return {ch.topic: counts.get(cid, 0) for cid, ch in summary.channels.items()}


def read_metadata_records(mcap_path: Path) -> dict[str, dict[str, str]]:
    """MCAP metadata records by name (e.g. `panel_rig/parameters`)."""
    with open(mcap_path, "rb") as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}

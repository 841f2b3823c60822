"""Integrity of an MCAP file: every chunk against its CRC, the data-section and summary CRCs, the index.

`scan_mcap` walks the data section record by record (opcode, length) without trusting the summary.
Every chunk is checked against its `uncompressed_crc` and its header against the messages it holds;
where a damaged length field breaks the record framing, the scan resynchronises on the next chunk
whose CRC verifies (a false match is a 1 in 2^32 event). The data-section CRC of DataEnd and the
summary CRC of the Footer are checked when the writer set them (non-zero), and the summary's chunk
index is compared with the chunks found. The result lists the intact records (for `recover`) and
every problem with its chunk index, byte offset and time range (for `analyze` and `bag recover`).
"""

from __future__ import annotations

import heapq
import io
import itertools
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import StreamReader

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_CHUNK, OP_MESSAGE_INDEX, OP_DATA_END = 0x01, 0x02, 0x06, 0x07, 0x0F
MAX_OPCODE = 0x0F
_FRAME = struct.Struct("<BQ")  # opcode, content length
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
FOOTER_LEN = 1 + 8 + 20  # opcode + length + (summary_start, summary_offset_start, summary_crc)
_COMPRESSIONS = ("", "zstd", "lz4")


@dataclass
class ChunkInfo:
    """One chunk of the data section; `problem` is empty if it is intact."""

    index: int  # 0-based, in file order among the chunks found
    offset: int  # byte offset of the chunk record (its opcode) in the file
    length: int  # record length including opcode and length field
    start_ns: int
    end_ns: int
    messages: int = 0  # decoded (intact) or listed by its message index (corrupt; -1 if unknown)
    topic_counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages
    problem: str = ""

    @property
    def ok(self) -> bool:
        return not self.problem


@dataclass
class Problem:
    """Something wrong in the file: where (byte offset, chunk index if any), what, which times."""

    offset: int
    what: str
    chunk: ChunkInfo | None = None
    length: int = 0


@dataclass
class McapScan:
    """Everything `scan_mcap` found; `ok` is True for an intact, complete file."""

    path: Path
    size: int
    header_ok: bool = False
    profile: str = ""
    chunks: list[ChunkInfo] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    message_count: int = 0  # of the intact chunks and the unchunked records (:func:`messages_in_time_order`)
    loose_messages: list[Message] = field(default_factory=list)  # outside chunks (the rig's writer makes none)
    metadata: list[Metadata] = field(default_factory=list)
    data_end_offset: int | None = None  # where DataEnd was found
    good_end: int = 0  # end of the last intact record of the data section
    footer: Footer | None = None
    summary_ok: bool = False
    truncated: bool = False  # the data section runs into the end of the file (no DataEnd)
    data_crc_stored: int = 0  # DataEnd's data_section_crc (0: not set by the writer)
    data_crc: str = "absent"  # "absent" (0 or no DataEnd), "ok", "mismatch"
    summary_crc: str = "absent"  # "absent", "ok", "mismatch"
    summary_message_count: int | None = None  # the summary's Statistics, when readable (what the writer wrote)

    @property
    def complete(self) -> bool:
        """Footer and summary present and consistent (what ordinary readers need)."""
        return self.footer is not None and self.summary_ok

    @property
    def ok(self) -> bool:
        return self.header_ok and self.complete and not self.problems

    @property
    def recoverable(self) -> bool:
        """A header or a chunk to rebuild from: what `bag recover` needs (random bytes, an empty file or the bare
        magic have neither)."""
        return self.header_ok or bool(self.chunks)

    @property
    def bad_chunks(self) -> list[ChunkInfo]:
        return [c for c in self.chunks if not c.ok]

    @property
    def start_ns(self) -> int | None:
        """First message time: of the intact chunks, else of any chunk header near their median."""
        times = sorted(c.start_ns for c in self.chunks if c.start_ns <= c.end_ns)
        if not times:
            return None
        median = times[len(times) // 2]
        return min(t for t in times if abs(t - median) < 10**15)  # a damaged header is far off

    def channel_topic(self, channel_id: int) -> str:
        ch = self.channels.get(channel_id)
        return ch.topic if ch is not None else f"channel {channel_id}"

    def describe(self, p: Problem) -> str:
        """`chunk 9 at byte 723118 (t 23.10-25.93 s, 512 messages): CRC mismatch`."""
        if p.chunk is None:
            return f"from byte {p.offset}: {p.what}"  # "dropped byte N" read as one byte
        c = p.chunk
        where = f"chunk {c.index} at byte {c.offset}"
        details = [self.time_range(c.start_ns, c.end_ns)]
        if c.messages >= 0:
            details.append(f"{c.messages} messages")
        return f"{where} ({', '.join(d for d in details if d)}): {p.what}"

    def time_range(self, start_ns: int, end_ns: int) -> str:
        t0 = self.start_ns
        if t0 is None or not (0 <= start_ns <= end_ns) or end_ns - t0 > 10**15 or start_ns < t0 - 10**15:
            return ""
        return f"t {(start_ns - t0) * 1e-9:.2f}-{(end_ns - t0) * 1e-9:.2f} s"

    def summary_line(self) -> str:
        """One line: what is wrong (first problem and how many more)."""
        if self.ok:
            return f"{self.path}: intact ({len(self.chunks)} chunks, {self.message_count} messages)"
        if not self.problems:
            return f"{self.path}: no summary (writer killed?)"
        more = len(self.problems) - 1
        bad = len(self.bad_chunks)
        text = f"{self.path}: {self.describe(self.problems[0])}"
        if more:
            text += f"; {more} more problem{'s' if more > 1 else ''}"
        if bad:
            text += f" ({bad} corrupt chunk{'s' if bad > 1 else ''} of {len(self.chunks)})"
        return text


# ------------------------------------------------------------------------------------ parsing
def _one_record(raw: bytes) -> Any:
    """Parse one framed record (opcode + length + content) with mcap's record classes."""
    reader = StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True, record_size_limit=None)
    return next(iter(reader.records))


def _what_broke(exc: Exception) -> str:
    """Plain words for a parser failure on corrupt bytes (no exception class names in a user's error line)."""
    if isinstance(exc, UnicodeDecodeError):
        return "a text field is not valid UTF-8"
    if isinstance(exc, (struct.error, EOFError, IndexError)):
        return "a length field points past the record"
    return "its content does not parse"


def _parse_chunk(raw: bytes) -> tuple[ChunkInfo, list[Any], str]:
    """(info, inner records, problem) of one chunk record; raw starts at its opcode."""
    start, end, usize, crc, clen = _CHUNK_HEAD.unpack_from(raw, 9)
    info = ChunkInfo(index=-1, offset=0, length=len(raw), start_ns=start, end_ns=end)
    try:
        data = _chunk_data(_one_record(raw))
        records = chunk_records(data)
    except Exception as exc:  # noqa: BLE001 - corrupt content can fail anywhere in the parser
        return info, [], f"unreadable chunk ({_what_broke(exc)})"
    if crc != 0 and zlib.crc32(data) != crc:
        return info, [], f"CRC mismatch (stored {crc:08x}, computed {zlib.crc32(data):08x})"
    if len(data) != usize:
        return info, [], f"uncompressed size {len(data)} != header {usize}"
    times = [r.log_time for r in records if isinstance(r, Message)]
    if times and (min(times) != start or max(times) != end):
        return info, [], "chunk header time range disagrees with its messages"
    info.messages = len(times)
    for r in records:
        if isinstance(r, Message):
            info.topic_counts[r.channel_id] = info.topic_counts.get(r.channel_id, 0) + 1
    return info, records, ""


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def chunk_records(data: bytes) -> list[Any]:
    """The records of a chunk's uncompressed ``data``: schemas, channels and messages (others skipped, as mcap
    does). Message records are read at fixed offsets: mcap's general record parser took a third of reading a bag.
    Raises EOFError for a record that runs past the end."""
    out: list[Any] = []
    pos, size = 0, len(data)
    while pos < size:
        if pos + _FRAME.size > size:
            raise EOFError("a record frame cut off by the chunk's end")
        opcode, length = _FRAME.unpack_from(data, pos)
        body, pos = pos + _FRAME.size, pos + _FRAME.size + length
        if pos > size:
            raise EOFError("a record runs past the chunk's end")
        if opcode == Opcode.MESSAGE:
            if length < _MESSAGE_HEAD.size:
                raise EOFError("a message record shorter than its header")
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, body)
            out.append(Message(channel_id=channel_id, sequence=sequence, log_time=log_time,
                               publish_time=publish_time, data=data[body + _MESSAGE_HEAD.size : pos]))
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            kind = Schema if opcode == Opcode.SCHEMA else Channel
            out.append(kind.read(ReadDataStream(io.BytesIO(data[body:pos]))))
    return out


def _chunk_data(chunk: Any) -> bytes:
    from mcap.stream_reader import get_chunk_data_stream

    stream, length = get_chunk_data_stream(chunk, validate_crc=False)
    return stream.read(length)


def _plausible_chunk(head: bytes, pos: int, limit: int) -> bool:
    """Cheap test that a chunk record could start at `pos` (head: its first 9 + 32 + 16 bytes)."""
    if len(head) < 9 + _CHUNK_HEAD.size or head[0] != OP_CHUNK:
        return False
    _, length = _FRAME.unpack_from(head, 0)
    if pos + 9 + length > limit or length < _CHUNK_HEAD.size + 8:
        return False
    start, end, usize, _crc, clen = _CHUNK_HEAD.unpack_from(head, 9)
    if clen > 8 or start > end or usize > 2**40:
        return False
    off = 9 + _CHUNK_HEAD.size
    if len(head) < off + clen + 8 or head[off : off + clen].decode("latin-1") not in _COMPRESSIONS:
        return False
    (rlen,) = struct.unpack_from("<Q", head, off + clen)
    return rlen == length - _CHUNK_HEAD.size - clen - 8


def _resync(f: io.BufferedReader, pos: int, limit: int) -> int | None:
    """Offset of the next chunk record after `pos` whose CRC verifies, or None."""
    block = 1 << 20
    while pos < limit:
        f.seek(pos)
        buf = f.read(min(block, limit - pos) + 64)
        i = buf.find(bytes([OP_CHUNK]))
        while i != -1 and pos + i < limit:
            cand = pos + i
            head = buf[i : i + 64] if i + 64 <= len(buf) else _read_at(f, cand, 64)
            if _plausible_chunk(head, cand, limit):
                _, length = _FRAME.unpack_from(head, 0)
                raw = _read_at(f, cand, 9 + length)
                _, _, problem = _parse_chunk(raw)
                if not problem:
                    return cand
            i = buf.find(bytes([OP_CHUNK]), i + 1)
        pos += block
    return None


def _read_at(f: io.BufferedReader, pos: int, n: int) -> bytes:
    f.seek(pos)
    return f.read(n)


def _read_footer(f: io.BufferedReader, size: int) -> Footer | None:
    if size < len(MAGIC) * 2 + FOOTER_LEN:
        return None
    tail = _read_at(f, size - len(MAGIC) - FOOTER_LEN, FOOTER_LEN + len(MAGIC))
    if tail[-len(MAGIC) :] != MAGIC or tail[0] != OP_FOOTER or _FRAME.unpack_from(tail, 0)[1] != 20:
        return None
    start, offset_start, crc = struct.unpack_from("<QQI", tail, 9)
    footer_pos = size - len(MAGIC) - FOOTER_LEN
    if not (start == 0 or len(MAGIC) < start <= footer_pos) or not (offset_start == 0 or start <= offset_start <= footer_pos):
        return None
    return Footer(summary_start=start, summary_offset_start=offset_start, summary_crc=crc)


def _message_index_counts(raw: bytes) -> tuple[int, int]:
    """(channel id, entries) of a MessageIndex record."""
    channel_id, nbytes = struct.unpack_from("<HI", raw, 9)
    if nbytes % 16 or 9 + 6 + nbytes > len(raw):
        raise ValueError("bad message index")
    return channel_id, nbytes // 16


def _take(scan: McapScan, record: Any, loose: bool = False) -> None:
    """Note a record: schemas, channels and metadata are kept; messages are counted (and kept only when ``loose``,
    outside any chunk: a chunk's are read again by :func:`messages_in_time_order`)."""
    if isinstance(record, Schema):
        scan.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        scan.channels.setdefault(record.id, record)
    elif isinstance(record, Message):
        scan.message_count += 1
        if loose:
            scan.loose_messages.append(record)
    elif isinstance(record, Metadata):
        scan.metadata.append(record)


# ------------------------------------------------------------------------------------ the scan
def scan_mcap(path: Path, on_chunk: Callable[[list[Any], McapScan], None] | None = None) -> McapScan:
    """Walk the whole file (see the module docstring); never raises on content, only on I/O. The messages of
    the chunks are counted, not held (holding them took 2.4 x the file's size in memory); read them with
    :func:`messages_in_time_order`, or take each intact chunk's records as the scan parses them: ``on_chunk(records, scan)``
    (in file order; ``scan`` has the schemas and channels met so far, also those written outside chunks; a reader
    of a bag found damaged afterwards must drop what it took)."""
    path = Path(path)
    size = path.stat().st_size
    scan = McapScan(path=path, size=size)
    with open(path, "rb") as f:
        if _read_at(f, 0, len(MAGIC)) != MAGIC:
            scan.problems.append(Problem(0, "not an MCAP file (no magic)"))
            return scan
        scan.footer = _read_footer(f, size)
        footer_pos = size - len(MAGIC) - FOOTER_LEN
        limit = (scan.footer.summary_start or footer_pos) if scan.footer else size
        _scan_data(scan, f, limit, on_chunk)
        if scan.footer is None:
            if not scan.truncated and scan.data_end_offset is not None:
                scan.problems.append(Problem(footer_pos, "footer missing or corrupt"))
        else:
            _check_summary(scan, f, footer_pos)
        if scan.data_end_offset is not None:
            _check_data_crc(scan, f)
    scan.problems.sort(key=lambda p: p.offset)
    return scan


def messages_in_time_order(scan: McapScan) -> Iterator[Message]:
    """The messages of the scan's intact chunks and its unchunked ones, in log-time order (file order among equal
    times within a chunk), read chunk by chunk from the file again: only the chunks that overlap in time are held
    at once. A chunk that no longer verifies (the file changed since the scan) is left out."""
    chunks = sorted((c for c in scan.chunks if c.ok), key=lambda c: (c.start_ns, c.offset))
    order = itertools.count()
    pending = [(m.log_time, next(order), m) for m in scan.loose_messages]
    heapq.heapify(pending)
    with open(scan.path, "rb") as f:
        for chunk in chunks:
            while pending and pending[0][0] < chunk.start_ns:
                yield heapq.heappop(pending)[2]
            _, records, problem = _parse_chunk(_read_at(f, chunk.offset, chunk.length))
            for r in records if not problem else ():
                if isinstance(r, Message):
                    heapq.heappush(pending, (r.log_time, next(order), r))
    while pending:
        yield heapq.heappop(pending)[2]


_NEXT_OPCODES = (OP_CHUNK, OP_MESSAGE_INDEX, OP_DATA_END, 0x03, 0x04, 0x09, 0x0C)  # what may follow a chunk


def _frame_ok(f: io.BufferedReader, pos: int, limit: int) -> bool:
    head = _read_at(f, pos, 9)
    if pos == limit:
        return True
    if len(head) < 9:
        return False
    opcode, length = _FRAME.unpack(head)
    return opcode in _NEXT_OPCODES and pos + 9 + length <= limit


def _scan_data(scan: McapScan, f: io.BufferedReader, limit: int,
               on_chunk: Callable[[list[Any], McapScan], None] | None = None) -> None:
    pos = len(MAGIC)
    last_chunk: ChunkInfo | None = None
    while pos < limit:
        head = _read_at(f, pos, 9)
        opcode, length = _FRAME.unpack(head) if len(head) == 9 else (0, 0)
        end = pos + 9 + length
        if len(head) < 9 or opcode == 0 or opcode > MAX_OPCODE or end > limit:
            nxt = _resync(f, pos + 1, limit)
            if nxt is None and scan.footer is None:
                scan.truncated = True  # a record cut off by the end of the file: a killed writer
                scan.problems.append(Problem(pos, f"file ends inside a record at byte {pos} ({limit - pos} "
                                                  "bytes: writer killed or file truncated)", None, limit - pos))
                break
            stop = nxt if nxt is not None else limit
            scan.problems.append(Problem(pos, f"unreadable bytes {pos}-{stop} (broken record framing)",
                                         None, stop - pos))
            if nxt is None:
                break
            pos = nxt
            continue
        raw = _read_at(f, pos, 9 + length)
        if opcode == OP_CHUNK:
            info, records, problem = _parse_chunk(raw)
            info.index, info.offset = len(scan.chunks), pos
            scan.chunks.append(info)
            last_chunk = info
            if problem:
                info.problem, info.messages = problem, -1  # until a message index that follows lists them
                scan.problems.append(Problem(pos, problem, info, len(raw)))
                if not _frame_ok(f, end, limit):  # its length may be damaged: go to the next good chunk
                    nxt = _resync(f, pos + 1, limit)
                    end = nxt if nxt is not None else limit
            else:
                for r in records:
                    _take(scan, r)
                if on_chunk is not None:
                    on_chunk(records, scan)
                scan.good_end = end
        elif opcode == OP_MESSAGE_INDEX:
            try:
                channel_id, n = _message_index_counts(raw)
            except (struct.error, ValueError):
                scan.problems.append(Problem(pos, "corrupt message index", None, len(raw)))
            else:
                if last_chunk is not None and not last_chunk.ok:
                    last_chunk.topic_counts[channel_id] = last_chunk.topic_counts.get(channel_id, 0) + n
                    last_chunk.messages = max(last_chunk.messages, 0) + n
                elif last_chunk is not None and last_chunk.topic_counts.get(channel_id, 0) != n:
                    scan.problems.append(Problem(pos, "message index disagrees with its chunk", None, len(raw)))
            scan.good_end = end
        elif opcode == OP_DATA_END:
            scan.data_end_offset = pos
            try:
                scan.data_crc_stored = _one_record(raw).data_section_crc
            except Exception:  # noqa: BLE001
                scan.problems.append(Problem(pos, "corrupt DataEnd record", None, len(raw)))
            scan.good_end = end
            break
        else:
            try:
                record = _one_record(raw)
            except Exception as exc:  # noqa: BLE001 - e.g. UnicodeDecodeError in a corrupt string
                scan.problems.append(Problem(pos, f"corrupt record (opcode {opcode:#04x}: {_what_broke(exc)})",
                                             None, len(raw)))
            else:
                if isinstance(record, Header):
                    scan.header_ok, scan.profile = True, record.profile
                else:
                    _take(scan, record, loose=True)
                scan.good_end = end
        pos = end
    if scan.data_end_offset is None and not scan.truncated:
        if scan.footer is None:
            scan.truncated = True
            scan.problems.append(Problem(pos, "file ends without DataEnd, summary and footer (writer killed?)"))
        else:
            scan.problems.append(Problem(limit, "no DataEnd record before the summary"))
    if not scan.header_ok and not any(p.offset == len(MAGIC) for p in scan.problems):
        scan.problems.append(Problem(len(MAGIC), "no readable Header record"))


def _check_data_crc(scan: McapScan, f: io.BufferedReader) -> None:
    expected, end = scan.data_crc_stored, scan.data_end_offset or 0
    if not expected:
        return
    crc, pos = 0, 0
    f.seek(0)
    while pos < end:
        buf = f.read(min(1 << 20, end - pos))
        if not buf:
            break
        crc = zlib.crc32(buf, crc)
        pos += len(buf)
    scan.data_crc = "ok" if crc == expected else "mismatch"
    if crc != expected:
        scan.problems.append(Problem(end, f"data section CRC mismatch (stored {expected:08x}, computed {crc:08x})"))


def _check_summary(scan: McapScan, f: io.BufferedReader, footer_pos: int) -> None:
    footer = scan.footer
    assert footer is not None
    if footer.summary_start == 0:
        scan.problems.append(Problem(footer_pos, "file has no summary section"))
        return
    tail = _read_at(f, footer.summary_start, scan.size - footer.summary_start)
    if footer.summary_crc:
        crc = zlib.crc32(tail[: footer_pos + 9 + 16 - footer.summary_start])
        scan.summary_crc = "ok" if crc == footer.summary_crc else "mismatch"
        if crc != footer.summary_crc:
            scan.problems.append(Problem(footer.summary_start, "summary CRC mismatch"))
            return
    try:
        records = list(StreamReader(io.BytesIO(tail), skip_magic=True, record_size_limit=len(tail)).records)
    except Exception:  # noqa: BLE001 - any parse error: the summary cannot be used
        scan.problems.append(Problem(footer.summary_start, "summary section unreadable"))
        return
    for r in records:
        if isinstance(r, (Schema, Channel)):
            _take(scan, r)
    index = [r for r in records if isinstance(r, ChunkIndex)]
    by_offset = {c.offset: c for c in scan.chunks}
    for ci in index:
        chunk = by_offset.get(ci.chunk_start_offset)
        if chunk is None:
            scan.problems.append(Problem(ci.chunk_start_offset, "the summary indexes a chunk that is not there"))
            continue
        if chunk.ok and (ci.message_start_time, ci.message_end_time) != (chunk.start_ns, chunk.end_ns):
            scan.problems.append(Problem(chunk.offset, "chunk index time range disagrees with the chunk"))
        chunk.start_ns, chunk.end_ns = ci.message_start_time, ci.message_end_time
    if len(index) != len(scan.chunks):
        scan.problems.append(Problem(footer.summary_start,
                                     f"the summary indexes {len(index)} chunks, the file has {len(scan.chunks)}"))
    stats = next((r for r in records if isinstance(r, Statistics)), None)
    scan.summary_message_count = stats.message_count if stats is not None else None
    if stats is not None and not scan.bad_chunks and stats.message_count != scan.message_count:
        scan.problems.append(Problem(footer.summary_start, f"the summary counts {stats.message_count} messages, "
                                                           f"the data section holds {scan.message_count}"))
    scan.summary_ok = True

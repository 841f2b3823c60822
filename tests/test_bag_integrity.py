"""Damaged bags: chunk CRCs are checked, `analyze` refuses with one line naming `bag recover`, and
`bag recover` rebuilds a bag that mcap (summary + mcap-ros2 decoding) and rosbags read again.
Every case works on a copy of the reference bag in tmp_path."""

from __future__ import annotations

import ast
import os
import random
import shutil
import struct
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

pytest.importorskip("mcap_ros2")
pytest.importorskip("rosbags")

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from panel_rig.analyze_cli import analyze_main
from panel_rig.recording import CorruptBagError, main_bag_recover, read_bag, recover_bag, scan_mcap, verify_bag
from panel_rig.recording.integrity import messages_in_time_order

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "bags" / "stiffness_staircase"
MCAP = "stiffness_staircase_0.mcap"

if not REFERENCE.is_dir():
    pytest.skip("no reference bag", allow_module_level=True)


def _copy(tmp_path: Path, name: str = "bag") -> tuple[Path, Path]:
    dest = tmp_path / name
    shutil.copytree(REFERENCE, dest, ignore=shutil.ignore_patterns("plots", "analysis.json"))
    return dest, dest / MCAP


def _flip_bit(path: Path, offset: int, bit: int = 4) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 1 << bit
    path.write_bytes(data)


def _flip_bytes(path: Path, n: int, seed: int) -> None:
    data = bytearray(path.read_bytes())
    rng = random.Random(seed)
    for pos in rng.sample(range(len(data)), n):
        data[pos] ^= rng.randrange(1, 256)
    path.write_bytes(data)


def _truncate(path: Path, fraction: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


def _mcap_count(path: Path) -> tuple[int, int]:
    """(summary message count, decoded messages) through mcap's make_reader + the mcap-ros2 decoder."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        decoded = sum(1 for _ in reader.iter_decoded_messages())
    assert summary is not None and summary.statistics is not None
    return summary.statistics.message_count, decoded


def _rosbags_counts(bag: Path) -> Counter:
    from rosbags.highlevel import AnyReader

    counts: Counter = Counter()
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] += 1
    return counts


def _refused(bag: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """`panel-rig analyze` exits 2 with exactly one stderr line naming `panel-rig bag recover`."""
    assert analyze_main([str(bag)]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "panel-rig bag recover" in lines[0] and "Error" not in lines[0], lines[0]
    assert captured.out == ""
    return lines[0]


def _reference_total() -> int:
    with open(REFERENCE / MCAP, "rb") as f:
        return make_reader(f).get_summary().statistics.message_count


# ------------------------------------------------------------------------------ the intact bag
def test_reference_bag_is_intact() -> None:
    scan = scan_mcap(REFERENCE / MCAP)
    assert scan.ok and scan.problems == [] and scan.summary_crc == "ok"
    assert len(scan.chunks) > 10 and all(c.ok for c in scan.chunks)
    assert scan.message_count == _reference_total()
    assert verify_bag(REFERENCE) is not None


def test_a_check_counts_the_messages_without_holding_them() -> None:
    """Checking a bag (every analyze, every read) held each message of it in memory, 2.4x the file's size: a long
    real-time recording could not be analysed (or recovered) on a machine with less memory than that."""
    import tracemalloc

    tracemalloc.start()
    try:
        scan = scan_mcap(REFERENCE / MCAP)
        peak_b = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert scan.ok and scan.message_count == _reference_total()
    assert peak_b < 0.5 * (REFERENCE / MCAP).stat().st_size, peak_b
    times = [m.log_time for m in messages_in_time_order(scan)]  # what recover writes: read again, in time order
    assert len(times) == _reference_total() and times == sorted(times)


# ------------------------------------------------------------------------------ one flipped bit
def test_one_flipped_bit_is_found_refused_and_recovered(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rosbags.highlevel import AnyReader

    bag, path = _copy(tmp_path)
    total = _reference_total()
    offset = path.stat().st_size // 2
    _flip_bit(path, offset)
    original = path.read_bytes()
    # the corrupt chunk is named: index, byte range containing the flip, time range
    scan = scan_mcap(path)
    assert not scan.ok and scan.complete  # the summary itself is intact
    (bad,) = scan.bad_chunks
    assert bad.offset <= offset < bad.offset + bad.length and "CRC mismatch" in bad.problem
    assert 0 < bad.messages < total and sum(bad.topic_counts.values()) == bad.messages
    line = _refused(bag, capsys)
    assert f"chunk {bad.index} at byte {bad.offset}" in line and " s, " in line  # time range
    with pytest.raises(CorruptBagError, match="bag recover"):
        list(read_bag(bag))  # our reader checks CRCs too
    with pytest.raises(Exception, match="[Cc]hecksum"):  # the independent reader refuses it
        with AnyReader([bag]) as reader:
            for _ in reader.messages():
                pass

    assert main_bag_recover(str(bag)) == 0
    out = capsys.readouterr().out.splitlines()
    assert f"recovered {total - bad.messages} messages" in out[0] and "dropped 1 corrupt chunk" in out[0]
    assert len(out) == 2 and f"chunk {bad.index} at byte {bad.offset}" in out[1] and "/rig/tip_displacement" in out[1]
    assert (bag / (MCAP + ".broken")).read_bytes() == original
    assert _mcap_count(path) == (total - bad.messages, total - bad.messages)
    assert sum(_rosbags_counts(bag).values()) == total - bad.messages
    assert scan_mcap(path).ok and recover_bag(bag).was_complete
    assert analyze_main([str(bag), "--json"]) == 0  # 2.8 s of 52 s lost: still analysable
    capsys.readouterr()
    # the recovered bag is chunked as the recorder chunks (it had mcap's 1 MiB: 2 chunks for the whole bag, so the
    # next damage lost 16x more)
    from panel_rig.recording.writer import CHUNK_SIZE_BYTES

    chunks = scan_mcap(path).chunks
    assert len(chunks) >= len(scan.chunks) - 1 and max(c.length for c in chunks) < 2 * CHUNK_SIZE_BYTES


# ------------------------------------------------------------------------------ many flipped bytes
@pytest.mark.parametrize("seed", range(6))
def test_200_flipped_bytes_never_raise(tmp_path: Path, capsys: pytest.CaptureFixture[str], seed: int) -> None:
    bag, path = _copy(tmp_path)
    _flip_bytes(path, 200, seed)
    _refused(bag, capsys)
    report = recover_bag(bag)
    assert not report.was_complete and report.dropped_chunks >= 1 and report.dropped
    assert _mcap_count(path) == (report.messages, report.messages)
    assert sum(_rosbags_counts(bag).values()) == report.messages
    assert analyze_main([str(bag)]) == 2  # (almost) nothing left: refused, still one line
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_few_flipped_bytes_keep_the_intact_chunks(tmp_path: Path) -> None:
    """5 flipped bytes: exactly the chunks that hold them are dropped, all others kept."""
    bag, path = _copy(tmp_path)
    chunks = scan_mcap(path).chunks
    rng = random.Random(7)
    targets = rng.sample(chunks[1:], 3)  # chunk 0 holds the schemas: keep it
    data = bytearray(path.read_bytes())
    for c in targets:
        data[c.offset + c.length - 100] ^= 0x55  # inside the chunk's records
    path.write_bytes(data)
    report = recover_bag(bag)
    dropped = sorted(c.index for c in targets)
    assert report.dropped_chunks == 3
    assert all(f"chunk {i} at" in d for i, d in zip(dropped, report.dropped, strict=True))
    kept = sum(c.messages for c in chunks if c.index not in dropped)
    assert report.messages == kept == sum(_rosbags_counts(bag).values())


def test_broken_record_length_is_skipped_to_the_next_good_chunk(tmp_path: Path) -> None:
    """A damaged chunk length breaks the framing; the scan resynchronises on the next chunk."""
    bag, path = _copy(tmp_path)
    chunks = scan_mcap(path).chunks
    victim = chunks[5]
    _flip_bit(path, victim.offset + 1 + 5, bit=3)  # a high byte of the record length
    scan = scan_mcap(path)
    assert [c.offset for c in scan.chunks if c.ok] == [c.offset for c in chunks if c is not victim]
    report = recover_bag(bag)
    assert report.messages == sum(c.messages for c in chunks if c is not victim)
    # the loss is counted from the original's summary (the report named only the unreadable byte range)
    assert report.unaccounted_messages == victim.messages and f"lost {victim.messages} messages" in report.line()
    assert _mcap_count(path)[0] == report.messages == sum(_rosbags_counts(bag).values())


def test_a_shortened_chunk_is_uncounted_and_its_messages_lost(tmp_path: Path) -> None:
    """A chunk record whose length was cut short: its message indexes are skipped with the broken framing, so no
    index counts its messages; the report says so (not '0 messages') and counts them among the lost."""
    bag, path = _copy(tmp_path)
    chunks = scan_mcap(path).chunks
    victim = chunks[5]
    data = bytearray(path.read_bytes())
    (length,) = struct.unpack_from("<Q", data, victim.offset + 1)
    struct.pack_into("<Q", data, victim.offset + 1, length - 40)
    path.write_bytes(data)
    report = recover_bag(bag)
    assert report.dropped_chunks == report.uncounted_chunks == 1 and report.dropped_messages == 0, report
    assert report.messages == sum(c.messages for c in chunks if c is not victim)
    line = report.line()
    assert "(0 messages)" not in line and "no message index counts its messages" in line, line
    assert f"lost {victim.messages} messages in uncounted chunks or unreadable bytes" in line, line


# ------------------------------------------------------------------------------ truncated file
def test_truncated_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, path = _copy(tmp_path)
    _truncate(path, 0.6)
    line = _refused(bag, capsys)
    assert "no summary" in line
    assert main_bag_recover(str(bag)) == 0
    out = capsys.readouterr().out
    report = recover_bag(bag)
    assert report.was_complete and "discarded" in out and "trailing bytes" in out
    # exactly the chunks wholly inside the kept 60 % (about 60 % of the messages: the partial chunk is dropped, the
    # summary at the end is small), counted on the intact bag
    size = (REFERENCE / MCAP).stat().st_size
    inside = sum(c.messages for c in scan_mcap(REFERENCE / MCAP).chunks if c.offset + c.length <= int(size * 0.6))
    assert report.messages == inside and 0.5 * _reference_total() < inside < 0.65 * _reference_total()
    assert _mcap_count(path) == (report.messages, report.messages)
    assert sum(_rosbags_counts(bag).values()) == report.messages


def test_cli_subprocess_prints_no_traceback(tmp_path: Path) -> None:
    bag, path = _copy(tmp_path)
    _flip_bytes(path, 200, seed=0)  # used to end in a UnicodeDecodeError
    proc = subprocess.run([sys.executable, "-m", "panel_rig.cli", "analyze", str(bag)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "panel-rig bag recover" in proc.stderr
    assert "Traceback" not in proc.stderr


# ------------------------------------------------------------------------------ layering
# argparsing is stdlib only (checked below), so every layer may use it; the study scripts in analysis do
ORDER = ["argparsing", "processes", "config", "topics", "model", "analysis", "rig", "ros", "recording", "viz", "cli"]


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("panel_rig."):
            out.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            out |= {a.name.split(".")[1] for a in node.names if a.name.startswith("panel_rig.")}
    return out


@pytest.mark.parametrize("layer", ["analysis", "recording"])
def test_layers_import_only_from_above(layer: str) -> None:
    allowed = set(ORDER[: ORDER.index(layer) + 1])
    for path in sorted((ROOT / "panel_rig" / layer).glob("*.py")):
        bad = _imports(path) - allowed
        assert not bad, f"{path.name} imports {bad}"


def test_the_base_layer_imports_nothing_of_the_package() -> None:
    assert _imports(ROOT / "panel_rig" / "argparsing.py") == set()


def test_panel_length_fallback_is_the_config_default(tmp_path: Path) -> None:
    from geometry_msgs.msg import PointStamped, Vector3Stamped

    from panel_rig.config import PanelConfig
    from panel_rig.recording import BagWriter
    from panel_rig.recording.series import load_series

    with BagWriter(tmp_path / "nolen") as writer:  # no parameters record
        for k in range(32):
            tip, air = PointStamped(), Vector3Stamped()
            tip.point.z = 0.001 * k
            writer.write("/rig/tip_displacement", tip, k + 1)
            writer.write("/rig/airspeed", air, k + 1)
    rec = load_series(tmp_path / "nolen")
    assert rec.length_source == "default" and rec.panel_length_m == PanelConfig().panel_length_m
    assert rec.tip_w_over_L[10] == pytest.approx(0.01 / PanelConfig().panel_length_m)


# ------------------------------------------------------------------------------ interrupted recover
def test_interrupted_recover_leaves_no_partial_output(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C while the recovered copy is written used to leave `<file>.recovering` behind (only an OSError removed
    it): now the bag is left as it was, and the next run works."""
    import panel_rig.recording.recover as recover

    bag, path = _copy(tmp_path)
    _flip_bit(path, path.stat().st_size // 2)
    before = {p.name: p.read_bytes() for p in bag.iterdir()}

    class InterruptedWriter(recover.Writer):
        def add_message(self, *args: object, **kwargs: object) -> None:
            if getattr(self, "_n", 0) == 1000:
                raise KeyboardInterrupt
            self._n = getattr(self, "_n", 0) + 1
            super().add_message(*args, **kwargs)

    with monkeypatch.context() as mp:
        mp.setattr(recover, "Writer", InterruptedWriter)
        with pytest.raises(KeyboardInterrupt):
            recover_bag(bag)
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before  # no .recovering, no lock file
    report = recover_bag(bag)
    assert report.dropped_chunks == 1 and not report.notes
    assert sorted(p.name for p in bag.iterdir()) == sorted([*before, MCAP + ".broken"])


def test_sigterm_during_recover_leaves_the_bag_as_it_was(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A `kill` (SIGTERM) of `panel-rig bag recover` ended it at once with status 143, leaving the partial
    `<file>.recovering` and the lock file (a review's finding); now it leaves the bag as Ctrl-C does, and says so."""
    import signal

    import panel_rig.recording.recover as recover

    bag, path = _copy(tmp_path)
    _flip_bit(path, path.stat().st_size // 2)
    before = {p.name: p.read_bytes() for p in bag.iterdir()}

    class KilledWriter(recover.Writer):
        def add_message(self, *args: object, **kwargs: object) -> None:
            if getattr(self, "_n", 0) == 1000:
                os.kill(os.getpid(), signal.SIGTERM)
            self._n = getattr(self, "_n", 0) + 1
            super().add_message(*args, **kwargs)

    with monkeypatch.context() as mp:
        mp.setattr(recover, "Writer", KilledWriter)
        code = recover.main_bag_recover(str(bag))
    err = capsys.readouterr().err
    assert code == 143 and "stopped by SIGTERM" in err and "is as it was" in err, err
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before  # no .recovering, no lock file
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # the handler is given back


def test_ctrl_c_while_the_recovered_file_is_put_in_place_is_held(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A Ctrl-C between giving the original its .broken name and the recovered copy its place is held until the
    recovered bag and its metadata.yaml are in place (a half-swapped bag has two names for its damaged data)."""
    import signal

    import panel_rig.recording.recover as recover

    bag, path = _copy(tmp_path)
    _flip_bit(path, path.stat().st_size // 2)
    real_link = os.link

    def link_then_ctrl_c(src: object, dst: object) -> None:
        real_link(src, dst)
        if str(dst).endswith(".broken"):
            os.kill(os.getpid(), signal.SIGINT)

    with monkeypatch.context() as mp:
        mp.setattr(recover.os, "link", link_then_ctrl_c)
        with pytest.raises(KeyboardInterrupt):
            recover_bag(bag)
    assert sorted(p.name for p in bag.iterdir()) == sorted([MCAP, MCAP + ".broken", "metadata.yaml"])
    assert scan_mcap(path).ok and _mcap_count(path)[0] == sum(_rosbags_counts(bag).values())


def test_stale_recovering_file_of_a_killed_recover_is_removed(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A recover killed mid-write leaves `<file>.recovering`; the next run used to write `.recovering.1` and leave
    the stale one in place. Now it is removed, in one line."""
    bag, path = _copy(tmp_path)
    _truncate(path, 0.5)
    (bag / (MCAP + ".recovering")).write_bytes(path.read_bytes()[:5000])  # what a killed recover leaves
    assert main_bag_recover(str(bag)) == 0
    out = capsys.readouterr().out.splitlines()
    assert f"removed {MCAP}.recovering" in out[0] and "interrupted recover" in out[0], out
    assert "recovered" in out[1]
    assert sorted(p.name for p in bag.iterdir()) == sorted([MCAP, MCAP + ".broken", "metadata.yaml"])
    assert _mcap_count(path)[0] == sum(_rosbags_counts(bag).values()) > 0


KILL_BEFORE_PUT_IN_PLACE = """
import os, signal, sys
import panel_rig.recording.recover as recover
real_replace = os.replace
def replace(src, dst):
    if str(src).endswith(".recovering"):  # SIGKILL: no handler can hold it
        os.kill(os.getpid(), signal.SIGKILL)
    real_replace(src, dst)
recover.os.replace = replace
recover.recover_bag(sys.argv[1])
"""


def test_recover_killed_before_the_recovered_file_is_in_place_leaves_the_mcap(tmp_path: Path) -> None:
    """A recover SIGKILLed between renaming the original to .broken and the recovered copy into its place left a
    bag without its .mcap. Now the original's second name is a hard link: the .mcap is there at every instant, and
    the next recover removes the leftovers (named) and ends as a clean one does."""
    bag, path = _copy(tmp_path)
    _flip_bit(path, path.stat().st_size // 2)
    original = path.read_bytes()
    done = subprocess.run([sys.executable, "-c", KILL_BEFORE_PUT_IN_PLACE, str(bag)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == -9, done.stderr
    assert path.read_bytes() == original  # the bag still has its (damaged) .mcap, unchanged
    report = recover_bag(bag)
    assert any(f"removed {MCAP}.recovering" in n for n in report.notes), report.notes
    assert any(f"removed {MCAP}.broken, a second name" in n for n in report.notes), report.notes
    assert report.dropped_chunks == 1
    assert sorted(p.name for p in bag.iterdir()) == sorted([MCAP, MCAP + ".broken", "metadata.yaml"])
    assert (bag / (MCAP + ".broken")).read_bytes() == original
    assert scan_mcap(path).ok and _mcap_count(path)[0] == sum(_rosbags_counts(bag).values())


def test_recover_without_hard_links_renames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the file system refuses hard links the original is renamed to .broken instead: the same result."""
    import errno

    import panel_rig.recording.recover as recover

    bag, path = _copy(tmp_path)
    _flip_bit(path, path.stat().st_size // 2)
    original = path.read_bytes()

    def no_link(src: object, dst: object) -> None:
        raise OSError(errno.EPERM, "Operation not permitted")

    with monkeypatch.context() as mp:
        mp.setattr(recover.os, "link", no_link)
        report = recover_bag(bag)
    assert report.dropped_chunks == 1 and not report.notes
    assert sorted(p.name for p in bag.iterdir()) == sorted([MCAP, MCAP + ".broken", "metadata.yaml"])
    assert (bag / (MCAP + ".broken")).read_bytes() == original
    assert scan_mcap(path).ok


# ------------------------------------------------------------------------------ damaged metadata.yaml
@pytest.mark.parametrize("text", ["garbage: [", "rosbag2_bagfile_information: 7\n"])
def test_damaged_metadata_yaml_is_named_and_rebuilt(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    text: str) -> None:
    """An unparsable metadata.yaml made a good bag unreadable: analyze and recover printed a multi-line YAML
    parser error, and recover did not rebuild it. Now: one line naming the file and `bag recover`; recover keeps
    it as metadata.yaml.broken and rebuilds metadata.yaml from the .mcap."""
    import yaml

    bag, path = _copy(tmp_path)
    original = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    (bag / "metadata.yaml").write_text(text)
    line = _refused(bag, capsys)
    assert f"{bag / 'metadata.yaml'}" in line
    assert main_bag_recover(str(bag)) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and "metadata.yaml" in out[0] and "metadata.yaml.broken" in out[0], out
    assert "already complete" in out[1]
    assert (bag / "metadata.yaml.broken").read_text() == text
    rebuilt = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for key in ("message_count", "topics_with_message_count", "relative_file_paths", "starting_time", "duration"):
        assert rebuilt[key] == original[key], key
    assert sum(_rosbags_counts(bag).values()) == _reference_total()
    assert analyze_main([str(bag), "--json"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("content", [b"", b"random bytes, not a recording", b"\x89MCAP0\r\n"],
                         ids=["empty", "random", "bare_magic"])
def test_analyze_does_not_send_a_file_recover_cannot_use_to_recover(tmp_path: Path, content: bytes,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """An .mcap of random bytes, none, or the bare magic: analyze said "run `panel-rig bag recover`", and recover
    then said "not an MCAP file (no valid header)". Now analyze says so itself, in one line, and names no recover."""
    bag, path = _copy(tmp_path)
    path.write_bytes(content)
    assert analyze_main([str(bag)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    what = "is empty (0 bytes)" if not content else "not an MCAP file"  # an empty file ended "nothing to recover"
    assert len(lines) == 1 and what in lines[0] and "bag recover" not in lines[0], lines
    assert lines[0].endswith("no recording in it to read or to rebuild"), lines
    assert main_bag_recover(str(bag)) == 2  # and recover agrees
    assert ("is empty (0 bytes): nothing to rebuild" if not content else "not an MCAP file") in capsys.readouterr().err


def test_recover_says_it_wrote_a_missing_metadata_yaml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A complete .mcap without metadata.yaml: recover wrote it and said "metadata ok"."""
    bag, _ = _copy(tmp_path)
    (bag / "metadata.yaml").unlink()
    assert main_bag_recover(str(bag)) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and "metadata.yaml was missing: written" in out[0], out
    assert "already complete" in out[1] and "metadata.yaml written" in out[1] and "metadata ok" not in out[1]
    assert (bag / "metadata.yaml").is_file() and analyze_main([str(bag), "--json"]) == 0


def test_a_bag_recovered_to_nothing_is_not_a_rig_that_never_ran(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A file cut to 100 bytes recovers to no messages; analyze then said "the rig stopped before it ran a step",
    though the rig ran for 51 s and the file was cut. It now names the damaged original recover kept."""
    bag, path = _copy(tmp_path)
    with open(path, "r+b") as f:
        f.truncate(100)
    assert main_bag_recover(str(bag)) == 0
    assert "recovered 0 messages" in capsys.readouterr().out
    assert analyze_main([str(bag)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(f"holds no messages: `bag recover` found none it could read in the damaged original (kept as "
                         f"{MCAP}.broken)"), line


def test_a_damaged_parameter_record_is_named_not_silently_defaulted(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """The MCAP's metadata record has no checksum: one flipped bit turned `panel.length_m` into `panel*length_m`,
    and with metadata.yaml rebuilt from it analyze read "L = 0.27 m (default)" without a word; for another panel
    w/L would be quietly wrong. The parameters it lacks are now named."""
    bag, path = _copy(tmp_path)
    data = bytearray(path.read_bytes())
    at = data.find(b"panel.length_m")
    data[at + len("panel")] ^= 0x04  # '.' -> '*'
    path.write_bytes(bytes(data))
    (bag / "metadata.yaml").unlink()
    assert main_bag_recover(str(bag)) == 0
    capsys.readouterr()
    assert analyze_main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert "warning: the recorded parameters lack panel.length_m (a damaged record, or an older bag)" in out
    intact, _ = _copy(tmp_path, "intact")
    assert analyze_main([str(intact), "--json"]) == 0  # nothing lacking
    import json

    assert json.loads(capsys.readouterr().out)["missing_parameters"] == []

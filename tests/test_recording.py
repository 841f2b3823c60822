"""The rosbag2-compatible MCAP recorder: cross-reader round trip, schemas, crash recovery, errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("mcap_ros2")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped, Vector3Stamped
from mcap.reader import make_reader
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Float64
from visualization_msgs.msg import Marker

from panel_rig.recording import (
    BagWriter,
    RecordingError,
    find_mcap,
    has_summary,
    main_bag_recover,
    read_bag,
    recover_bag,
)
from panel_rig.recording.metadata import read_metadata
from panel_rig.recording.reader import read_metadata_records, summary_counts

try:
    from rosgraph_msgs.msg import Clock
except ImportError:  # pragma: no cover - depends on the installed interfaces
    Clock = None

REPO = Path(__file__).resolve().parents[1]


def read_ros2_messages(path: str) -> list:
    """Decoded messages (schema, channel, message, decoded_message) through mcap's make_reader with
    the mcap-ros2 DecoderFactory (mcap_ros2.reader.read_ros2_messages is deprecated)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        return list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
T0_NS = 1_700_000_000_000_000_000
N_SAMPLES = 60  # per high-rate topic
PARAMS = {"physics_dt": 1 / 2048, "n_modes": 3, "variant": "full", "limits": [0.1, 40.0]}


def _stamp(msg: object, ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)


def _joint_state(k: int, ns: int) -> JointState:
    m = JointState()
    _stamp(m, ns)
    m.name = ["q1", "q2", "q3"]
    m.position = [0.01 * k, -0.002 * k, 1e-4 * k]
    m.velocity = [0.5, -0.25, 0.125 * k]
    m.effort = [1.0 + k, 2.0, 3.0]
    return m


def _marker(k: int, ns: int) -> Marker:
    m = Marker()
    _stamp(m, ns)
    m.header.frame_id = "panel"
    m.ns, m.id, m.type, m.action = "panel", 0, Marker.LINE_STRIP, Marker.ADD
    m.scale.x = 0.002
    m.pose.orientation.w = 1.0
    m.points = [Point(x=0.01 * i, y=0.0, z=1e-3 * k * i) for i in range(20)]
    m.colors = [ColorRGBA(r=0.1, g=0.2, b=0.9, a=1.0) for _ in range(20)]
    m.color = ColorRGBA(r=0.1, g=0.2, b=0.9, a=1.0)
    return m


def _diagnostics(k: int, ns: int) -> DiagnosticArray:
    m = DiagnosticArray()
    _stamp(m, ns)
    m.status = [
        DiagnosticStatus(
            level=DiagnosticStatus.OK, name="panel_rig", message="running", hardware_id="emulated",
            values=[KeyValue(key="rtf", value=f"{1.0 + 0.01 * k:.2f}"), KeyValue(key="overruns", value="0")],
        )
    ]
    return m


def _expected_messages() -> list[tuple[str, object, int, str]]:
    """(topic, message, stamp_ns, qos) for a small but complete rig recording."""
    out: list[tuple[str, object, int, str]] = []
    for k in range(N_SAMPLES):
        ns = T0_NS + k * 2_000_000  # 500 Hz
        tip = PointStamped()
        _stamp(tip, ns)
        tip.point.x, tip.point.z = 0.5, 1e-4 * k
        air = Vector3Stamped()
        _stamp(air, ns)
        air.vector.x = 20.0 + 0.1 * k
        out += [
            ("/rig/tip_displacement", tip, ns, "sensor"),
            ("/rig/modal_states", _joint_state(k, ns), ns, "sensor"),
            ("/rig/airspeed", air, ns, "sensor"),
            ("/rig/airspeed_cmd", Float64(data=20.0 + k), ns, "reliable"),
        ]
        if Clock is not None:
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(ns, 1_000_000_000)
            out.append(("/clock", clock, ns, "reliable"))
        if k % 5 == 0:
            out.append(("/rig/panel_shape", _marker(k, ns), ns, "reliable"))
        if k % 10 == 0:
            out.append(("/diagnostics", _diagnostics(k, ns), ns, "reliable"))
    return out


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag_dir = tmp_path_factory.mktemp("bags") / "run_a"
    with BagWriter(bag_dir) as writer:
        writer.write_parameters(PARAMS)
        for topic, msg, ns, qos in _expected_messages():
            assert writer.write(topic, msg, ns, qos=qos)
    return bag_dir


def _expected_counts() -> Counter:
    return Counter(topic for topic, _, _, _ in _expected_messages())


# ------------------------------------------------------------------ 1. three readers agree
def test_bag_layout_and_mcap_ros2_roundtrip(bag: Path) -> None:
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "run_a_0.mcap"]
    expected = _expected_messages()
    assert len(expected) > 250
    decoded = list(read_ros2_messages(str(bag / "run_a_0.mcap")))
    assert Counter(m.channel.topic for m in decoded) == _expected_counts()
    with open(bag / "run_a_0.mcap", "rb") as f:
        header = make_reader(f).get_header()
    assert header.profile == "ros2" and "panel_rig" in header.library
    js = [m.decoded_message for m in decoded if m.channel.topic == "/rig/modal_states"]
    assert list(js[7].name) == ["q1", "q2", "q3"]
    assert list(js[7].position) == pytest.approx([0.07, -0.014, 7e-4])
    assert list(js[7].effort) == pytest.approx([8.0, 2.0, 3.0])
    markers = [m.decoded_message for m in decoded if m.channel.topic == "/rig/panel_shape"]
    assert markers[2].type == Marker.LINE_STRIP and len(markers[2].points) == 20
    assert markers[2].points[19].z == pytest.approx(1e-3 * 10 * 19)
    assert len(markers[2].colors) == 20
    # our own iterator: same data, (topic, type, stamp, msg)
    ours = list(read_bag(bag))
    assert len(ours) == len(expected)
    assert {(t, ty) for t, ty, _, _ in ours} >= {("/rig/modal_states", "sensor_msgs/msg/JointState")}


def test_rosbags_reads_bag_directory(bag: Path) -> None:
    from rosbags.highlevel import AnyReader

    counts: Counter = Counter()
    values: dict[str, object] = {}
    with AnyReader([bag]) as reader:  # types come from the bag's own schemas
        assert reader.message_count == len(_expected_messages())
        for conn, stamp_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] += 1
            values.setdefault(conn.topic, (stamp_ns, msg))
        types = {c.topic: c.msgtype for c in reader.connections}
    assert counts == _expected_counts()
    assert types["/rig/modal_states"] == "sensor_msgs/msg/JointState"
    stamp_ns, js = values["/rig/modal_states"]
    assert stamp_ns == T0_NS and list(js.effort) == [1.0, 2.0, 3.0]
    assert values["/diagnostics"][1].status[0].values[0].key == "rtf"


def test_rerun_converts_mcap_and_jointstate_becomes_plots(bag: Path, tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    rerun_bin = Path(sys.executable).with_name("rerun")
    if not rerun_bin.exists():
        pytest.skip("rerun CLI not installed")
    out = tmp_path / "bag.rrd"
    proc = subprocess.run(
        [str(rerun_bin), "mcap", "convert", str(bag / "run_a_0.mcap"), "-o", str(out)],
        check=False, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    check = subprocess.run(
        [str(rerun_bin), "mcap", "check", "--full", str(bag / "run_a_0.mcap")],
        check=False, capture_output=True, text=True, timeout=60,
    )
    assert check.returncode == 0, check.stderr
    statuses = [ln.split()[0] for ln in check.stdout.splitlines() if ln.strip().startswith(("ok", "warn", "err"))]
    assert statuses and set(statuses) == {"ok"}, check.stdout
    rows: Counter = Counter()
    for chunk in RrdReader(out).stream().to_chunks():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] += chunk.num_rows
    for field in ("position", "velocity", "effort"):
        assert rows[f"/rig/modal_states/{field}"] == N_SAMPLES
    for topic, n in _expected_counts().items():
        assert rows[topic] == n, topic


# ------------------------------------------------------------------ 2. schema text and hashes
def test_schema_text_and_channel_metadata(bag: Path) -> None:
    sep = "=" * 80
    with open(bag / "run_a_0.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {s.name: s for s in summary.schemas.values()}
    js = schemas["sensor_msgs/msg/JointState"]
    assert js.encoding == "ros2msg"
    text = js.data.decode()
    assert f"\n{sep}\nMSG: std_msgs/Header\n" in text
    assert f"\n{sep}\nMSG: builtin_interfaces/Time\n" in text
    assert text.index("MSG: std_msgs/Header") < text.index("MSG: builtin_interfaces/Time")
    assert text.startswith("# This is a message that holds data")
    marker = schemas["visualization_msgs/msg/Marker"].data.decode()
    assert marker.count("MSG: builtin_interfaces/Time\n") == 1  # each dependency once
    assert "MSG: geometry_msgs/Point\n" in marker
    for channel in summary.channels.values():
        assert channel.message_encoding == "cdr"
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        qos = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        assert qos[0]["history"] == "keep_last"
    by_topic = {c.topic: c for c in summary.channels.values()}
    sensor = yaml.safe_load(by_topic["/rig/modal_states"].metadata["offered_qos_profiles"])[0]
    reliable = yaml.safe_load(by_topic["/diagnostics"].metadata["offered_qos_profiles"])[0]
    assert (sensor["reliability"], sensor["depth"]) == ("best_effort", 5)
    assert (reliable["reliability"], reliable["depth"], reliable["durability"]) == (
        "reliable", 10, "volatile")


# ------------------------------------------------------------------ 5. metadata.yaml
def test_metadata_yaml_counts_and_parameters(bag: Path) -> None:
    info = read_metadata(bag)
    expected = _expected_counts()
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["ros_distro"] == "jazzy"
    assert info["message_count"] == sum(expected.values())
    assert info["relative_file_paths"] == ["run_a_0.mcap"]
    assert info["starting_time"]["nanoseconds_since_epoch"] == T0_NS
    assert info["duration"]["nanoseconds"] == (N_SAMPLES - 1) * 2_000_000
    assert info["files"][0]["message_count"] == sum(expected.values())
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert {name: t["message_count"] for name, t in topics.items()} == expected
    meta = topics["/rig/modal_states"]["topic_metadata"]
    assert meta["serialization_format"] == "cdr"
    assert meta["type_description_hash"].startswith("RIHS01_")
    assert meta["offered_qos_profiles"][0]["reliability"] == "best_effort"
    assert json.loads(info["custom_data"]["panel_rig.parameters"])["n_modes"] == 3
    records = read_metadata_records(bag / "run_a_0.mcap")
    assert json.loads(records["panel_rig/parameters"]["variant"]) == "full"
    assert "rosbag2_bagfile_information" in records["rosbag2"]["serialized_metadata"]
    assert summary_counts(bag / "run_a_0.mcap") == expected


# ------------------------------------------------------------------ CDR trailing padding
def test_empty_trailing_array_is_normalised_for_rosbags(tmp_path: Path) -> None:
    """rclpy pads a trailing empty sequence beyond what `rosbags` accepts; the writer trims it."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    sparse = JointState(name=["q1"], position=[1.5])  # velocity=[] and effort=[] at the end
    raw = serialize_message(sparse)
    with pytest.raises(Exception, match="size mismatch"):  # the problem we work around
        get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(raw, "sensor_msgs/msg/JointState")
    diag = DiagnosticArray(status=[DiagnosticStatus(name="x")])  # ends in empty values[]
    with BagWriter(tmp_path / "sparse") as writer:
        writer.write("/rig/modal_states", sparse, T0_NS)
        writer.write("/diagnostics", diag, T0_NS + 1, qos="reliable")
    with AnyReader([tmp_path / "sparse"]) as reader:
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert list(msgs[0].position) == [1.5] and len(msgs[0].effort) == 0
    assert msgs[1].status[0].name == "x" and len(msgs[1].status[0].values) == 0
    decoded = [m for _, _, _, m in read_bag(tmp_path / "sparse")]
    assert list(decoded[0].position) == [1.5]


# ------------------------------------------------------------------ 3. SIGKILL and recovery
_CHILD = textwrap.dedent(
    """
    import sys, time
    from sensor_msgs.msg import JointState
    from panel_rig.recording import BagWriter
    bag, period, batch, rate = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
    w = BagWriter(bag, chunk_size_bytes=4096, flush_period_s=period)
    n, t0 = 0, time.monotonic()
    while True:
        for _ in range(batch):
            m = JointState(name=["q1", "q2", "q3"], position=[n, 0.0, 0.0],
                           velocity=[0.0, 0.0, 0.0], effort=[0.0, 0.0, 0.0])
            w.write("/rig/modal_states", m, 1_000_000 * (n + 1))
            n += 1
        print(n, time.monotonic(), flush=True)
        time.sleep(max(0.0, t0 + n / rate - time.monotonic()))  # pacing only
    """
)


def test_sigkill_then_recover(tmp_path: Path) -> None:
    """Messages the child reported written >= flush_period_s + 2 batch intervals before SIGKILL
    (both clocks are CLOCK_MONOTONIC) are on disk; >= 99 % of them must come back."""
    flush_period_s, batch, rate_hz, n_before_kill = 0.2, 10, 1000.0, 1200
    bag_dir = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(bag_dir), str(flush_period_s), str(batch), str(rate_hz)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    reports: list[tuple[int, float]] = []
    try:
        for line in child.stdout:
            count, t_s = line.split()
            reports.append((int(count), float(t_s)))
            if reports[-1][0] >= n_before_kill:
                break
        t_kill = time.monotonic()
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert reports, child.stderr.read()
    horizon_s = t_kill - flush_period_s - 2 * batch / rate_hz
    safe = max((n for n, t in reports if t <= horizon_s), default=0)
    assert safe >= 500, reports[-3:]

    mcap_path = bag_dir / "killed_0.mcap"
    assert not has_summary(mcap_path)  # the ordinary reader has nothing to go on
    assert not (bag_dir / "metadata.yaml").exists()
    with pytest.raises(Exception):  # noqa: B017 - any error type: the file is truncated
        list(read_ros2_messages(str(mcap_path)))
    size_before = mcap_path.stat().st_size

    report = recover_bag(bag_dir)
    assert not report.was_complete
    assert report.broken_path is not None and report.broken_path.stat().st_size == size_before
    assert report.messages >= 0.99 * safe, (report, safe)
    assert report.messages <= reports[-1][0]
    print(f"\nSIGKILL: child reported {reports[-1][0]}, safe horizon {safe}, recovered "
          f"{report.messages} ({report.messages / safe:.3f} of safe); {report.line()}")

    positions = [m.position[0] for _, _, _, m in read_bag(bag_dir)]
    assert positions == [float(i) for i in range(report.messages)]  # a gap-free prefix
    from rosbags.highlevel import AnyReader

    with AnyReader([bag_dir]) as reader:
        assert reader.message_count == report.messages
        last = None
        for conn, _, raw in reader.messages():
            last = reader.deserialize(raw, conn.msgtype)
        assert last.position[0] == report.messages - 1
    assert read_metadata(bag_dir)["message_count"] == report.messages
    assert recover_bag(bag_dir).was_complete  # idempotent: a second run finds nothing to do


_TERM_CHILD = textwrap.dedent(
    """
    import signal, sys
    from std_msgs.msg import Float64
    from panel_rig.recording import BagWriter
    w = BagWriter(sys.argv[1], flush_period_s=0.05)
    signal.signal(signal.SIGTERM, lambda *_: w.close())  # may land inside write(): deferred
    n = 0
    while not w.closed:
        w.write("/rig/airspeed_cmd", Float64(data=float(n)), n + 1, qos="reliable")
        n += 1
        if n % 100 == 0:
            print(n, flush=True)
    print("closed", w.message_count, flush=True)
    """
)


def test_sigterm_handler_close_finalises_bag(tmp_path: Path) -> None:
    """close() called from a signal handler (possibly mid-write) leaves a complete bag."""
    bag_dir = tmp_path / "termed"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen(
        [sys.executable, "-c", _TERM_CHILD, str(bag_dir)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        for line in child.stdout:
            if int(line) >= 2000:
                break
        child.send_signal(signal.SIGTERM)
        out, err = child.communicate(timeout=30)  # bounded: a writer deadlocked in its handler fails, not hangs
        tail = out.split()
        assert child.returncode == 0, err
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert tail[-2] == "closed"
    written = int(tail[-1])
    assert has_summary(bag_dir / "termed_0.mcap")
    assert read_metadata(bag_dir)["message_count"] == written >= 2000
    assert sum(1 for _ in read_bag(bag_dir)) == written


class _SignalAt:
    """The writer's lock, calling ``hook`` in the writing thread right after it acquires or right after it releases:
    where a signal can land between the lock and the writer's mark of the thread that holds it."""

    def __init__(self, lock: threading.Lock, hook: Callable[[], None], after: str) -> None:
        self._lock, self._hook, self._after, self._armed = lock, hook, after, True
        self._writer_thread = threading.get_ident()

    def _fire(self, where: str) -> None:
        if self._armed and where == self._after and threading.get_ident() == self._writer_thread:
            self._armed = False
            self._hook()

    def acquire(self, *args: Any, **kwargs: Any) -> bool:
        got = self._lock.acquire(*args, **kwargs)
        if got:
            self._fire("acquire")
        return got

    def release(self) -> None:
        self._lock.release()
        self._fire("release")


@pytest.mark.parametrize("after", ["acquire", "release"])
def test_close_from_a_signal_at_the_lock_s_edges_finishes_the_bag(tmp_path: Path, after: str) -> None:
    """A CI run hung in test_sigterm_handler_close_finalises_bag: the handler's close() landed just after write()
    had acquired the lock but before it marked its thread as inside, took the lock again and deadlocked. The mark
    now covers acquiring and releasing; a close() landing just after the release (the mark still set) is done
    there, not deferred to a write that has ended. Either way the close completes the bag."""
    done: list[bool] = []

    def write_once() -> None:
        w = BagWriter(tmp_path / after, flush_period_s=60.0)
        w._lock = _SignalAt(w._lock, w.close, after)  # the "signal handler" calls close(), as the node's does
        w.write("/rig/airspeed_cmd", Float64(data=1.0), 1, qos="reliable")
        done.append(w.closed)

    t = threading.Thread(target=write_once, daemon=True)
    t.start()
    t.join(timeout=10.0)
    assert not t.is_alive(), "deadlocked: close() from the handler took the lock its own thread held"
    assert done == [True]
    assert has_summary(tmp_path / after / f"{after}_0.mcap")
    assert read_metadata(tmp_path / after)["message_count"] == 1


def test_recover_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main_bag_recover(str(tmp_path / "nope")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a bag directory: it does not exist" in err[0]
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk_0.mcap").write_bytes(b"this is not an mcap file")
    assert main_bag_recover(str(junk)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an MCAP" in err[0]
    assert (junk / "junk_0.mcap").read_bytes() == b"this is not an mcap file"  # untouched


# ------------------------------------------------------------------ 4. bad bag directories
def test_unwritable_or_nonempty_bag_dir_is_refused_at_construction(tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(RecordingError, match="cannot create bag directory"):
        BagWriter(afile / "bag")
    with pytest.raises(RecordingError, match="already exists and is not empty"):
        BagWriter(tmp_path)
    if os.geteuid() != 0:  # root ignores permission bits
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        try:
            with pytest.raises(RecordingError, match="cannot create"):
                BagWriter(ro / "bag")
        finally:
            ro.chmod(0o700)


def test_bad_writes_are_clear_errors_and_close_is_idempotent(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / "b")
    with pytest.raises(RecordingError, match="absolute"):
        writer.write("relative", Float64(data=1.0), 1)
    with pytest.raises(RecordingError, match="stamp_ns"):
        writer.write("/x", Float64(data=1.0), -5)
    with pytest.raises(RecordingError, match="unknown qos"):
        writer.write("/x", Float64(data=1.0), 1, qos="fast")
    with pytest.raises(RecordingError, match="not an rclpy message"):
        writer.write("/x", {"data": 1.0}, 1)
    writer.write("/x", Float64(data=1.0), 1)
    with pytest.raises(RecordingError, match="recorded as std_msgs/msg/Float64"):
        writer.write("/x", PointStamped(), 2)
    writer.close()
    writer.close()
    assert writer.write("/x", Float64(data=2.0), 3) is False and writer.dropped_after_close == 1
    assert find_mcap(tmp_path / "b").name == "b_0.mcap" and read_metadata(tmp_path / "b")["message_count"] == 1


def test_concurrent_writers_threads(tmp_path: Path) -> None:
    n_threads, n_each = 4, 200
    with BagWriter(tmp_path / "mt", chunk_size_bytes=2048) as writer:
        def work(i: int) -> None:
            for k in range(n_each):
                writer.write(f"/t{i}", Float64(data=float(k)), T0_NS + k)

        threads = [threading.Thread(target=work, args=(i,)) for i in range(n_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    counts = Counter(topic for topic, _, _, _ in read_bag(tmp_path / "mt"))
    assert counts == {f"/t{i}": n_each for i in range(n_threads)}


# ------------------------------------------------------------------ 6. a bag that is still being recorded
def _listing(bag_dir: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(bag_dir.iterdir())}


def test_recover_and_analyze_refuse_a_bag_being_recorded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`bag recover` on a live bag used to rename the .mcap the writer was still writing (to .broken) and write a
    'recovered' copy; the writer's metadata.yaml then counted messages the .mcap did not hold. Now the writer holds
    the bag's lock: recover refuses in one line (exit 2) and touches nothing, analyze says it is being recorded."""
    from rosbags.highlevel import AnyReader

    from panel_rig.analyze_cli import analyze_main
    from panel_rig.recording import verify_bag

    bag_dir = tmp_path / "live"
    writer = BagWriter(bag_dir, flush_period_s=0.05)
    for k in range(500):
        writer.write("/rig/tip_displacement", PointStamped(), T0_NS + k)
    writer.flush()
    before = _listing(bag_dir)
    assert main_bag_recover(str(bag_dir)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "being recorded" in err[0] and f"PID {os.getpid()}" in err[0], err
    assert _listing(bag_dir) == before  # nothing renamed, nothing written
    with pytest.raises(RecordingError, match="being recorded"):
        verify_bag(bag_dir)
    assert analyze_main([str(bag_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "still being recorded" in err[0] and "bag recover" not in err[0], err
    for k in range(500, 1000):
        writer.write("/rig/tip_displacement", PointStamped(), T0_NS + k)
    writer.close()
    assert sorted(p.name for p in bag_dir.iterdir()) == ["live_0.mcap", "metadata.yaml"]  # no lock file left
    info = read_metadata(bag_dir)
    assert info["relative_file_paths"] == ["live_0.mcap"] and info["message_count"] == 1000
    assert summary_counts(bag_dir / "live_0.mcap") == {"/rig/tip_displacement": 1000}
    with AnyReader([bag_dir]) as reader:
        assert reader.message_count == 1000
    assert recover_bag(bag_dir).was_complete


_LIVE_CHILD = textwrap.dedent(
    """
    import sys
    from std_msgs.msg import Float64
    from panel_rig.recording import BagWriter
    w = BagWriter(sys.argv[1])
    for n in range(300):
        w.write("/rig/airspeed_cmd", Float64(data=float(n)), n + 1, qos="reliable")
    w.flush()
    print("ready", flush=True)
    sys.stdin.read()  # until the test kills it
    """
)


def test_lock_of_a_killed_recorder_blocks_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The lock is held by the recording process (named by PID) and released by the OS when it is SIGKILLed: the
    lock file it leaves blocks neither analyze's 'recover it' advice nor `bag recover`, which removes it."""
    from rosbags.highlevel import AnyReader

    from panel_rig.analyze_cli import analyze_main

    bag_dir = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen([sys.executable, "-c", _LIVE_CHILD, str(bag_dir)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert child.stdout.readline().strip() == "ready", child.stderr.read()
        assert main_bag_recover(str(bag_dir)) == 2
        err = capsys.readouterr().err
        assert "being recorded" in err and f"PID {child.pid}" in err and err.count("\n") == 1, err
    finally:
        child.kill()
        child.wait(timeout=10)
    assert (bag_dir / ".panel_rig.lock").exists()  # left behind, but nobody holds it
    assert analyze_main([str(bag_dir)]) == 2
    err = capsys.readouterr().err
    assert "no summary" in err and "panel-rig bag recover" in err and "being recorded" not in err, err
    assert main_bag_recover(str(bag_dir)) == 0
    assert "recovered 300 messages" in capsys.readouterr().out
    assert sorted(p.name for p in bag_dir.iterdir()) == ["killed_0.mcap", "killed_0.mcap.broken", "metadata.yaml"]
    with AnyReader([bag_dir]) as reader:
        assert reader.message_count == 300


# ------------------------------------------------------------------ 7. bag directory names
def test_fresh_bag_dir_never_reuses_a_name(tmp_path: Path) -> None:
    """Bag directories were named to the second: a second recorder in the same second failed to start
    ('already exists and is not empty'). The same second now gives _2, _3, ..., also to racing threads."""
    from panel_rig.recording import fresh_bag_dir

    when_s = 1_750_000_000.0
    stamp = time.strftime("rig_%Y%m%d_%H%M%S", time.localtime(when_s))
    first = fresh_bag_dir(tmp_path, "rig", when_s)
    assert first == tmp_path / stamp and first.is_dir() and not any(first.iterdir())
    with BagWriter(first) as writer:
        writer.write("/x", Float64(data=1.0), 1)
    second = fresh_bag_dir(tmp_path, "rig", when_s)
    assert second.name == f"{stamp}_2"
    with BagWriter(second) as writer:
        writer.write("/x", Float64(data=2.0), 1)
    barrier = threading.Barrier(8)
    made: list[Path] = []

    def make() -> None:
        barrier.wait()
        made.append(fresh_bag_dir(tmp_path / "shared", "rig", when_s))

    threads = [threading.Thread(target=make) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(p.name for p in made) == sorted([stamp] + [f"{stamp}_{n}" for n in range(2, 9)])


def _frozen_second(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every time.strftime formats one fixed local time (a restart within the same second)."""
    fixed, real = time.localtime(1_750_000_000), time.strftime
    monkeypatch.setattr(time, "strftime", lambda fmt, t=None: real(fmt, fixed))


def test_node_restarted_in_the_same_second_records_into_a_new_bag(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Two rig nodes recording into one bag_dir within one second (a respawn, two namespaces): the second used to
    fail to start ('bag directory ... already exists and is not empty')."""
    import random

    import rclpy
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode

    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.randint(60, 90)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_LOG_DIR", str(tmp_path / "ros_log"))
    _frozen_second(monkeypatch)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    nodes = []
    try:
        for ns in ("a", "b"):
            nodes.append(RigNode(context=ctx, namespace=ns, parameter_overrides=[
                Parameter("record", value=True), Parameter("bag_dir", value=str(tmp_path / "bags"))]))
    finally:
        for node in nodes:
            node.close()
            node.destroy_node()
        rclpy.shutdown(context=ctx)
    names = sorted(p.name for p in (tmp_path / "bags").iterdir())
    assert len(names) == 2 and names[1] == names[0] + "_2"
    for name in names:
        assert has_summary(tmp_path / "bags" / name / f"{name}_0.mcap")


def test_flutter_test_started_twice_in_the_same_second_records_twice(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The in-process flutter test names its bag like the node; a second run in the same second failed to start."""
    import panel_rig.analysis.flutter_test as procedure
    from panel_rig.config import load_config
    from panel_rig.flutter_cli import run_in_process

    class Stop(Exception):
        pass

    def stop(*args: object, **kwargs: object) -> None:
        raise Stop

    _frozen_second(monkeypatch)
    monkeypatch.setattr(procedure, "run_procedure", stop)  # the bag is open by then; skip the test points
    cfg = load_config()
    for _ in range(2):
        with pytest.raises(Stop):
            run_in_process(cfg, bag_dir=tmp_path)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) == 2 and names[0].startswith("flutter_test_") and names[1] == names[0] + "_2"


def test_modal_rows_are_cut_to_the_shortest() -> None:
    """The modal states are read into one flat float array (memory: 8 bytes a number); rows of different lengths
    (not written by the rig) are cut to the shortest, as the list of rows was."""
    from panel_rig.recording.series import _ModalRows

    rows = _ModalRows()
    assert rows.rows().shape == (0, 0)
    for stamp_ns, position in ((3, [1.0, 2.0, 3.0]), (1, [4.0, 5.0]), (2, [6.0, 7.0, 8.0, 9.0])):
        rows.append(stamp_ns, position)
    assert rows.rows().tolist() == [[1.0, 2.0], [4.0, 5.0], [6.0, 7.0]]
    times_s, q = rows.sorted(t0_ns=1)  # read in the file's order, sorted by time
    assert times_s.tolist() == [0.0, 1e-9, 2e-9] and q.tolist() == [[4.0, 5.0], [6.0, 7.0], [1.0, 2.0]]


@pytest.mark.parametrize("frame_id", ["", "r", "rig_tip", "a_frame_id_of_seventeen"])
def test_fixed_layout_reads_equal_the_general_decoder(frame_id: str) -> None:
    """The tip, airspeed and modal-state values read at fixed CDR offsets (panel_rig.recording.fast_cdr) are the
    mcap-ros2 decoder's, whatever the frame id's length does to the alignment; bytes that are not little-endian
    CDR are left to the decoder (None)."""
    from mcap_ros2._dynamic import generate_dynamic

    from panel_rig.recording.fast_cdr import joint_positions, point_z, vector_x
    from panel_rig.recording.schemas import schema_text

    def decoded(msg: Any, type_name: str) -> Any:
        return generate_dynamic(type_name, schema_text(type_name))[type_name](serialize_message(msg))

    tip = PointStamped()
    tip.header.frame_id, tip.point.x, tip.point.y, tip.point.z = frame_id, 1.5, -2.5, 3.25e-4
    assert point_z(serialize_message(tip)) == decoded(tip, "geometry_msgs/msg/PointStamped").point.z == 3.25e-4
    air = Vector3Stamped()
    air.header.frame_id, air.vector.x, air.vector.y = frame_id, 11.46, 0.7
    assert vector_x(serialize_message(air)) == decoded(air, "geometry_msgs/msg/Vector3Stamped").vector.x == 11.46
    modal = JointState(name=[frame_id, "q2", "mode_three"], position=[0.1, -0.2, 0.3], velocity=[1.0, 2.0, 3.0])
    modal.header.frame_id = frame_id
    assert joint_positions(serialize_message(modal)) == tuple(
        decoded(modal, "sensor_msgs/msg/JointState").position) == (0.1, -0.2, 0.3)
    big_endian = b"\x00\x00" + serialize_message(tip)[2:]
    assert point_z(big_endian) is None and vector_x(big_endian) is None and joint_positions(big_endian) is None


def test_a_bag_written_out_of_time_order_is_read_in_time_order(tmp_path: Path) -> None:
    """The series are read in the file's order and sorted by time (mcap's merge into log-time order took a fifth of
    the reading): a bag whose messages are not in time order gives the same series as one that is."""
    import numpy as np

    from panel_rig.recording.series import load_series

    stamps = np.random.default_rng(3).permutation(np.arange(1, 41)) * 2_000_000  # 2 ms apart, shuffled
    with BagWriter(tmp_path / "shuffled", chunk_size_bytes=512) as writer:  # several chunks
        for k, stamp in enumerate(stamps):
            tip, air = PointStamped(), Vector3Stamped()
            tip.point.z, air.vector.x = stamp * 1e-12, 5.0 + stamp * 1e-9
            writer.write("/rig/tip_displacement", tip, int(stamp))
            writer.write("/rig/airspeed", air, int(stamp))
            if k == 20:
                writer.write("/rig/airspeed_cmd", Float64(data=6.0), int(stamp), qos="reliable")
    rec = load_series(tmp_path / "shuffled")
    assert np.all(np.diff(rec.t_s) > 0) and rec.t_s[0] == 2e-3
    np.testing.assert_allclose(rec.tip_w_over_L * rec.panel_length_m, (rec.t_s * 1e9) * 1e-12, rtol=1e-12)
    np.testing.assert_allclose(rec.airspeed_mps, 5.0 + rec.t_s, rtol=1e-12)
    assert rec.commands["airspeed_cmd"] == [(stamps[20] * 1e-9, 6.0)]


def test_a_bag_is_checked_and_read_in_one_pass_and_a_damaged_one_still_refused(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """load_series parsed every chunk twice (the integrity scan, then the read: half of `analyze` on a flutter
    test's 156 MB bag). It now takes the messages as the scan parses each chunk, once; a chunk damaged after the
    ones it took still refuses the bag (CorruptBagError, naming `bag recover`), with nothing half-read returned."""
    import numpy as np

    from panel_rig.recording import integrity, reader
    from panel_rig.recording.errors import CorruptBagError
    from panel_rig.recording.series import load_series

    bag_dir = tmp_path / "bag"
    with BagWriter(bag_dir, chunk_size_bytes=512) as writer:  # several chunks
        for k in range(1, 41):
            tip, air = PointStamped(), Vector3Stamped()
            tip.point.z, air.vector.x = k * 1e-3, 5.0
            writer.write("/rig/tip_displacement", tip, k * 2_000_000)
            writer.write("/rig/airspeed", air, k * 2_000_000)
    parsed = []
    real = integrity.chunk_records
    monkeypatch.setattr(integrity, "chunk_records", lambda data: parsed.append(1) or real(data))
    monkeypatch.setattr(reader, "chunk_records", lambda data: parsed.append(1) or real(data))
    rec = load_series(bag_dir)
    chunks = len(reader.verify_bag(bag_dir).chunks)
    assert chunks > 2 and len(parsed) == 2 * chunks  # once by load_series, once by the verify_bag just above
    np.testing.assert_allclose(rec.tip_w_over_L * rec.panel_length_m, np.arange(1, 41) * 1e-3)
    mcap = next(bag_dir.glob("*.mcap"))
    raw = bytearray(mcap.read_bytes())
    last = reader.verify_bag(bag_dir).chunks[-1]
    raw[last.offset + last.length - 20] ^= 0xFF  # inside the last chunk's records: its CRC no longer matches
    mcap.write_bytes(bytes(raw))
    with pytest.raises(CorruptBagError, match="bag recover"):
        load_series(bag_dir)


def test_channels_written_outside_chunks_are_read_in_the_one_pass(tmp_path: Path) -> None:
    """Another writer may put its schema and channel records in the data section outside any chunk, before the
    chunks of messages (this file is made so with mcap's own writer). The one-pass reader knows them from the scan:
    without that such an intact bag was refused as corrupt (the chunk's messages named a channel it had not seen)."""
    import numpy as np
    from mcap.writer import Writer
    from rclpy.serialization import serialize_message

    from panel_rig.recording.reader import verify_bag
    from panel_rig.recording.schemas import schema_text
    from panel_rig.recording.series import load_series

    bag_dir = tmp_path / "foreign"
    bag_dir.mkdir()
    with open(bag_dir / "foreign_0.mcap", "wb") as f:
        writer = Writer(f, chunk_size=512)
        writer.start(profile="ros2", library="test")
        chunks = writer._Writer__chunk_builder  # none while the schema and channel are written: outside chunks
        writer._Writer__chunk_builder = None
        schema = writer.register_schema("geometry_msgs/msg/PointStamped", "ros2msg",
                                        schema_text("geometry_msgs/msg/PointStamped").encode())
        channel = writer.register_channel("/rig/tip_displacement", "cdr", schema)
        writer._Writer__chunk_builder = chunks
        for k in range(1, 41):
            tip = PointStamped()
            tip.point.z = k * 1e-3
            writer.add_message(channel, log_time=k * 2_000_000, data=serialize_message(tip),
                               publish_time=k * 2_000_000)
        writer.finish()
    scan = verify_bag(bag_dir)
    assert len(scan.chunks) > 2 and scan.channels  # chunked messages, a channel seen outside them
    rec = load_series(bag_dir)
    np.testing.assert_allclose(rec.tip_w_over_L * rec.panel_length_m, np.arange(1, 41) * 1e-3)


def test_a_bag_that_cannot_be_finished_closes_its_file_and_releases_its_lock(tmp_path: Path) -> None:
    """A full disk fails the summary's write: the file was left open (and its lock taken) when `close` raised."""
    import errno

    from std_msgs.msg import Float64

    bag_dir = tmp_path / "full"
    writer = BagWriter(bag_dir)
    writer.write("/rig/airspeed", Float64(data=1.0), 1)

    def no_space() -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    writer._writer.finish = no_space
    with pytest.raises(RecordingError, match="cannot finish .*No space left on device"):
        writer.close()
    from panel_rig.recording.lock import lock_holder

    assert writer._stream.closed and lock_holder(bag_dir) is None  # `bag recover` may take it


def test_a_bag_s_mcap_file_given_for_its_directory_names_the_directory(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """`panel-rig analyze bags/x/x_0.mcap` said only "... is not a bag directory"; it now names the directory."""
    import subprocess
    import sys

    bag = tmp_path / "run"
    bag.mkdir()
    (bag / "run_0.mcap").write_bytes(b"")
    assert main_bag_recover(str(bag / "run_0.mcap")) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"is not a bag directory: it is a bag's MCAP file; give the directory that holds it ({bag})")
    out = subprocess.run([sys.executable, "-m", "panel_rig.cli", "analyze", str(bag / "run_0.mcap")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and f"give the directory that holds it ({bag})" in out.stderr, out.stderr


def test_recover_keeps_the_parameters_a_readable_metadata_yaml_holds_and_the_damaged_mcap_lost(tmp_path: Path) -> None:
    """A closed bag whose MCAP was later damaged before its parameters record (a cut copy, here at that record):
    recover rebuilt metadata.yaml from the MCAP alone and replaced the good file's parameters with none, keeping
    no copy. It now keeps the previous metadata.yaml's custom_data entries that the recovered MCAP does not hold,
    and says so; the parameters record in the MCAP stays the source when it survived."""
    bag_dir = tmp_path / "cut"
    with BagWriter(bag_dir) as writer:
        writer.write_parameters(PARAMS)
        for topic, msg, ns, qos in _expected_messages():
            writer.write(topic, msg, ns, qos=qos)
    before = read_metadata(bag_dir)["custom_data"]
    assert json.loads(before["panel_rig.parameters"]) == PARAMS
    mcap = bag_dir / "cut_0.mcap"
    data = mcap.read_bytes()
    record = data.index(b"panel_rig/parameters") - 13  # opcode (1), record length (8), name length (4)
    assert data[record] == 0x0C  # an MCAP Metadata record starts there
    mcap.write_bytes(data[:record])
    report = recover_bag(bag_dir)
    assert read_metadata(bag_dir)["custom_data"] == before
    assert any("panel_rig.parameters kept from the previous metadata.yaml" in n for n in report.notes), report.notes
    assert any("kept from the previous" in line for line in report.lines())

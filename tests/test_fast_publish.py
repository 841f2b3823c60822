"""The fast node's blocks: numpy-built CDR and MCAP records equal the per-message path they replace; its pacing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("mcap")

from geometry_msgs.msg import PointStamped, Vector3Stamped  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from visualization_msgs.msg import Marker  # noqa: E402

from panel_rig.recording import BagWriter  # noqa: E402
from panel_rig.rig.reading import ReadingBlock  # noqa: E402
from panel_rig.ros import messages  # noqa: E402

N_MODES = 4
TOPICS = ("/rig/tip_displacement", "/rig/modal_states", "/rig/airspeed", "/rig/tip_displacement/truth")
TYPES = (PointStamped, JointState, Vector3Stamped, PointStamped)


def _block(rng: np.random.Generator, t0_s: float, n: int) -> ReadingBlock:
    def col(*shape: int) -> np.ndarray:
        return rng.normal(size=(n, *shape))

    block = ReadingBlock(t0_s + np.arange(1, n + 1) / 500.0, col(), col(), col(), col(), col(N_MODES),
                         col(N_MODES), col(N_MODES))
    if n > 3:  # non-finite values must become 0 on both paths
        block.q[1, 2] = np.nan
        block.tip_w_m[3] = np.inf
    return block


def _reference_messages(block: ReadingBlock, offset_ns: int, panel_length_m: float) -> list[list]:
    """The readings built field by field as rclpy messages (what the node publishes)."""
    out = []
    for i in range(len(block)):
        ns = messages.stamp_ns(float(block.time_s[i])) + offset_ns
        hdr = messages.header(ns)

        def fin(x: float) -> float:
            return float(x) if np.isfinite(x) else 0.0

        tip = PointStamped(header=hdr)
        tip.point.x, tip.point.z = 0.5, fin(block.tip_w_m[i])
        modal = JointState(header=hdr, name=[f"q{k + 1}" for k in range(N_MODES)],
                           position=[fin(v) for v in block.q[i]], velocity=[fin(v) for v in block.qdot_per_s[i]],
                           effort=[fin(v) for v in block.aero_force_npm[i]])
        air = Vector3Stamped(header=hdr)
        air.vector.x = fin(block.airspeed_mps[i])
        truth = PointStamped(header=hdr)
        truth.point.x, truth.point.z = 0.5, fin(block.tip_w_over_L[i] * panel_length_m)
        out.append([ns, tip, modal, air, truth, Clock(clock=messages.stamp(ns))])
    return out


@pytest.mark.parametrize("offset_ns", [0, 1_763_000_000_123_456_789])
def test_block_cdr_decodes_to_the_messages_field_by_field(offset_ns: int) -> None:
    rng = np.random.default_rng(3)
    msgs = messages.ReadingMessages([f"q{k + 1}" for k in range(N_MODES)], 0.5, 0.3)
    assert msgs.templated
    block = _block(rng, 12.345, 40)
    enc = msgs.encode_block(block, offset_ns)
    assert enc is not None and len(enc) == len(block)
    per_message = list(msgs.encode(block, offset_ns))
    for i, (ns, *expected) in enumerate(_reference_messages(block, offset_ns, 0.3)):
        assert int(enc.stamps_ns[i]) == ns == per_message[i][0]
        for k, (cls, msg) in enumerate(zip((*TYPES, Clock), expected)):
            data = (enc.payloads + (enc.clock,))[k][i].tobytes()
            assert deserialize_message(data, cls) == msg, (i, k)
            assert deserialize_message(data, cls) == deserialize_message(serialize_message(msg), cls)
        for k in range(4):  # and byte for byte the per-message templates
            assert enc.payloads[k][i].tobytes() == per_message[i][1 + k]


def test_a_wrong_template_is_refused() -> None:
    """The check that guards every template can fail: a shifted field offset no longer decodes to the message."""
    tpl = messages.ReadingMessages(["q1", "q2"], 0.5, 0.3)._tpl[0]
    assert tpl.ok and tpl._check()
    stamp_at, starts = tpl._offsets
    tpl._offsets = (stamp_at, [starts[0] - 8])
    assert not tpl._check()


def test_shape_template_decodes_to_the_marker() -> None:
    x = np.linspace(0.0, 1.0, 31)
    shape = messages.ShapeCdr(0.1, 0.3, x)
    assert shape.ok
    w = 0.4 * np.sin(3 * x)
    w[4] = np.nan
    for aborted in (False, True, False):
        expected = messages.shape_msg(987_654_321_012, 0.1, 0.3, w, x, aborted)
        got = deserialize_message(shape.pack(987_654_321_012, w * 0.3, aborted), Marker)
        assert got == deserialize_message(serialize_message(expected), Marker)  # float32 colours as on the wire
        assert type(shape.message(aborted)) is Marker


def test_shape_block_rows_are_the_single_shapes() -> None:
    """A block's shapes packed at once (the fast node's one bag write per block) are byte for byte pack()."""
    x = np.linspace(0.0, 1.0, 31)
    shape = messages.ShapeCdr(0.1, 0.3, x)
    rng = np.random.default_rng(3)
    stamps = np.array([5, 1_000_000_000, 987_654_321_012, 2**40])
    z = rng.normal(size=(4, 31))
    z[2, 7] = np.inf
    for aborted in (False, True):
        rows = shape.pack_block(stamps, z, aborted)
        assert rows.dtype == np.uint8 and rows.shape[0] == 4
        for k in range(4):
            assert rows[k].tobytes() == shape.pack(int(stamps[k]), z[k], aborted)


def _write_both(tmp_path: Path, chunk_size: int) -> tuple[Path, Path, list]:
    rng = np.random.default_rng(7)
    msgs = messages.ReadingMessages([f"q{k + 1}" for k in range(N_MODES)], 0.5, 0.3)
    objs = (msgs.tip, msgs.modal, msgs.airspeed, msgs.truth)
    topics = list(zip(TOPICS, objs))
    blocks = [msgs.encode_block(_block(rng, 0.2 * i, [64, 1, 13, 64, 2][i % 5])) for i in range(25)]
    paths = []
    for name, blockwise in (("a", False), ("b", True)):
        writer = BagWriter(tmp_path / name / "bag", chunk_size_bytes=chunk_size, flush_period_s=1e3)
        for (topic, msg), p in zip(topics, blocks[0].payloads):  # channels registered alike in both
            writer.write(topic, msg, 1, data=p[0].tobytes())
        for enc in blocks:
            if blockwise:
                assert writer.write_block(topics, enc.stamps_ns, enc.payloads)
            else:
                for i in range(len(enc)):
                    for (topic, msg), p in zip(topics, enc.payloads):
                        writer.write(topic, msg, int(enc.stamps_ns[i]), data=p[i].tobytes())
        writer.close()
        paths.append(tmp_path / name / "bag")
    return paths[0], paths[1], blocks


@pytest.mark.parametrize("chunk_size", [200, 4096, 64 * 1024])
def test_block_writes_give_the_same_bag_byte_for_byte(tmp_path: Path, chunk_size: int) -> None:
    a, b, blocks = _write_both(tmp_path, chunk_size)
    assert (a / "bag_0.mcap").read_bytes() == (b / "bag_0.mcap").read_bytes()
    assert (a / "metadata.yaml").read_text() == (b / "metadata.yaml").read_text()
    with open(b / "bag_0.mcap", "rb") as f:  # and it decodes, with chunk indexes, in order
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        n = 4 * (1 + sum(len(e) for e in blocks))
        assert summary.statistics.message_count == n
        assert len(summary.chunk_indexes) == summary.statistics.chunk_count >= 1
        decoded = list(reader.iter_decoded_messages(log_time_order=False))
    assert len(decoded) == n
    assert [d.channel.topic for d in decoded[4:12]] == list(TOPICS) * 2
    assert [d.message.sequence for d in decoded if d.channel.topic == TOPICS[1]] == list(range(n // 4))


def test_write_block_refuses_bad_payloads(tmp_path: Path) -> None:
    from panel_rig.recording import RecordingError

    msgs = messages.ReadingMessages(["q1"], 0.5, 0.3)
    with BagWriter(tmp_path / "bag") as writer:
        with pytest.raises(RecordingError):
            writer.write_block([("/rig/tip", msgs.tip)], np.array([1, 2]), [np.zeros((3, 8), np.uint8)])
        with pytest.raises(RecordingError):
            writer.write_block([("rig/tip", msgs.tip)], np.array([1]), [np.zeros((1, 8), np.uint8)])
    assert not writer.write_block([("/rig/tip", msgs.tip)], np.array([1]), [np.zeros((1, 8), np.uint8)])
    assert writer.dropped_after_close == 1


def test_exact_shape_sampler_is_the_exact_integral() -> None:
    """The node's shape sampler (Gauss-Legendre between stations) against adaptive quadrature of cos/sin theta,
    for tip angles up to a few radians, and against :func:`shape` within its error (a 2001-point Simpson rule read
    at the stations by linear interpolation: ~4e-6 at these amplitudes)."""
    from scipy.integrate import quad

    from panel_rig.model.elastica import shape, shape_sampler
    from panel_rig.model.structure import mode_shapes

    s = np.linspace(0.0, 1.0, 31)
    sampler = shape_sampler(4, tuple(s))
    rng = np.random.default_rng(0)
    for amplitude in (0.01, 0.5, 1.5):
        q = amplitude * rng.normal(size=4)

        def theta(x: float, q: np.ndarray = q) -> float:
            return float(q @ mode_shapes(4, np.array([x]), 1)[:, 0])

        x_ref = [quad(lambda x: np.cos(theta(x)), 0.0, sk, epsabs=1e-14, epsrel=1e-14)[0] for sk in s]
        w_ref = [quad(lambda x: np.sin(theta(x)), 0.0, sk, epsabs=1e-14, epsrel=1e-14)[0] for sk in s]
        x, w = sampler(q)
        np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-13)
        np.testing.assert_allclose(w, w_ref, rtol=0, atol=1e-13)
        for got, expected in zip((x, w), shape(q, s)):
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)
    unsorted = (0.7, 0.0, 1.0, 0.25)  # any stations, in any order
    q = rng.normal(size=4)
    for got, expected in zip(shape_sampler(4, unsorted)(q), shape_sampler(4, tuple(sorted(unsorted)))(q)):
        np.testing.assert_allclose(got, expected[np.argsort(np.argsort(unsorted))], rtol=0, atol=1e-15)


@pytest.mark.parametrize("variant", ["full", "exact"])
def test_shape_of_a_sample_q_is_the_shape_of_that_state(variant: str) -> None:
    """Fast mode draws the shape of a mid-block sample from its q: the same as the stepper's own shape there."""
    from panel_rig.config import PanelConfig
    from panel_rig.model.stepper import Stepper

    st = Stepper(PanelConfig(), variant=variant)
    x = np.linspace(0.0, 1.0, 31)
    for _ in range(40):
        st.step(11.0, 2.0)
    q = st.q.copy()
    own = st.shape_w_over_L(x)
    assert np.max(np.abs(own)) > 0
    np.testing.assert_array_equal(st.shape_w_over_L(x, q=q), own)
    for _ in range(5):
        st.step(11.0, 2.0)
    np.testing.assert_array_equal(st.shape_w_over_L(x, q=q), own)  # of q, not of the present state
    assert not np.array_equal(st.shape_w_over_L(x), own)


def test_fast_node_records_every_reading_and_the_shape_of_each_sample(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """In-process fast node, recording, no subscribers (64-period blocks): the bag holds every reading once, in
    order, and a panel_shape every 1/30 s whose trailing-edge z is the truth reading at its stamp."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import FAST_MAX_BLOCK_PERIODS, RigNode
    from panel_rig.ros.rig_node import spin

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("model.variant", value="full"), Parameter("record", value=True),
        Parameter("bag_dir", value=str(tmp_path)), Parameter("tunnel.time_constant_s", value=0.2)])
    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        node.rig.command_force(0.5)
        node.rig.command_airspeed(8.0)
        blocks: list[int] = []
        march = node.rig.advance_samples
        node.rig.advance_samples = lambda counts: (blocks.append(len(counts)), march(counts))[1]  # type: ignore
        spin(node, executor, lambda: node.rig.time_s > 3.0)
        executor.shutdown()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert max(blocks) == FAST_MAX_BLOCK_PERIODS  # marched past the 30 Hz shape samples
    mcap = next(tmp_path.glob("*/*.mcap"))
    by_topic: dict[str, list] = {}
    with open(mcap, "rb") as f:
        for _, channel, message, decoded in make_reader(f, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append((message.log_time, decoded))
    truth = dict(by_topic["/tip_displacement/truth"])
    tip_stamps = [t for t, _ in by_topic["/tip_displacement"]]
    assert tip_stamps == sorted(tip_stamps) and len(set(tip_stamps)) == len(tip_stamps)
    steps = np.diff(tip_stamps) / (1e9 / 2048)  # readings at whole physics steps, 500 per simulated second
    assert np.all(np.abs(steps - np.round(steps)) < 1e-3) and set(np.round(steps).astype(int)) <= {4, 5}
    assert len(tip_stamps) == pytest.approx(500 * tip_stamps[-1] * 1e-9, abs=2)
    for topic in ("/modal_states", "/airspeed", "/tip_displacement/truth"):
        assert [t for t, _ in by_topic[topic]] == tip_stamps
    shapes = by_topic["/panel_shape"]
    assert len(shapes) == pytest.approx(30 * tip_stamps[-1] * 1e-9, abs=2)
    assert np.all(np.abs(np.diff([t for t, _ in shapes]) - 1e9 / 30) <= 2_000_001)  # within one reading
    moving = 0
    for stamp, marker in shapes:
        z_tip = marker.points[-1].z
        assert z_tip == pytest.approx(truth[stamp].point.z, rel=1e-9, abs=1e-12)
        moving += abs(z_tip) > 1e-6
    assert moving > len(shapes) // 2


def test_fast_node_holds_its_realtime_factor_cap(ros_env: dict[str, str]) -> None:
    """In-process fast node, no subscribers (64-period blocks, 0.128 s simulated each): with
    fast_max_realtime_factor 4 it marches at 4x the wall clock (it used to wait only one executor pass, 5 ms, per
    block: ~18x whatever the cap below that), and set to 0 live it runs uncapped."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode
    from panel_rig.ros.rig_node import spin

    cap = 4.0
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("model.variant", value="full"),
        Parameter("fast_max_realtime_factor", value=cap)])
    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        node.rig.command_airspeed(8.0)
        spin(node, executor, lambda: node.rig.time_s > 0.3)  # warm: kernels loaded, pace anchored
        wall0, sim0 = time.monotonic(), node.rig.time_s
        spin(node, executor, lambda: node.rig.time_s > sim0 + 3.0)
        capped = (node.rig.time_s - sim0) / (time.monotonic() - wall0)
        assert node.set_parameters([Parameter("fast_max_realtime_factor", value=0.0)])[0].successful
        wall0, sim0 = time.monotonic(), node.rig.time_s
        spin(node, executor, lambda: node.rig.time_s > sim0 + 3.0)
        uncapped = (node.rig.time_s - sim0) / (time.monotonic() - wall0)
        executor.shutdown()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    # at most the cap (one block, 0.128 s, may run ahead of it: 4 % of 3 s); at least half of it on a loaded machine
    assert 0.5 * cap < capped <= 1.05 * cap
    assert uncapped > 2 * cap


def test_late_real_time_tick_publishes_the_samples_it_owes(ros_env: dict[str, str],
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Real-time mode: a tick that comes 10 ms late (a loaded machine) publishes the samples it owes, one publish
    period apart on the publish grid (it used to publish only the present one: ~20 % of the readings were missing
    with both cores busy); an on-time tick publishes one. The node's steady clock is a fake one here."""
    import types

    import rclpy
    from rclpy.parameter import Parameter

    from panel_rig.ros import node as node_module
    from panel_rig.ros.node import RigNode

    clock = [1000.0]
    monkeypatch.setattr(node_module, "time", types.SimpleNamespace(monotonic=lambda: clock[0]))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[Parameter("fast", value=False),
                                                     Parameter("model.variant", value="full")])
    published: list[np.ndarray] = []
    publish = node.publication.publish_block
    node.publication.publish_block = lambda block: (published.append(block.time_s.copy()), publish(block))[1]  # type: ignore
    try:  # no executor spins: the timer never fires, the test drives the ticks
        for wall_s in (1000.002, 1000.004, 1000.0141):  # on time, on time, 10.1 ms late
            clock[0] = wall_s
            node._tick()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    dt = node.dt_s
    assert [len(p) for p in published] == [1, 1, 5]  # the late tick: the five grid points it passed
    owed = np.concatenate(published[1:])
    assert owed == pytest.approx([0.004, 0.006, 0.008, 0.010, 0.012, 0.014], abs=dt)  # at whole steps


def test_node_with_an_unreachable_viewer_closes_its_bag_and_stops(ros_env: dict[str, str], tmp_path: Path) -> None:
    """A node recording with `rerun:=connect:URL` whose viewer went away after the start (a node is refused one
    where none listens): closing it (what SIGINT does) closes the bag first and then ends, reporting the
    undelivered viewer data; it used to wait forever in rerun's flush, with the bag still open (a bag without its
    summary, for `panel-rig bag recover`)."""
    import socket
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.recording import verify_bag
    from panel_rig.ros.node import RigNode
    from panel_rig.ros.rig_node import spin

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    viewer = socket.socket()
    viewer.bind(("127.0.0.1", 0))
    viewer.listen(1)
    url = f"rerun+http://127.0.0.1:{viewer.getsockname()[1]}/proxy"
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("model.variant", value="full"), Parameter("record", value=True),
        Parameter("bag_dir", value=str(tmp_path)), Parameter("rerun", value=f"connect:{url}")])
    viewer.close()  # the viewer is gone
    errors: list[str] = []
    node.rig.log.error = errors.append  # type: ignore[method-assign]
    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        spin(node, executor, lambda: node.rig.time_s > 200.0)  # a viewer's worth of undelivered data
        executor.shutdown()
        closing = threading.Thread(target=node.close, daemon=True)
        closing.start()
        closing.join(timeout=30.0)  # at most the 5 s flush timeout, then rerun's own 5 s last connection attempt
        assert not closing.is_alive(), "node.close() still waiting for the viewer after 30 s"
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    bag = next(tmp_path.iterdir())
    assert verify_bag(bag).path.stat().st_size > 0  # closed: summary and index written
    assert any("Rerun data not delivered" in e for e in errors), errors


def test_a_failing_recording_shows_in_diagnostics(ros_env: dict[str, str], tmp_path: Path) -> None:
    """The disk fills up during a recorded run: the rig runs on and /diagnostics says so (level ERROR, "recording
    failed: ...", `recording: failed` and a count); it was only in the node's log."""
    import errno

    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode
    from panel_rig.ros.rig_node import spin

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("model.variant", value="full"), Parameter("record", value=True),
        Parameter("bag_dir", value=str(tmp_path))])
    published: list = []
    publish = node.publication.publish
    node.publication.publish = lambda pub, msg, *a, **k: (  # type: ignore[method-assign]
        published.append(msg) if pub is node.pub_diag else None, publish(pub, msg, *a, **k))[1]

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        node.publish_diagnostics()
        spin(node, executor, lambda: node.rig.time_s > 0.5)
        node.publish_diagnostics()
        node.recording.recorders[0].write_block = full  # type: ignore[method-assign]
        spin(node, executor, lambda: node.rig.time_s > 1.0)
        node.publish_diagnostics()
        executor.shutdown()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    statuses = [m.status[0] for m in published]
    values = [{kv.key: kv.value for kv in s.values} for s in statuses]
    assert statuses[1].level == DiagnosticStatus.OK and values[1]["recording"] == "on"
    assert statuses[-1].level == DiagnosticStatus.ERROR
    assert statuses[-1].message.startswith("recording failed: ") and "No space left" in statuses[-1].message
    assert values[-1]["recording"] == "failed" and int(values[-1]["recording_errors"]) > 0
    assert node.rig.time_s > 1.0  # the rig ran on


def test_a_live_viewer_s_dropped_batches_are_on_diagnostics_and_in_the_log(ros_env: dict[str, str], tmp_path: Path
                                                                          ) -> None:
    """A live viewer that takes no data has its batches dropped (panel_rig.viz.sender): the node says so while it
    happens, on /diagnostics (`viewer_dropped_batches`) and in a warning (at most every 10 s of wall time: each
    status said it, 39 lines in 20 s)."""
    import rclpy
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("rerun", value=f"save:{tmp_path / 'x.rrd'}")])
    warnings: list[str] = []
    published: list[dict[str, str]] = []

    class Logger:
        def warning(self, text: str) -> None:
            warnings.append(text)

        info = error = debug = warning

    class Dropping:  # the live logger's count, as a viewer that stopped taking data leaves it
        dropped_batches = 0

        def close(self) -> None:
            pass

    try:
        real = node._rerun
        node._rerun = Dropping()
        node.get_logger = Logger  # type: ignore[method-assign]
        node.publication.publish = lambda pub, msg, stamp, qos: published.append(  # type: ignore[method-assign]
            {kv.key: kv.value for kv in msg.status[0].values})
        node.publish_diagnostics()
        Dropping.dropped_batches = 50
        node.publish_diagnostics()
        node.publish_diagnostics()  # no more dropped: no second warning
        Dropping.dropped_batches = 80
        node.publish_diagnostics()  # more, but within VIEWER_WARNING_PERIOD_S of the warning: on /diagnostics only
        assert [p["viewer_dropped_batches"] for p in published] == ["0", "50", "50", "80"]
        assert warnings == ["the Rerun viewer is not taking data: 50 batches dropped so far (the bag has every "
                            "reading)"], warnings
        node._rerun = real
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def test_the_node_takes_off_for_the_turbulence_spectrum(ros_env: dict[str, str]) -> None:
    """`-p tunnel.turbulence.spectrum:=off` reaches the node as a boolean (YAML 1.1): it refused to start ("expected
    type 'STRING'"). Given as rclpy hands it over, it starts a quiet tunnel."""
    import rclpy
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = RigNode(context=ctx, parameter_overrides=[
        Parameter("fast", value=True), Parameter("tunnel.turbulence.spectrum", Parameter.Type.BOOL, False)])
    try:
        assert node.get_parameter("tunnel.turbulence.spectrum").value == "off"
        assert node.rig.turbulence is None  # the rig keeps no field for a quiet tunnel
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)

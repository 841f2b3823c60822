"""The rig node's publication: readings, panel shapes, /clock and its other messages to their topics, the same bytes
to the recording, the shapes to the viewer.

:class:`Recording` holds the node's recorders (bag writers) and the full topic name of each publisher; a recorder
that fails (a full disk) is logged and counted, and the rig carries on. :class:`ReadingPublisher` stamps simulated
time (itself in fast mode, the ROS clock in real time: ``stamp_offset_ns``), serialises a block of readings once
(with numpy where the layouts are fixed), publishes each topic that has subscribers and writes the whole block to
every recorder in one write, then draws the panel's shape at each shape sample the block reaches. The node owns one
of each and gives them its publishers; topics and QoS stay declared in :mod:`panel_rig.ros.node`.
"""

from __future__ import annotations

import inspect
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from rclpy.serialization import serialize_message

from panel_rig.config import PanelConfig
from panel_rig.rig.reading import Reading, ReadingBlock
from panel_rig.rig.rig import ABORTED, Rig
from panel_rig.ros import messages

SHAPE_POINTS = 31  # points of the panel's drawn shape (panel_shape, the viewer's strip)


#: wall seconds between checks of the free space under a recording (fast mode writes ~25 MB a second)
SPACE_CHECK_PERIOD_S = 0.5


def free_bytes(path: Any) -> int:
    """Free bytes for an unprivileged writer on the file system of ``path``."""
    return shutil.disk_usage(path).free


class Recording:
    """The node's recorders: every write goes to each; the topic a publisher's messages are recorded under.
    ``min_free_bytes`` (the ``record_min_free_mb`` parameter; 0: none): a recorder whose file system has less free
    space than that is closed, its bag intact, before the disk is full (a fast node left running filled 76 GB)."""

    def __init__(self, logger: Any, min_free_bytes: float = 0.0,
                 free_space: Callable[[Any], int] = free_bytes) -> None:
        self.recorders: list[Any] = []
        self.topics: dict[Any, str] = {}  # publisher -> full topic name (namespace included)
        self.errors = 0
        self.last_error = ""
        self.stopped = ""  # why the recording was stopped short of a full disk ("": it was not)
        self.min_free_bytes = float(min_free_bytes)
        self._free_space = free_space
        self._next_space_check = 0.0
        self._log = logger

    @property
    def active(self) -> bool:
        return bool(self.recorders)

    @property
    def state(self) -> str:
        """"off" (nothing recorded), "on", "failed" (a write has failed) or "stopped" (closed at the free-space
        reserve: the bag is intact)."""
        if self.errors:
            return "failed"
        return "stopped" if self.stopped else "on" if self.recorders else "off"

    def record(self, write: Callable[[Any], Any]) -> None:
        """``write(recorder)`` for every recorder. A failure (a full disk) is logged, counted and shown in
        /diagnostics (level ERROR while it goes on); the rig carries on."""
        if self.min_free_bytes > 0 and self.recorders:
            self._keep_free_space()
        for rec in self.recorders:
            try:
                write(rec)
            except Exception as exc:  # noqa: BLE001
                self.errors += 1
                self.last_error = str(exc)
                self._log.error(f"recording failed: {exc}", throttle_duration_sec=5.0)

    def _keep_free_space(self) -> None:
        """Close (intact) each recorder whose file system has fallen below ``min_free_bytes`` free (checked every
        SPACE_CHECK_PERIOD_S of wall time)."""
        now = time.monotonic()
        if now < self._next_space_check:
            return
        self._next_space_check = now + SPACE_CHECK_PERIOD_S
        for rec in list(self.recorders):
            try:
                free = self._free_space(rec.bag_dir)
            except OSError:
                continue  # not knowable now: the write itself says if the disk is full
            if free >= self.min_free_bytes:
                continue
            self.recorders.remove(rec)
            self.stopped = (f"the free space under {rec.bag_dir} fell to {free / 1e6:.0f} MB, below "
                            f"record_min_free_mb = {self.min_free_bytes / 1e6:g}: the recording stopped there and "
                            "its bag was closed intact")
            self.last_error = self.stopped
            try:
                rec.close()
            except Exception as exc:  # noqa: BLE001
                self.errors += 1
                self.last_error = f"closing the recording failed: {exc}"
            self._log.error(self.last_error)

    def close(self) -> None:
        """Close every recorder (idempotent); a failure is logged."""
        for rec in self.recorders:
            try:
                rec.close()
            except Exception as exc:  # noqa: BLE001
                self._log.error(f"closing the recording failed: {exc}")
        self.recorders.clear()


@dataclass(frozen=True)
class ReadingTopics:
    """The publishers of the readings, the shape and /clock (None: real-time mode, no /clock)."""

    tip: Any
    truth: Any
    modal: Any
    airspeed: Any
    shape: Any
    clock: Any | None


class ReadingPublisher:
    """A rig's readings and shapes to their topics, the recording and the viewer (``rerun``, or None)."""

    def __init__(self, rig: Rig, cfg: PanelConfig, names: list[str], topics: ReadingTopics, recording: Recording, *,
                 rerun: Any, logger: Any, shape_period_s: float, stamp_offset_ns: int = 0) -> None:
        self.rig, self.topics, self.recording = rig, topics, recording
        self._rerun, self._log = rerun, logger
        self._panel_length_m, self._airfoil_length_m = cfg.panel_length_m, cfg.airfoil_length_m
        self.stamp_offset_ns = stamp_offset_ns  # real time: shifted by every overrun (stamps stay on the ROS clock)
        self.shape_period_s = shape_period_s
        self.next_shape_s = 0.0
        # a stepper that draws the shape of any sample's q lets fast mode march whole blocks past shape samples
        try:
            self.shape_of_q = "q" in inspect.signature(rig.stepper.shape_w_over_L).parameters
        except (TypeError, ValueError, AttributeError):
            self.shape_of_q = False
        self._x_over_L = np.linspace(0.0, 1.0, SHAPE_POINTS)
        self._msgs = messages.ReadingMessages(names, cfg.airfoil_length_m + cfg.panel_length_m, cfg.panel_length_m)
        self._shape_cdr = messages.ShapeCdr(cfg.airfoil_length_m, cfg.panel_length_m, self._x_over_L)
        marker = messages.shape_msg(0, cfg.airfoil_length_m, cfg.panel_length_m, np.zeros(SHAPE_POINTS), self._x_over_L)
        self._shape_x_m = np.array([pt.x for pt in marker.points])  # the Rerun strip: airfoil, then the panel

    def stamp_ns(self, time_s: float) -> int:
        """The stamp of simulated time ``time_s``: itself in fast mode (with /clock), the ROS clock in real time."""
        return messages.stamp_ns(time_s) + self.stamp_offset_ns

    def publish(self, pub: Any, msg: Any, stamp_ns: int, qos: str = "sensor") -> None:
        """Serialise once; the same bytes go to the topic and to every recorder."""
        self.publish_bytes(pub, msg, serialize_message(msg), stamp_ns, qos)

    def publish_bytes(self, pub: Any, msg: Any, data: bytes, stamp_ns: int, qos: str = "sensor") -> None:
        pub.publish(data)
        self.recording.record(lambda rec: rec.write(self.recording.topics[pub], msg, stamp_ns, qos=qos, data=data))

    def readings_subscribed(self) -> bool:
        t = self.topics
        return any(pub is not None and pub.get_subscription_count()
                   for pub in (t.tip, t.truth, t.modal, t.airspeed, t.clock))

    def publish_readings(self) -> Reading:
        """The current reading to topics and sinks (real-time tick); the shape at its own rate."""
        r = self.rig.reading()
        self.publish_block(ReadingBlock.of([r]))
        return r

    def publish_block(self, block: ReadingBlock) -> None:
        """Samples to sinks, topics and recorders (one serialisation, one bag write per block), then the shape of
        each sample that is due (a recorded block's shapes follow its readings: log times overlap by at most one
        block, which MCAP's per-chunk indexes and log-time-ordered readers take as they come)."""
        if not len(block):
            return
        self.rig.emit_block(block)
        msgs, t = self._msgs, self.topics
        pubs = ((t.tip, msgs.tip), (t.modal, msgs.modal), (t.airspeed, msgs.airspeed), (t.truth, msgs.truth))
        encoded_block = msgs.encode_block(block, self.stamp_offset_ns)
        if encoded_block is not None:
            self._publish_encoded(pubs, encoded_block)
        else:
            self._publish_each(pubs, block, self.recording.active)
        self._publish_due_shapes(block)

    def _publish_due_shapes(self, block: ReadingBlock) -> None:
        """The shape at each sample that reaches the next shape time (of that sample's q if the stepper can draw
        it, else only at the block's last sample: such blocks end at the shape samples)."""
        times, n, due = block.time_s, len(block), []
        while True:
            k = int(np.searchsorted(times, self.next_shape_s - 1e-9, side="left"))
            if k >= n:
                break
            k = k if self.shape_of_q else n - 1
            due.append(k)
            self.next_shape_s = float(times[k]) + self.shape_period_s
            if not self.shape_of_q:
                break
        if not due:
            return
        aborted = block.state == ABORTED
        if self.shape_of_q and self._shape_cdr.ok and len(due) > 1:
            self._publish_shapes(times[due], block.q[due], aborted)
            return
        for k in due:
            self._publish_shape(float(times[k]), aborted, block.q[k] if self.shape_of_q else None)

    def _publish_shapes(self, times_s: np.ndarray, q: np.ndarray, aborted: bool) -> None:
        """Several shapes (of modal coordinates q, one row each) at once: drawn together, one bag write, published
        one by one if anyone subscribes (a volatile depth-1 topic: with no subscriber a publish reaches nobody)."""
        pub_shape = self.topics.shape
        z_m = np.asarray(self.rig.shape_w_over_L(self._x_over_L, q), dtype=float) * self._panel_length_m
        stamps = np.array([self.stamp_ns(float(t)) for t in times_s], dtype=np.int64)
        rows = self._shape_cdr.pack_block(stamps, z_m, aborted)
        self.recording.record(lambda rec: rec.write_block(
            [(self.recording.topics[pub_shape], self._shape_cdr.message(aborted))], stamps, [rows], qos="reliable"))
        if pub_shape.get_subscription_count():
            for row in messages.EncodedBlock.rows(rows):
                pub_shape.publish(row)
        if self._rerun is not None:
            for t, z in zip(times_s, z_m):
                self._queue_rerun_shape(float(t), z)

    def _publish_encoded(self, pubs: tuple[tuple[Any, Any], ...], enc: messages.EncodedBlock) -> None:
        """A block serialised once with numpy: every recorder gets all of it in one write; each topic gets its
        messages (sample by sample, topics in the same order as before) if anyone subscribes to it: with no
        matched subscription (best-effort/volatile sensor QoS; /clock volatile) a publish reaches nobody."""
        self.recording.record(lambda rec: rec.write_block([(self.recording.topics[pub], msg) for pub, msg in pubs],
                                                          enc.stamps_ns, enc.payloads))
        streams = [(pub.publish, enc.rows(data)) for (pub, _), data in zip(pubs, enc.payloads)
                   if pub.get_subscription_count()]
        clock = self.topics.clock
        if clock is not None and clock.get_subscription_count():
            streams.append((clock.publish, enc.rows(enc.clock)))
        if not streams:
            return
        for row in zip(*(rows for _, rows in streams)):
            for (publish, _), data in zip(streams, row):
                publish(data)

    def _publish_each(self, pubs: tuple[tuple[Any, Any], ...], block: ReadingBlock, recording: bool) -> None:
        """Message by message (the layouts are not fixed: rclpy serialises each)."""
        msgs, clock = self._msgs, self.topics.clock
        for stamp_ns, *encoded in msgs.encode(block, self.stamp_offset_ns):
            for (pub, msg), data in zip(pubs, encoded):
                if recording:
                    self.publish_bytes(pub, msg, data, stamp_ns)
                else:
                    pub.publish(data)
            if clock is not None:
                clock.publish(msgs.clock_bytes(stamp_ns))

    def _publish_shape(self, t: float, aborted: bool, q: np.ndarray | None = None) -> None:
        w = self.rig.shape_w_over_L(self._x_over_L, q)
        stamp = self.stamp_ns(t)
        z_m = np.asarray(w, dtype=float) * self._panel_length_m
        if self._shape_cdr.ok:  # the Marker's CDR from its template (serialize_message of 36 points: ~0.3 ms)
            self.publish_bytes(self.topics.shape, self._shape_cdr.message(aborted),
                               self._shape_cdr.pack(stamp, z_m, aborted), stamp, qos="reliable")
        else:
            marker = self._msgs.shape(stamp, self._airfoil_length_m, self._panel_length_m, w, self._x_over_L, aborted)
            self.publish(self.topics.shape, marker, stamp, qos="reliable")
        if self._rerun is not None:
            self._queue_rerun_shape(t, z_m)

    def _queue_rerun_shape(self, t: float, z_m: np.ndarray) -> None:
        try:
            z_all = np.concatenate([np.zeros(self._shape_x_m.size - z_m.size), z_m])
            self._rerun.queue_shape(t, self._shape_x_m, np.where(np.isfinite(z_all), z_all, 0.0))
        except Exception as exc:  # noqa: BLE001
            self._log.error(f"rerun shape failed: {exc}", throttle_duration_sec=5.0)

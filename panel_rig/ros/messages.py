"""Readings to standard ROS messages (pure functions; SI units; stamps in the rig's simulated time)."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped, Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from panel_rig.rig.reading import ReadingBlock
from panel_rig.topics import RIG_STATUS_NAME

FRAME_ID = "panel_rig"


def stamp(ns: int) -> Time:
    """Integer nanoseconds to builtin_interfaces/Time."""
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(time_s: float) -> int:
    """Simulated seconds to integer nanoseconds."""
    return max(0, round(time_s * 1e9))


def header(ns: int, frame_id: str = FRAME_ID) -> Header:
    """A header stamped at ``ns`` (simulated time, or the ROS clock in real-time mode)."""
    return Header(stamp=stamp(ns), frame_id=frame_id)


def _finite(values: np.ndarray) -> list[float]:
    """Never put NaN/inf on a topic (the rig guarantees it; this is the last line of defence)."""
    arr = np.asarray(values, dtype=float)
    return np.where(np.isfinite(arr), arr, 0.0).tolist()


def _finite_array(values: Any) -> np.ndarray:
    """As :func:`_finite`, as a float64 array."""
    arr = np.asarray(values, dtype=float)
    return np.where(np.isfinite(arr), arr, 0.0)


class EncodedBlock:
    """A block of readings in CDR: ``stamps_ns`` (N,) int64 and, per reading topic, an (N, size) uint8 array
    (row i = the message of sample i); ``clock`` the /clock messages likewise."""

    __slots__ = ("stamps_ns", "payloads", "clock")

    def __init__(self, stamps_ns: np.ndarray, payloads: tuple[np.ndarray, ...], clock: np.ndarray) -> None:
        self.stamps_ns, self.payloads, self.clock = stamps_ns, payloads, clock

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @staticmethod
    def rows(payload: np.ndarray) -> list[bytes]:
        """The messages of one topic as ``bytes`` (for ``Publisher.publish``)."""
        data, size = payload.tobytes(), payload.shape[1]
        return [data[i:i + size] for i in range(0, len(data), size)]


def _f(x: float) -> float:
    return float(x) if math.isfinite(x) else 0.0


GREY = ColorRGBA(r=0.6, g=0.6, b=0.6, a=1.0)
BLUE = ColorRGBA(r=0.1, g=0.4, b=0.9, a=1.0)
RED = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)


def shape_msg(
    stamp_ns: int,
    airfoil_length_m: float,
    panel_length_m: float,
    w_over_L: np.ndarray,
    x_over_L: np.ndarray,
    aborted: bool = False,
    n_airfoil: int = 5,
) -> Marker:
    """LINE_STRIP of the rigid airfoil (z = 0) followed by the deflected panel; one colour per point."""
    m = Marker(header=header(stamp_ns), ns="panel", id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.scale.x = 0.002
    m.color = RED if aborted else BLUE
    pts: list[Point] = []
    cols: list[ColorRGBA] = []
    for x in np.linspace(0.0, airfoil_length_m, n_airfoil, endpoint=False):
        pts.append(Point(x=float(x), y=0.0, z=0.0))
        cols.append(GREY)
    w = _finite(np.asarray(w_over_L) * panel_length_m)
    panel_col = RED if aborted else BLUE
    for xl, z in zip(np.asarray(x_over_L, dtype=float), w):
        pts.append(Point(x=float(airfoil_length_m + xl * panel_length_m), y=0.0, z=z))
        cols.append(panel_col)
    m.points = pts
    m.colors = cols
    return m


# RIG_STATUS_NAME (panel_rig.topics): filtered by hardware_id too, since /diagnostics is global, and a client of
# one rig took another rig's aborts and set-point as its own


def diagnostics_msg(stamp_ns: int, level: bytes, message: str, values: Mapping[str, object],
                    hardware_id: str = "panel_rig") -> DiagnosticArray:
    """One DiagnosticStatus for the rig at ``level`` (DiagnosticStatus.OK / WARN / ERROR)."""
    status = DiagnosticStatus(
        level=level,
        name=RIG_STATUS_NAME,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )
    return DiagnosticArray(header=header(stamp_ns, ""), status=[status])


def rig_status(msg: DiagnosticArray, namespace: str) -> dict[str, str] | None:
    """The values of the tunnel status of the rig node in ``namespace`` in a /diagnostics message, else None."""
    for status in msg.status:
        if status.name == RIG_STATUS_NAME and status.hardware_id == namespace:
            return {kv.key: kv.value for kv in status.values}
    return None


class ReadingMessages:
    """Reusable reading messages, refilled for each sample (no per-sample message construction)."""

    def __init__(self, names: Sequence[str], trailing_edge_x_m: float, panel_length_m: float = 1.0) -> None:
        self.tip = PointStamped(header=header(0), point=Point(x=float(trailing_edge_x_m)))
        self.truth = PointStamped(header=header(0), point=Point(x=float(trailing_edge_x_m)))  # the model's tip
        self.panel_length_m = float(panel_length_m)
        self.modal = JointState(header=header(0), name=list(names))
        self.airspeed = Vector3Stamped(header=header(0))
        self._clock = Clock()
        self._marker: Marker | None = None
        self._marker_aborted = False
        self.modal.position = self.modal.velocity = self.modal.effort = [0.0] * len(self.modal.name)
        self._stamps = (self.tip.header.stamp, self.modal.header.stamp, self.airspeed.header.stamp,
                        self.truth.header.stamp)
        self._templates()

    def _templates(self) -> None:
        n = len(self.modal.name)

        def stamp_of(m: Any) -> Any:
            return m.header.stamp

        def setter(path: str) -> Callable[[Any, list[float]], None]:
            obj, _, field = path.rpartition(".")

            def put(m: Any, v: list[float]) -> None:
                setattr(getattr(m, obj) if obj else m, field, v[0] if obj else v)

            return put

        self._tpl = (
            CdrTemplate(self.tip, stamp_of, [setter("point.z")], [1]),
            CdrTemplate(self.modal, stamp_of, [setter("position"), setter("velocity"), setter("effort")], [n, n, n]),
            CdrTemplate(self.airspeed, stamp_of, [setter("vector.x")], [1]),
        )
        self._clock_tpl = CdrTemplate(self._clock, lambda m: m.clock, [], [])
        self.templated = all(t.ok for t in self._tpl)

    def encode(self, block: ReadingBlock, offset_ns: int = 0) -> Iterator[tuple[int, bytes, bytes, bytes, bytes]]:
        """For each sample: (stamp ns = simulated time + ``offset_ns``, CDR bytes of tip_displacement (the
        sensor's reading), modal_states, airspeed, tip_displacement/truth (the model's tip, w/L * L)). Non-finite
        values become 0. The message objects (:attr:`tip`, ...) keep their type and layout for recorders."""
        ns_all = [stamp_ns(t) + offset_ns for t in block.time_s.tolist()]
        tip_z, airspeed = _finite(block.tip_w_m), _finite(block.airspeed_mps)
        truth_z = _finite(np.asarray(block.tip_w_over_L, dtype=float) * self.panel_length_m)
        q, qdot, effort = _finite(block.q), _finite(block.qdot_per_s), _finite(block.aero_force_npm)
        if self.templated:
            t_tip, t_modal, t_air = self._tpl
            for i, ns in enumerate(ns_all):
                sec, nanosec = divmod(ns, 1_000_000_000)
                yield (ns, t_tip.pack(sec, nanosec, ((tip_z[i],),)),
                       t_modal.pack(sec, nanosec, (q[i], qdot[i], effort[i])),
                       t_air.pack(sec, nanosec, ((airspeed[i],),)),
                       t_tip.pack(sec, nanosec, ((truth_z[i],),)))
            return
        from rclpy.serialization import serialize_message

        tip, modal, air, truth = self.tip, self.modal, self.airspeed, self.truth
        for i, ns in enumerate(ns_all):
            sec, nanosec = divmod(ns, 1_000_000_000)
            for st in self._stamps:
                st.sec, st.nanosec = sec, nanosec
            tip.point.z = tip_z[i]
            truth.point.z = truth_z[i]
            modal.position, modal.velocity, modal.effort = q[i], qdot[i], effort[i]
            air.vector.x = airspeed[i]
            yield ns, serialize_message(tip), serialize_message(modal), serialize_message(air), serialize_message(truth)

    def encode_block(self, block: ReadingBlock, offset_ns: int = 0) -> EncodedBlock | None:
        """As :meth:`encode`, for the whole block at once with numpy (no per-sample Python): the stamps and,
        per topic (tip_displacement, modal_states, airspeed, tip_displacement/truth, then /clock), an (N, size)
        uint8 array whose row i is the CDR message of sample i, byte for byte what :meth:`encode` and
        :meth:`clock_bytes` give. None if the layouts are not fixed (no templates: use :meth:`encode`)."""
        if not (self.templated and self._clock_tpl.ok):
            return None
        t = np.asarray(block.time_s, dtype=float)
        ns = np.maximum(np.rint(t * 1e9), 0.0).astype(np.int64) + np.int64(offset_ns)  # = stamp_ns(t) + offset
        sec, nanosec = np.divmod(ns, 1_000_000_000)
        t_tip, t_modal, t_air = self._tpl
        tip = t_tip.pack_block(sec, nanosec, [_finite_array(block.tip_w_m)])
        modal = t_modal.pack_block(sec, nanosec, [_finite_array(block.q), _finite_array(block.qdot_per_s),
                                                  _finite_array(block.aero_force_npm)])
        air = t_air.pack_block(sec, nanosec, [_finite_array(block.airspeed_mps)])
        truth = t_tip.pack_block(sec, nanosec, [_finite_array(np.asarray(block.tip_w_over_L, dtype=float)
                                                              * self.panel_length_m)])
        clock = self._clock_tpl.pack_block(sec, nanosec, [])
        return EncodedBlock(ns, (tip, modal, air, truth), clock)

    def clock_bytes(self, stamp_ns: int) -> bytes | Clock:
        """/clock at this stamp: CDR bytes (or the refilled message if no template)."""
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        if self._clock_tpl.ok:
            return self._clock_tpl.pack(sec, nanosec, ())
        return self.clock(stamp_ns)

    def clock(self, stamp_ns: int) -> Clock:
        """/clock at this stamp (the same message object, refilled)."""
        self._clock.clock.sec, self._clock.clock.nanosec = divmod(stamp_ns, 1_000_000_000)
        return self._clock

    def shape(self, stamp_ns: int, airfoil_length_m: float, panel_length_m: float, w_over_L: np.ndarray,
              x_over_L: np.ndarray, aborted: bool = False) -> Marker:
        """As :func:`shape_msg`, refilling one Marker (panel points' z, colours, stamp)."""
        m = self._marker
        n_panel = len(x_over_L)
        if m is None or len(m.points) < n_panel:
            self._marker = m = shape_msg(stamp_ns, airfoil_length_m, panel_length_m, w_over_L, x_over_L, aborted)
            self._marker_aborted = aborted
            return m
        st = stamp(stamp_ns)
        m.header.stamp.sec, m.header.stamp.nanosec = st.sec, st.nanosec
        colour = RED if aborted else BLUE
        m.color = colour
        first = len(m.points) - n_panel
        for pt, z in zip(m.points[first:], _finite(np.asarray(w_over_L) * panel_length_m)):
            pt.z = z
        if aborted != self._marker_aborted:
            m.colors = list(m.colors[:first]) + [colour] * n_panel
        self._marker_aborted = aborted
        return m


class ShapeCdr:
    """The panel_shape Marker of :func:`shape_msg` in CDR without rclpy serialising ~36 Points and ColorRGBAs
    (~0.2-0.5 ms): one template per colour (running / aborted), found by serialising probe values once; a
    call writes the stamp and the panel points' z into it. The template is checked once (decoded) against
    ``serialize_message``; :attr:`ok` False means the caller must serialise the message."""

    def __init__(self, airfoil_length_m: float, panel_length_m: float, x_over_L: np.ndarray) -> None:
        self.airfoil_length_m, self.panel_length_m = float(airfoil_length_m), float(panel_length_m)
        self.x_over_L = np.asarray(x_over_L, dtype=float).copy()
        n = self.x_over_L.size
        self.ok = False
        try:
            self._templates = {aborted: self._probe(aborted, n) for aborted in (False, True)}
            self.ok = all(t is not None for t in self._templates.values()) and self._check(n)
        except Exception:  # noqa: BLE001 (no template: plain serialisation)
            self.ok = False

    def _msg(self, stamp_ns: int, z_m: np.ndarray, aborted: bool) -> Marker:
        return shape_msg(stamp_ns, self.airfoil_length_m, self.panel_length_m, np.asarray(z_m) / self.panel_length_m,
                         self.x_over_L, aborted)

    def _probe(self, aborted: bool, n: int) -> tuple[bytearray, int, int, int, Marker] | None:
        from rclpy.serialization import serialize_message

        probes = np.array([1.2345678901234567e-300 * (k + 3) for k in range(n)])
        sec, nanosec = _SENTINEL_INTS[0], _SENTINEL_INTS[1] % 1_000_000_000  # a valid stamp (nanosec < 1e9)
        msg = self._msg(sec * 1_000_000_000 + nanosec, probes, aborted)  # z = w/L * L may round: set the probes exactly
        for pt, z in zip(msg.points[len(msg.points) - n:], probes):
            pt.z = float(z)
        data = bytes(serialize_message(msg))
        if data[:2] != b"\x00\x01":  # little-endian CDR only
            return None
        stamp_at = data.find(struct.pack("<iI", sec, nanosec))
        at = [data.find(struct.pack("<d", z)) for z in probes]
        stride = at[1] - at[0] if n > 1 else 8
        if stamp_at < 0 or min(at) < 0 or any(b - a != stride for a, b in zip(at, at[1:])):
            return None
        return bytearray(data), stamp_at, at[0], stride, msg

    def _check(self, n: int) -> bool:
        from rclpy.serialization import deserialize_message, serialize_message

        z = np.linspace(-0.25, 0.5, n) * self.panel_length_m
        for aborted in (False, True):
            expected = self._msg(12345 * 1_000_000_000 + 678901234, z, aborted)
            for pt, zk in zip(expected.points[len(expected.points) - n:], z):
                pt.z = float(zk)
            wire = deserialize_message(serialize_message(expected), Marker)  # float32 colours as on the wire
            if deserialize_message(self.pack(12345 * 1_000_000_000 + 678901234, z, aborted), Marker) != wire:
                return False
        return True

    def message(self, aborted: bool) -> Marker:
        """A Marker of the template's type and layout (for recorders: the type of the bytes)."""
        return self._templates[aborted][4]

    def pack(self, stamp_ns: int, z_m: np.ndarray, aborted: bool) -> bytes:
        """CDR of the shape Marker at ``stamp_ns`` with panel points' z = ``z_m`` (m; non-finite -> 0)."""
        buf, stamp_at, first, stride, _ = self._templates[aborted]
        struct.pack_into("<iI", buf, stamp_at, *divmod(stamp_ns, 1_000_000_000))
        z = np.asarray(z_m, dtype=float)
        view = np.ndarray((z.size,), dtype="<f8", buffer=buf, offset=first, strides=(stride,))
        view[:] = np.where(np.isfinite(z), z, 0.0)
        return bytes(buf)

    def pack_block(self, stamps_ns: np.ndarray, z_m: np.ndarray, aborted: bool) -> np.ndarray:
        """K shapes at once: row k is :meth:`pack` (``stamps_ns[k]``, ``z_m[k]``), as a (K, size) uint8 array."""
        buf, stamp_at, first, stride, _ = self._templates[aborted]
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        z = np.asarray(z_m, dtype=float).reshape(stamps.size, -1)
        raw = np.tile(np.frombuffer(bytes(buf), dtype=np.uint8), (stamps.size, 1))
        sec, nanosec = np.divmod(stamps, 1_000_000_000)
        raw[:, stamp_at:stamp_at + 4] = sec.astype("<i4").view(np.uint8).reshape(-1, 4)
        raw[:, stamp_at + 4:stamp_at + 8] = nanosec.astype("<u4").view(np.uint8).reshape(-1, 4)
        at = (first + stride * np.arange(z.shape[1]))[:, None] + np.arange(8)
        raw[:, at.reshape(-1)] = np.where(np.isfinite(z), z, 0.0).astype("<f8").view(np.uint8).reshape(stamps.size, -1)
        return raw


_SENTINEL_INTS = (0x5A3B1C2D, 0x6B2C3D4E)


class CdrTemplate:
    """Serialise a message whose layout never changes (fixed strings and sequence lengths) by writing the
    stamp and some float64 fields into a template of its CDR bytes: ~1 us instead of ~4.5 us.

    The offsets are found by serialising probe values with rclpy and are checked once against
    ``serialize_message`` (the decoded message; rclpy leaves alignment padding uninitialised, so the raw bytes
    may differ there); if anything does not match, :attr:`ok` is False and the caller must serialise.
    :meth:`pack_block` fills N messages at once with numpy.
    """

    def __init__(self, msg: Any, stamp_of: Callable[[Any], Any], doubles: Sequence[Callable[[Any, list[float]], None]],
                 n_doubles: Sequence[int]) -> None:
        from rclpy.serialization import serialize_message

        self._serialize = serialize_message
        self.msg, self._stamp_of, self._setters, self._counts = msg, stamp_of, list(doubles), list(n_doubles)
        self.ok = False
        try:
            self._offsets = self._probe()
            self.ok = self._offsets is not None and self._check()
        except Exception:  # noqa: BLE001 (no template: plain serialisation)
            self.ok = False

    def _fill_msg(self, sec: int, nanosec: int, values: Sequence[Sequence[float]]) -> None:
        st = self._stamp_of(self.msg)
        st.sec, st.nanosec = sec, nanosec
        for setter, v in zip(self._setters, values):
            setter(self.msg, list(v))

    def _probe(self) -> tuple[int, list[int]] | None:
        probes = [[1.2345678901234567e-300 * (i + 1) * (k + 3) for k in range(n)] for i, n in enumerate(self._counts)]
        self._fill_msg(*_SENTINEL_INTS, probes)
        data = bytes(self._serialize(self.msg))
        if data[:2] != b"\x00\x01":  # little-endian CDR only
            return None
        stamp_at = data.find(struct.pack("<iI", *_SENTINEL_INTS))
        starts = [data.find(struct.pack(f"<{len(p)}d", *p)) if p else 0 for p in probes]
        if stamp_at < 0 or min(starts, default=0) < 0:
            return None
        self._template = bytearray(data)
        self._formats = [struct.Struct(f"<{n}d") for n in self._counts]
        return stamp_at, starts

    def _check(self) -> bool:
        """The template's bytes decode to the message rclpy serialises (decoded, not byte for byte: rclpy leaves
        CDR alignment padding uninitialised, e.g. after an odd-length frame_id, so raw bytes may differ there)."""
        from rclpy.serialization import deserialize_message

        values = [[0.5 + 0.25 * k - i for k in range(n)] for i, n in enumerate(self._counts)]
        self._fill_msg(12345, 678901234, values)
        packed = self.pack(12345, 678901234, values)
        wire = bytes(self._serialize(self.msg))
        return len(packed) == len(wire) and \
            deserialize_message(packed, type(self.msg)) == deserialize_message(wire, type(self.msg))

    def pack(self, sec: int, nanosec: int, values: Sequence[Sequence[float]]) -> bytes:
        """The CDR bytes of the message with this stamp and these float64 values (one list per field)."""
        stamp_at, starts = self._offsets
        buf = self._template
        struct.pack_into("<iI", buf, stamp_at, sec, nanosec)
        for fmt, at, v in zip(self._formats, starts, values):
            fmt.pack_into(buf, at, *v)
        return bytes(buf)

    @property
    def size(self) -> int:
        """Bytes of one message (the layout is fixed)."""
        return len(self._template)

    def _block_dtype(self) -> np.dtype:
        """A structured dtype over the template: ``sec``, ``nanosec`` and ``v0``, ``v1``, ... (float64 fields)
        at their CDR offsets (unaligned, little-endian), itemsize = the message size."""
        dtype = getattr(self, "_dtype", None)
        if dtype is None:
            stamp_at, starts = self._offsets
            names, formats, offsets = ["sec", "nanosec"], ["<i4", "<u4"], [stamp_at, stamp_at + 4]
            for k, (at, n) in enumerate(zip(starts, self._counts)):
                names.append(f"v{k}")
                formats.append(("<f8", (n,)))
                offsets.append(at)
            dtype = self._dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets,
                                            "itemsize": self.size})
        return dtype

    def pack_block(self, sec: np.ndarray, nanosec: np.ndarray, values: Sequence[np.ndarray]) -> np.ndarray:
        """N messages at once: the same bytes as :meth:`pack` for each row, as an (N, size) uint8 array
        (row i is message i). ``values[k]`` has shape (N, n_k) (or (N,) for n_k = 1)."""
        n = len(sec)
        out = np.empty(n, dtype=self._block_dtype())
        raw = out.view(np.uint8).reshape(n, self.size)
        raw[:] = np.frombuffer(self._template, dtype=np.uint8)
        out["sec"], out["nanosec"] = sec, nanosec
        for k, (v, count) in enumerate(zip(values, self._counts)):
            out[f"v{k}"] = np.asarray(v, dtype=float).reshape(n, count)
        return raw

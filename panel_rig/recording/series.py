"""A rig recording as arrays: tip, airspeed, modal states, commands and the run's parameters.

`load_series(bag_dir)` checks the bag's integrity first (every chunk CRC; see
:mod:`panel_rig.recording.integrity`) and raises CorruptBagError naming `panel-rig bag recover` for a
damaged or incomplete bag. The analysis of the arrays is in :mod:`panel_rig.analysis.bag_analysis`.
"""

from __future__ import annotations

import json
import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panel_rig.analysis.bag_analysis import SHAKER_TOPICS, mean_dt
from panel_rig.config import PanelConfig
from panel_rig.recording.errors import RecordingError
from panel_rig.recording.fast_cdr import joint_positions, point_z, vector_x, wrench_force_z
from panel_rig.recording.metadata import read_metadata
from panel_rig.recording.reader import (
    find_mcap,
    read_bag_raw,
    read_metadata_records,
    read_verified,
    summary_counts,
    verify_bag,
)
from panel_rig.recording.writer import PARAMETERS_KEY, PARAMETERS_RECORD
from panel_rig.topics import CONTROL_TOPIC, REJECTED_SUFFIX, RIG_STATUS_NAME
from panel_rig.topics import FLUTTER_MONITOR_TOPIC as MONITOR_TOPIC


@dataclass
class BagSeries:
    """The series of a rig bag, on the tip sensor's time base (s, from the bag's log times)."""

    bag_dir: Path
    t_s: np.ndarray
    tip_w_over_L: np.ndarray
    airspeed_mps: np.ndarray
    q: np.ndarray  # (N, n_modes); (N, 0) if no modal_states
    force_npm: np.ndarray  # held shaker/force_cmd (zero-order hold), 0 before the first command
    commands: dict[str, list[tuple[float, float]]]  # topic suffix -> [(t_s, value)]
    shapes: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    panel_length_m: float = field(default_factory=lambda: PanelConfig().panel_length_m)
    length_source: str = "default"
    parameters: dict[str, Any] = field(default_factory=dict)
    #: commands the rig refused, per command topic: recorded on ``<topic>/rejected`` (left out of ``commands``),
    #: and, in bags from before that, non-finite values found on the command topics themselves (always refused)
    refused_commands: dict[str, int] = field(default_factory=dict)
    #: the rig's aborts its recorded /diagnostics show: (rig time s, reason), one per abort seen in a diagnostics
    #: period (``aborts`` counts them all); none in a bag without the node's diagnostics (the in-process rig's)
    aborts: list[tuple[float, str]] = field(default_factory=list)
    #: the plateaus the flutter monitor reported fluttered (its recorded ``flutter_monitor`` results marked so):
    #: (rig time s of the report, commanded airspeed m/s); a plateau cut short by its flutter is often too short to
    #: be a plateau of the analysis
    monitor_flutter: list[tuple[float, float]] = field(default_factory=list)

    @property
    def dt_s(self) -> float:
        """Mean sample interval (see :func:`panel_rig.analysis.bag_analysis.mean_dt`)."""
        return mean_dt(self.t_s)


def _parameters(bag_dir: Path, mcap_path: Path) -> dict[str, Any]:
    """Run parameters: metadata.yaml custom_data, else the MCAP metadata record, else {}."""
    try:
        text = (read_metadata(bag_dir).get("custom_data") or {}).get(PARAMETERS_KEY)
        if text:
            return dict(json.loads(text))
    except (RecordingError, ValueError, TypeError):
        pass
    try:
        record = read_metadata_records(mcap_path).get(PARAMETERS_RECORD) or {}
        return {k: json.loads(v) for k, v in record.items()}
    except Exception:  # noqa: BLE001 - parameters are optional
        return {}


def _topics(names: list[str]) -> dict[str, str]:
    """Suffix ('tip_displacement', 'shaker/force_cmd', ...) -> full topic name."""
    wanted = ("tip_displacement", "airspeed", "modal_states", "airspeed_cmd", "panel_shape", "diagnostics",
              MONITOR_TOPIC, CONTROL_TOPIC, *SHAKER_TOPICS)
    out: dict[str, str] = {}
    for suffix in wanted:
        match = sorted(n for n in names if n == f"/{suffix}" or n.endswith(f"/{suffix}"))
        if match:
            out[suffix] = match[0]
    return out


def open_bag(bag_dir: Path) -> tuple[Path, dict[str, str], dict[str, int]]:
    """Check the bag is intact and holds the tip topic; returns (mcap path, topics, refused commands: messages on
    each ``<command topic>/rejected``, by command topic)."""
    bag_dir = Path(bag_dir)
    if not bag_dir.exists():
        raise RecordingError(f"{bag_dir}: no such bag directory")
    mcap_path = verify_bag(bag_dir).path
    return (mcap_path, *_checked_topics(bag_dir, summary_counts(mcap_path)))


def _checked_topics(bag_dir: Path, counts: dict[str, int]) -> tuple[dict[str, str], dict[str, int]]:
    """(topics, refused commands) of an intact bag's message counts; RecordingError for a bag with no messages or
    no tip topic."""
    topics = _topics(list(counts))
    if not any(counts.values()):
        from panel_rig.recording.recover import BROKEN_SUFFIX

        damaged = sorted(Path(bag_dir).glob(f"*.mcap{BROKEN_SUFFIX}*"))
        if damaged:  # recovered from a file cut short: 'the rig stopped' was not what happened
            raise RecordingError(f"{bag_dir} holds no messages: `bag recover` found none it could read in the "
                                 f"damaged original (kept as {damaged[0].name})")
        # a node stopped before its first step (a fast node waits for its first command)
        raise RecordingError(f"{bag_dir} holds no messages: the rig stopped before it ran a step")
    if "tip_displacement" not in topics:
        raise RecordingError(f"{bag_dir} has no tip_displacement topic: not a rig recording")
    refused = {n[: -len(REJECTED_SUFFIX)]: c for n, c in counts.items() if n.endswith(REJECTED_SUFFIX)}
    return topics, refused


class _Messages:
    """What :func:`load_series` takes of a bag's messages, in the file's order (sorted by time at the end: the
    reader's merge of the chunks into log-time order took a fifth of the time, and the rig writes in time order
    anyway): the readings in flat arrays (8 bytes a number: a list of tuples took ~60 bytes a number, and an hour at
    500 Hz is 1.8 million samples of each topic), the few others decoded."""

    def __init__(self, by_name: dict[str, str]) -> None:
        self.by_name = by_name  # full topic name -> kind (its suffix)
        self.tip, self.air, self.modal, self.control = _Series(), _Series(), _ModalRows(), _Series()
        self.events: list[tuple[int, str, Any]] = []  # (stamp_ns, kind, decoded message)
        self._fast = {"tip_displacement": (point_z, self.tip), "airspeed": (vector_x, self.air),
                      "modal_states": (joint_positions, self.modal), CONTROL_TOPIC: (wrench_force_z, self.control)}

    def take(self, message: tuple[str, str, int, bytes, Any]) -> None:
        topic, _, stamp_ns, data, decode = message
        kind = self.by_name[topic]
        if kind in self._fast:
            read, series = self._fast[kind]
            value = read(data)
            if value is None:  # not little-endian CDR: the general decoder
                msg = decode(data)
                value = (msg.point.z if kind == "tip_displacement" else msg.vector.x if kind == "airspeed"
                         else msg.wrench.force.z if kind == CONTROL_TOPIC else msg.position)
            series.append(stamp_ns, value)
        else:
            self.events.append((stamp_ns, kind, decode(data)))


def _wanted(topics: dict[str, str], shapes: bool) -> dict[str, str]:
    return {v: k for k, v in topics.items() if k != "panel_shape" or shapes}


def _read_messages(bag_dir: Path, shapes: bool) -> tuple[Path, dict[str, str], dict[str, int], _Messages]:
    """(mcap path, topics, refused commands, messages) of an intact rig bag, checked and read in one pass
    (:func:`~panel_rig.recording.reader.read_verified`) when its summary names the topics; else checked first, then
    read (a bag without a readable summary is refused by the check)."""
    if not bag_dir.exists():
        raise RecordingError(f"{bag_dir}: no such bag directory")
    mcap_path = find_mcap(bag_dir)
    try:
        counts = summary_counts(mcap_path)
    except Exception:  # noqa: BLE001 - a damaged summary: the check below says what is wrong
        counts = None
    if counts is not None:
        got = _Messages(_wanted(_topics(list(counts)), shapes))
        if read_verified(bag_dir, list(got.by_name), got.take):
            return (mcap_path, *_checked_topics(bag_dir, counts), got)
    mcap_path, topics, refused = open_bag(bag_dir)
    got = _Messages(_wanted(topics, shapes))
    for message in read_bag_raw(bag_dir, topics=list(got.by_name)):
        got.take(message)
    return mcap_path, topics, refused, got


#: stamps beyond this (about 11.6 days) are wall-clock (real-time mode); fast-mode bags carry simulated time from 0
WALL_CLOCK_NS = 10**15


def load_series(bag_dir: Path, shapes: bool = False) -> BagSeries:
    """Read tip, airspeed, modal states, commands (and panel shapes) from a rig bag.

    Tip w/L uses the panel length of the run's parameters, else `PanelConfig().panel_length_m`.
    Raises RecordingError (CorruptBagError for a damaged bag) with a one-line message.
    """
    bag_dir = Path(bag_dir)
    mcap_path, topics, refused, got = _read_messages(bag_dir, shapes)
    params = _parameters(bag_dir, mcap_path)
    length = params.get("panel.length_m")
    ok_length = isinstance(length, (int, float)) and not isinstance(length, bool) and length > 0
    tip, air, modal, events = got.tip, got.air, got.modal, got.events
    if len(tip) < 16:
        raise RecordingError(f"{bag_dir}: only {len(tip)} tip_displacement samples, too few to analyse")
    events.sort(key=lambda e: e[0])
    # a real-time run is stamped on the ROS clock: times from its first message (fast mode: simulated time from 0)
    first_ns = min(x for x in (tip.first_ns(), air.first_ns(), modal.first_ns(), events[0][0] if events else None)
                   if x is not None)
    t0_ns = first_ns if first_ns > WALL_CLOCK_NS else 0
    commands: dict[str, list[tuple[float, float]]] = {}
    shape_list: list[tuple[float, np.ndarray, np.ndarray]] = []
    aborts: list[tuple[float, str]] = []
    monitor_flutter: list[tuple[float, float]] = []
    for stamp_ns, kind, msg in events:
        t = (stamp_ns - t0_ns) * 1e-9
        if kind == "panel_shape":
            shape_list.append((t, np.array([p.x for p in msg.points]), np.array([p.z for p in msg.points])))
        elif kind == "diagnostics":
            _take_aborts(msg, aborts)
        elif kind == MONITOR_TOPIC:
            _take_monitor_flutter(msg, t, monitor_flutter)
        elif math.isfinite(msg.data):
            commands.setdefault(kind, []).append((t, float(msg.data)))
        else:  # a bag from before the /rejected topics: the rig refuses every non-finite command
            topic = topics[kind]
            refused[topic] = refused.get(topic, 0) + 1
    length_m = float(length) if ok_length else PanelConfig().panel_length_m
    t_s, tip_m = tip.sorted(t0_ns)
    air_t, air_u = air.sorted(t0_ns)
    modal_t, q = modal.sorted(t0_ns)
    control_t, control_f = got.control.sorted(t0_ns)
    if control_t.size:  # a controller's commands (the rig refuses a non-finite one)
        ok = np.isfinite(control_f)
        commands[CONTROL_TOPIC] = list(zip(control_t[ok].tolist(), control_f[ok].tolist()))
    return BagSeries(
        bag_dir=bag_dir, t_s=t_s, tip_w_over_L=tip_m / length_m, airspeed_mps=_interp(t_s, air_t, air_u),
        q=_modal_on(t_s, modal_t, q), force_npm=_hold(t_s, commands.get("shaker/force_cmd", [])),
        commands=commands, shapes=shape_list, panel_length_m=length_m,
        length_source="parameters" if ok_length else "default", parameters=params, refused_commands=refused,
        aborts=aborts, monitor_flutter=monitor_flutter,
    )


class _Stamped:
    """Readings with their stamps (ns) in flat arrays, taken in file order and put in time order once at the end."""

    def __init__(self) -> None:
        self.stamps_ns, self.values = array("q"), array("d")

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def first_ns(self) -> int | None:
        return min(self.stamps_ns) if self.stamps_ns else None

    def rows(self) -> np.ndarray:
        """The readings, one row (or value) per stamp, in file order."""
        raise NotImplementedError

    def sorted(self, t0_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(times s from ``t0_ns``, the readings), in time order (stable)."""
        stamps = np.frombuffer(self.stamps_ns, dtype=np.int64)
        order = np.argsort(stamps, kind="stable")
        return (stamps[order] - t0_ns) * 1e-9, self.rows()[order]


class _Series(_Stamped):
    """One scalar reading per message."""

    def append(self, stamp_ns: int, value: float) -> None:
        self.stamps_ns.append(stamp_ns)
        self.values.append(value)

    def rows(self) -> np.ndarray:
        return np.frombuffer(self.values, dtype=float)


def _take_aborts(msg: Any, aborts: list[tuple[float, str]]) -> None:
    """The abort a rig status on /diagnostics reports, appended when it is a new one (its time not yet seen)."""
    for status in msg.status:
        if status.name != RIG_STATUS_NAME:
            continue
        values = {kv.key: kv.value for kv in status.values}
        try:
            t_abort = float(values.get("last_abort_time_s") or "nan")
        except ValueError:
            continue
        if math.isfinite(t_abort) and all(t != t_abort for t, _ in aborts):
            aborts.append((t_abort, values.get("abort_reason", "")))


def _take_monitor_flutter(msg: Any, t_s: float, out: list[tuple[float, float]]) -> None:
    """A flutter-monitor result marked fluttered: (its sim_time_s, else the message time ``t_s``; airspeed m/s)."""
    for status in msg.status:
        values = {kv.key: kv.value for kv in status.values}
        if values.get("fluttered") != "true":
            continue
        try:
            u, t = float(values.get("airspeed_mps", "nan")), float(values.get("sim_time_s", "nan"))
        except ValueError:
            continue
        if math.isfinite(u):
            out.append((t if math.isfinite(t) else t_s, u))


class _ModalRows(_Stamped):
    """The modal_states positions, row after row, in one flat float array; rows of different lengths (not written
    by the rig) are cut to the shortest, padded with NaN while reading."""

    def __init__(self) -> None:
        super().__init__()
        self.width = -1  # the first row's length: the stride of ``values``
        self.shortest = -1

    def append(self, stamp_ns: int, position: Any) -> None:
        n = len(position)
        if not self.stamps_ns:
            self.width = self.shortest = n
        self.stamps_ns.append(stamp_ns)
        self.values.extend(list(position[: self.width]) + [math.nan] * (self.width - n))
        self.shortest = min(self.shortest, n)

    def rows(self) -> np.ndarray:
        """(rows, shortest row length)."""
        if not self.stamps_ns:
            return np.zeros((0, 0))
        return np.frombuffer(self.values, dtype=float).reshape(len(self.stamps_ns), self.width)[:, : self.shortest]


def _interp(t_s: np.ndarray, times_s: np.ndarray, values: np.ndarray) -> np.ndarray:
    if not times_s.size:
        return np.full(t_s.size, np.nan)
    return np.interp(t_s, times_s, values)


def _modal_on(t_s: np.ndarray, times_s: np.ndarray, q: np.ndarray) -> np.ndarray:
    if q.ndim < 2 or q.shape[1] == 0:
        return np.zeros((t_s.size, 0))
    return np.column_stack([np.interp(t_s, times_s, q[:, i]) for i in range(q.shape[1])])


def _hold(t_s: np.ndarray, events: list[tuple[float, float]]) -> np.ndarray:
    """Zero-order hold of (time, value) events on t_s; 0 before the first."""
    if not events:
        return np.zeros(t_s.size)
    times = np.array([e[0] for e in events])
    values = np.r_[0.0, [e[1] for e in events]]
    return values[np.searchsorted(times, t_s, side="right")]

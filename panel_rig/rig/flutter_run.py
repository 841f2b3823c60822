"""The flutter-test procedure (``panel_rig.analysis.flutter_test``) on an in-process Rig: no ROS, the same
turbulence, sensor and safety as the node's rig. Used by the unit tests and as the node-equivalent driver."""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Any, Callable, ContextManager, Sequence

import numpy as np

from panel_rig.analysis.flutter_test import (
    DEFAULT_SETTLE_S,
    FLUTTER_TIP_FRACTION,
    FLUTTER_WINDOW_S,
    MIN_DWELL_S,
    Decision,
    FlutterTestResult,
    FlutterTestSettings,
    FlutterWatch,
    TestPoint,
    bands_from_model,
    decide,
    flutter_level_m,
    flutter_report,
    identify_point,
    kept_minimum,
    resample_window,
    run_procedure,
)
from panel_rig.config import PanelConfig
from panel_rig.rig.rig import RUNNING, Rig, TunnelSettings, tunnel_extras
from panel_rig.rig.safety import SafetyLimits

#: a test point's run-in and dwell (simulated s): the bounds the CLI and the node's flutter_test.* parameters share
MAX_SETTLE_S = 1e4
MAX_DWELL_S = 1e5  # (MIN_DWELL_S: the replay's, analysis.flutter_test)
#: the most repeats of one airspeed a plan may ask for (flutter-test --repeats, the node's flutter_test.repeats)
MAX_REPEATS = 12


#: simulated seconds of readings marched and handed to the sinks at a time: a stop between two such blocks leaves
#: the recording with every reading the rig marched (the rig's time is the last reading's)
EMIT_BLOCK_S = 1.0


@dataclass(frozen=True)
class Dwell:
    """A completed dwell: its airspeed (m/s), the monitor's window of the measured tip (m), the sample interval (s),
    whether the plateau fluttered, and which plateau of the test it was (1: the first airspeed commanded)."""

    airspeed_mps: float
    window_m: np.ndarray
    dt_s: float
    fluttered: bool
    plateau: int = 0


class RigMeasure:
    """``measure(U)`` for :func:`run_procedure` on an in-process Rig: command U, march the run-in, then the dwell,
    sampled every ``steps_per_sample`` physics steps (block march). Returns the monitor's window of the measured tip.

    The run-in and the dwell are marched and handed to the rig's sinks in blocks of ``EMIT_BLOCK_S``, each inside
    ``atomic()`` (e.g. :func:`panel_rig.processes.signals_deferred`: a stop waits for the block's end). ``last``
    is the newest completed dwell, set with its last block: a test stopped after it but before its point was taken
    can still take it (as the live client takes the node's late result). A plateau that flutters (:class:`FlutterWatch`
    in a block, run-in included) is marched no further, as the node's monitor reports it at once and the client
    winds the tunnel off: ``flutter_time_s`` is the rig's time at the end of that block."""

    def __init__(self, rig: Rig, settings: FlutterTestSettings, steps_per_sample: int = 4,
                 atomic: Callable[[], ContextManager[Any]] = nullcontext) -> None:
        self.rig, self.settings, self.steps_per_sample, self.atomic = rig, settings, steps_per_sample, atomic
        self.dt_s = rig.dt_s * steps_per_sample
        self.per_block = max(1, int(round(EMIT_BLOCK_S / self.dt_s)))
        self.last: Dwell | None = None
        self._newest = np.zeros(0), np.zeros(0)  # the newest sample marched so far, (s, m) (none before the first)
        self._watch = FlutterWatch(rig.panel_length_m)
        self.flutter_time_s: float | None = None
        self.plateau_start_s = 0.0  # the rig's time at the newest airspeed command (s)
        self.plateaus = 0  # airspeeds commanded so far (a repeated airspeed counts again)

    def _march(self, n_samples: int, done: Callable[[np.ndarray, np.ndarray], None] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """March n samples in blocks, each handed to the sinks (bag, viewer) as the node publishes its blocks;
        ``done(times s, tips m)`` runs inside the last block's ``atomic()``. Returns (times s, tips m). Stops after a
        block that fluttered (``flutter_time_s`` set; ``done`` not called)."""
        times, tips = [np.zeros(0)], [np.zeros(0)]
        if n_samples <= 0 and done is not None:
            with self.atomic():
                done(times[0], tips[0])
        for start in range(0, n_samples, self.per_block):
            with self.atomic():
                blk = self.rig.advance_samples([self.steps_per_sample] * min(self.per_block, n_samples - start))
                self.rig.emit_block(blk)
                times.append(np.asarray(blk.time_s, dtype=float))
                tips.append(np.asarray(blk.tip_w_m, dtype=float))
                if self._watch.take(times[-1], tips[-1]) or self.rig.state != RUNNING:
                    self.flutter_time_s = self.rig.time_s
                    break
                if done is not None and start + self.per_block >= n_samples:
                    done(np.concatenate(times), np.concatenate(tips))
        return np.concatenate(times), np.concatenate(tips)

    def __call__(self, u: float) -> tuple[np.ndarray, float, None, bool]:
        result = self.rig.command_airspeed(u)
        if not result.accepted:  # not a flutter: the plan asked for what the rig does not allow
            raise ValueError(f"airspeed {u:g} m/s rejected by the rig: {result.reason}")
        self.flutter_time_s, self.plateau_start_s = None, self.rig.time_s
        self.plateaus += 1
        plateau = self.plateaus
        self._watch = FlutterWatch(self.rig.panel_length_m)  # the plateau's samples from the command on
        settle_t, settle = self._march(int(round(self.settings.settle_s / self.dt_s)))
        if self.flutter_time_s is not None:
            return settle, self.dt_s, None, True
        before_t, before = np.concatenate([self._newest[0], settle_t]), np.concatenate([self._newest[1], settle])
        start_s = self.plateau_start_s + self.settings.settle_s

        def dwell_done(dwell_t: np.ndarray, dwell: np.ndarray) -> None:
            # the monitor's window [command + settle, command + settle + dwell), cut as the node's monitor and the
            # bag's replay cut it (resample_window on the same samples: the one at the window's start, if marched)
            t_all, y_all = np.concatenate([before_t, dwell_t]), np.concatenate([before, dwell])
            self._newest = t_all[-1:], y_all[-1:]
            window, dt_s = resample_window(t_all, y_all, start_s, start_s + self.settings.dwell_s)
            self.last = Dwell(u, window, dt_s, self._watch.fluttered or self.rig.state != RUNNING, plateau)

        _, dwell = self._march(int(round(self.settings.dwell_s / self.dt_s)), dwell_done)
        if self.flutter_time_s is not None:
            return dwell, self.dt_s, None, True
        last = self.last
        return last.window_m, last.dt_s, None, last.fluttered


def take_late_point(res: FlutterTestResult, dwell: Dwell | None, bands: Callable[[float], list[tuple[float, float]]],
                    settings: FlutterTestSettings) -> bool:
    """The point of a dwell that completed before the test was stopped but was not taken yet (the stop came during
    its identification): identified and added to ``res``, as the live client adds the node's late result. True
    if a point was added."""
    # each plateau before the one under way gave a point (a flutter ends the test): the dwell's is taken when there
    # are as many points as plateaus (a repeated airspeed is a plateau of its own)
    if dwell is None or dwell.fluttered or dwell.airspeed_mps != res.max_airspeed_mps or (
            dwell.plateau <= len(res.points)):
        return False
    u = dwell.airspeed_mps
    res.points.append(identify_point(dwell.window_m, dwell.dt_s, u, bands(u), None, settings.ssi))
    return True


def default_plan(uf_model_mps: float, margin: float = 0.1, start_mps: float | None = None,
                 **changes) -> FlutterTestSettings:
    """Test plan from the pre-test model's U_f: start at half of it, steps of a tenth of it."""
    return FlutterTestSettings(start_mps=start_mps if start_mps is not None else 0.5 * uf_model_mps,
                               step_mps=0.1 * uf_model_mps, margin=margin, **changes)


def pretest_flutter_speed(model: Any) -> tuple[float, int]:
    """The model's linear U_f (m/s) and flutter mode (1-based) that a test's plan is made from. ValueError when the
    model does not flutter below 60 m/s, or when its first crossing opens only a window (the mode is stable again
    above it): the plan would start at half a window edge of 1 m/s, and with no structural damping at 0 m/s."""
    from panel_rig.analysis.vg import model_flutter_speed, stable_again_mps

    found = model_flutter_speed(model)
    if found is None:
        raise ValueError("the model does not flutter below 60 m/s: nothing to clear")
    uf, mode = found
    again = stable_again_mps(model, mode, uf)
    if again is not None:
        raise ValueError(
            f"the pre-test analysis finds mode {mode} unstable from {uf:.3f} m/s and stable again at {again:g} m/s: "
            "an unstable window of the aero ROM at low airspeed (least accurate there, where the reduced frequency "
            "is high), not a flutter boundary to clear; it opens when structure.damping_ratio is too low to cover "
            "the ROM's dip (`panel-rig flutter --vg 0.5:20:0.25` shows it)")
    return uf, mode


def pretest_plan(cfg: PanelConfig, variant: str = "full", margin: float = 0.1, start_mps: float | None = None,
                 dwell_s: float | None = None, settle_s: float | None = None, max_points: int | None = None,
                 repeats: int | None = None) -> tuple[Any, float, int, FlutterTestSettings]:
    """The pre-test analysis: a stepper of ``cfg``, the model's linear U_f (m/s) and flutter mode, and the plan
    from them (None: the plan's default). Raises ValueError when the model does not flutter."""
    from panel_rig.model.stepper import Stepper

    st = Stepper(cfg, variant=variant)
    uf, mode = pretest_flutter_speed(st.model)
    changes = {k: v for k, v in (("dwell_s", dwell_s), ("settle_s", settle_s), ("max_points", max_points),
                                 ("repeats", repeats)) if v is not None}
    return st, uf, mode, default_plan(uf, margin, start_mps, **changes)


def start_problem(settings: FlutterTestSettings, max_airspeed_mps: float) -> str | None:
    """Why the plan cannot start on a rig whose airspeed limit is ``max_airspeed_mps``: a first point above it
    (checked before anything is recorded; the rig would refuse the command). None when it can."""
    if settings.start_mps > max_airspeed_mps:
        return (f"--start-mps must be at most this test's airspeed limit, {max_airspeed_mps:g} m/s (the node's "
                f"limit or 1.2 x the model's U_f, the larger), got {settings.start_mps:.10g}")
    return None


def start_warning(start_mps: float | None, uf_mps: float, margin: float) -> str | None:
    """A warning when the asked first airspeed is already inside the margin of the pre-test analysis's flutter
    speed (the procedure itself never goes there: it stops when a point is that close)."""
    edge = (1.0 - margin) * uf_mps
    if start_mps is None or start_mps < edge:
        return None
    return (f"warning: --start-mps {start_mps:g} m/s is at or above (1 - margin) x the pre-test analysis's flutter "
            f"speed ({1.0 - margin:g} x {uf_mps:.3f} = {edge:.3f} m/s): the first point may flutter")


#: the tip sensor's noise (fraction of the flutter monitor's RMS level) from which noise alone reads as flutter:
#: 200 s dwells of white noise read so 1 in 10 at 0.79 and all at 0.84
NOISE_AS_FLUTTER = 0.8


def noise_problem(tip_noise_m: float, panel_length_m: float) -> str | None:
    """Why a flutter test cannot run with this tip sensor: its noise alone reads as flutter (a test with 4 mm of
    noise stopped 0.4 s after its first command, "fluttered at 5.24 m/s", the tunnel still at ~2 m/s)."""
    level_m = flutter_level_m(panel_length_m)
    if tip_noise_m < NOISE_AS_FLUTTER * level_m:
        return None
    return (f"sensor.tip_noise_m {tip_noise_m:g} m: noise from about {NOISE_AS_FLUTTER * level_m * 1e3:.1f} mm reads "
            f"as flutter (the flutter monitor's level, an RMS of {level_m * 1e3:.2f} mm over {FLUTTER_WINDOW_S:g} s): "
            "a flutter test needs a quieter tip sensor")


def noise_warning(tip_noise_m: float, panel_length_m: float) -> str | None:
    """A warning when the tip sensor's noise is over half the flutter monitor's level (:class:`FlutterWatch`), short
    of :func:`noise_problem`'s."""
    level_m = flutter_level_m(panel_length_m)
    if tip_noise_m <= 0.5 * level_m:
        return None
    return (f"warning: sensor.tip_noise_m {tip_noise_m:g} m is over half the flutter monitor's level (an RMS of "
            f"{level_m * 1e3:.2f} mm over {FLUTTER_WINDOW_S:g} s, a sine of {FLUTTER_TIP_FRACTION:g} L); noise from "
            f"about {NOISE_AS_FLUTTER * level_m * 1e3:.1f} mm reads as flutter")


def start_warnings(cfg: PanelConfig, start_mps: float | None, uf_mps: float, margin: float) -> list[str]:
    """The warnings a test prints before it starts (:func:`start_warning`, :func:`noise_warning`)."""
    found = (start_warning(start_mps, uf_mps, margin), noise_warning(cfg.sensor_tip_noise_m, cfg.panel_length_m))
    return [w for w in found if w is not None]


def max_test_airspeed_mps(uf_mps: float) -> float:
    """A flutter test's airspeed limit (m/s): the node's default ``safety.max_airspeed_mps``, raised to 1.2 U_f (the
    tunnel's limit must not stop the approach of a stiffer panel's boundary)."""
    return float(max(SafetyLimits().max_airspeed_mps, 1.2 * uf_mps))


def node_equivalent_rig(cfg: PanelConfig, stepper: Any, uf_mps: float, sinks: Sequence[Any] = ()) -> Rig:
    """The rig a flutter test's node runs, in-process: ``cfg``'s turbulence, sensor and tip limit, the tunnel's
    airspeed lag and the node's other defaults (wall clearance, shaker limits), the test's airspeed limit."""
    limits = SafetyLimits(max_airspeed_mps=max_test_airspeed_mps(uf_mps), max_tip_w_over_L=cfg.max_tip_w_over_L)
    return Rig(stepper, cfg.panel_length_m, limits=limits, tunnel=TunnelSettings(), sinks=list(sinks),
               **tunnel_extras(cfg, stepper))


def run_on_rig(cfg: PanelConfig, variant: str = "full", settings: FlutterTestSettings | None = None,
               margin: float = 0.1, start_mps: float | None = None,
               on_point: Callable[[TestPoint, Decision], None] | None = None, **plan: Any
               ) -> tuple[FlutterTestResult, float]:
    """The whole procedure on a fresh in-process Rig of ``cfg``; returns (result, the model's linear U_f).
    ``plan``: changes to the default plan's other settings (e.g. ``repeats=0``)."""
    from panel_rig.model.stepper import Stepper

    st = Stepper(cfg, variant=variant)
    uf, mode = pretest_flutter_speed(st.model)
    settings = settings or default_plan(uf, margin, start_mps, **plan)
    rig = node_equivalent_rig(cfg, st, uf)
    return run_procedure(RigMeasure(rig, settings), bands_from_model(st.model, mode), settings, on_point), uf


class FlutterMonitorSink:
    """Live flutter monitor as a Rig sink (the node adds it with ``flutter_monitor:=true``): the test engineer's
    per-point work on the full-rate measured tip, in simulated time. From an accepted ``airspeed_cmd`` at t_c it
    drops the run-in [t_c, t_c + ``settle_s``), keeps the dwell [t_c + settle_s, t_c + settle_s + ``dwell_s``),
    and as soon as the dwell is complete (or, if the next command comes first, at that command when at least
    ``min_dwell_s`` was kept) identifies it (``identify_point``, bands from the model), updates the predictors
    (``decide``) and calls ``publish(time_s, point, decision, fluttered=False)``. If the measured tip fluttered
    (:class:`FlutterWatch`) or the rig aborts during the plateau (run-in included), it publishes at once with
    ``fluttered=True`` (point without modes). ``waiting`` is true before the first command and from a published
    result to the next command (the node's fast-mode hold uses it: a run is then reproducible from its seed).
    Plateaus at U <= 0 and descents are not test points. The identification runs in the caller's thread (seconds
    per point: meant for fast mode, where simulated time waits for it)."""

    def __init__(self, cfg: PanelConfig, model, publish: Callable[..., None], margin: float = 0.1,
                 settle_s: float = DEFAULT_SETTLE_S, min_dwell_s: float = MIN_DWELL_S, dwell_s: float = 200.0,
                 repeats: int = FlutterTestSettings.repeats) -> None:
        from panel_rig.analysis.vg import model_flutter_speed

        found = model_flutter_speed(model)
        self.enabled = found is not None
        self.uf_model, self.mode = found if found is not None else (float("nan"), 2)
        self.bands = bands_from_model(model, self.mode)
        self.settings = FlutterTestSettings(start_mps=0.0, step_mps=0.1 * self.uf_model, margin=margin,
                                            settle_s=settle_s, dwell_s=dwell_s, repeats=repeats)
        self.publish, self.settle_s, self.min_dwell_s, self.dwell_s = publish, settle_s, min_dwell_s, dwell_s
        self.panel_length_m = cfg.panel_length_m
        self._watch = FlutterWatch(cfg.panel_length_m)  # the plateau in progress's (from each command)
        self.points: list[TestPoint] = []
        self.published = 0  # results published (points and flutter reports)
        self.waiting = True  # for the first command (a node holding for its client starts the clock with it)
        self.last_wall_s = 0.0
        self.plateau_start_s = 0.0
        self._u: float | None = None
        self._t: list[np.ndarray] = []
        self._y: list[np.ndarray] = []
        self._newest = np.zeros(0), np.zeros(0)  # the newest sample seen, (s, m): a window may start at it

    @property
    def window_s(self) -> tuple[float, float]:
        """The dwell of the plateau in progress, simulated seconds."""
        t0 = self.plateau_start_s + self.settle_s
        return t0, t0 + self.dwell_s

    def on_reading(self, reading) -> None:
        self._take(np.array([reading.time_s]), np.array([reading.tip_w_m]), reading.state)

    def on_block(self, block) -> None:
        self._take(block.time_s, block.tip_w_m, block.state)

    def _take(self, t: np.ndarray, y: np.ndarray, state: str = RUNNING) -> None:
        t, y = np.asarray(t, float), np.asarray(y, float)
        self._newest = t[-1:], y[-1:]
        if self._u is None or self._u <= 0 or self.waiting:
            return
        if self._watch.take(t, y) or state != RUNNING:
            self._report_flutter(float(t[-1]))
            return
        self._keep(t, y)
        if t[-1] >= self.window_s[1]:
            self.finish(float(t[-1]))

    def _keep(self, t: np.ndarray, y: np.ndarray) -> None:
        """Keep the samples inside the dwell window (the recording holds them all: the replay cuts the same)."""
        lo, hi = self.window_s
        keep = (t >= lo) & (t < hi)
        if np.any(keep):
            self._t.append(t[keep])
            self._y.append(y[keep])

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        if name != "airspeed_cmd" or not accepted or not self.enabled:
            return
        if not self.waiting:
            self.finish(time_s)
        self._u, self.plateau_start_s, self._t, self._y = float(value), float(time_s), [], []
        self._watch = FlutterWatch(self.panel_length_m)
        self.waiting = False
        self._keep(*self._newest)  # with no run-in the window starts at the sample taken at the command

    def _report_flutter(self, time_s: float) -> None:
        self._t, self._y = [], []
        pt, d = flutter_report(self._u, self.points, self.settings)
        self.waiting = True
        self.published += 1
        self.publish(time_s, pt, d, fluttered=True)

    def finish(self, time_s: float) -> None:
        """Identify the plateau in progress (if at least ``min_dwell_s`` was kept) and publish."""
        if self._u is None or self._u <= 0 or not self._t:
            return
        t, y = np.concatenate(self._t), np.concatenate(self._y)
        self._t, self._y = [], []
        lo, hi = self.window_s
        end_s = min(hi, time_s)
        # the window's length in time, as the replay measures it (kept_minimum): a count of samples misses the one
        # at the window's start when none was taken there (no run-in from t = 0), and a complete 20 s dwell was
        # then never identified: the test hung
        if not kept_minimum(lo, end_s, self.min_dwell_s):
            return
        if self.points and self._u < self.points[-1].airspeed_mps:
            return  # the monitor follows the ascent only (the same airspeed again is a repeated point)
        w0 = time.monotonic()
        yy, dt = resample_window(t, y, lo, end_s)
        pt = identify_point(yy, dt, self._u, self.bands(self._u), ssi=self.settings.ssi)
        self.points.append(pt)
        d = decide(self.points, self.settings)
        self.last_wall_s = time.monotonic() - w0  # identification + prediction, wall s (profiling)
        self.waiting = True
        self.published += 1
        self.publish(time_s, pt, d, fluttered=False)

    def close(self) -> None:
        pass

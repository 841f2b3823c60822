"""The flutter-test procedure as a pure core: test points in, identification, prediction and the next airspeed out.

No ROS, no files, no clock. A driver (the ``panel-rig flutter-test`` command over the live node, a unit test over
the Rig, a bag replay) feeds it one airspeed plateau at a time: the measured tip samples of the dwell (the run-in
after the airspeed change already dropped), their sample interval, the plateau's airspeed, and the shaker force
if there was one. For each plateau the core

1. identifies frequency and damping (with a 95 % interval) of the first mode and of the flutter mode: output-only
   SSI-cov (``identification.identify_ssi``) on a turbulence response, free decay (``identify_free_decay``) on
   the samples after a shaker tap when the force shows one;
2. updates both boundary predictors from the subcritical points so far (``flutter_margin``): the damping trend
   of the flutter mode (quadratic in dynamic pressure, >= 3 airspeeds) and the Zimmerman–Weissenburger margin of
   the two modes (linear in dynamic pressure, >= 3 airspeeds), each with its bootstrap interval;
3. decides: stop when the flutter mode was not identified at the current point (no damping to clear the next one
   on: a quiet tunnel climbed blind to 1.6 U_f), when its identified damping is below ``min_damping``, or when the
   predicted speed margin 1 - U/U_f is below ``margin``; otherwise step up by ``step_mps``, but never to more than (1 - margin) x the
   predicted U_f (the lower of the two predictors, i.e. the conservative one), and stop when that cap leaves
   less than ``min_step_mps`` to go. Before either margin stop, a prediction whose interval is open or wide
   (``uncertain``) takes the same airspeed again, up to ``repeats`` times: one more record where the test has
   already been, never a step up.

Frequency bands. The identification needs a band per mode; they come from the pre-test model analysis (the
model's V-g at the plateau's airspeed, ``bands_from_model``), as a real test team's test plan gives them. Only the
bands come from the model: frequencies and damping are identified from the measured tip alone.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from panel_rig.analysis.flutter_margin import (
    BoundaryPrediction,
    flutter_margins,
    predict_by_damping_trend,
    predict_by_flutter_margin,
)
from panel_rig.analysis.identification import (
    ModalEstimate,
    SSISettings,
    identify_free_decay,
    identify_ssi,
)

#: bands around the model's frequency of the first (heavily damped) mode and of the flutter mode
FIRST_BAND = (0.6, 1.5)
FLUTTER_BAND = (0.85, 1.15)
#: SSI rate for the first mode (heavily damped: its covariance dies fast, see identify_ssi)
FIRST_MODE_RATE_FACTOR = 50.0


#: a test point's default run-in after its airspeed step (simulated s): the node's flutter_test.settle_s, --settle
DEFAULT_SETTLE_S = 5.0


@dataclass(frozen=True)
class FlutterTestSettings:
    """The test plan. ``start_mps`` and ``step_mps``: the first airspeed and the largest step; ``dwell_s`` of
    measured response per point after ``settle_s`` of run-in; ``margin``: the required speed margin M."""

    start_mps: float
    step_mps: float
    margin: float = 0.1
    #: stop when the flutter mode's identified damping ratio falls below this
    min_damping: float = 0.002
    min_step_mps: float = 0.05
    dwell_s: float = 200.0
    settle_s: float = DEFAULT_SETTLE_S
    max_points: int = 12
    #: before a margin stop on an uncertain prediction (its 95 % interval open, or wider than ``wide_ci`` x the
    #: predicted speed) take the current airspeed again, up to this many times: a repeat costs a dwell, never margin
    repeats: int = 1
    wide_ci: float = 0.2
    n_boot: int = 400
    ssi: SSISettings = SSISettings()


@dataclass(frozen=True)
class TestPoint:
    """One plateau: its airspeed and the identified first and flutter modes (None: not identified)."""

    __test__ = False  # not a pytest class

    airspeed_mps: float
    first: ModalEstimate | None
    flutter: ModalEstimate | None
    method: str

    def as_dict(self) -> dict:
        e = self.flutter
        return {"airspeed_mps": self.airspeed_mps,
                "frequency_hz": None if e is None else e.frequency_hz,
                "damping_ratio": None if e is None else e.damping_ratio,
                "damping_ci": None if e is None else list(e.damping_ci()),
                "frequency_ci_hz": None if e is None else list(e.frequency_ci_hz()),
                "first_mode": None if self.first is None else self.first.as_dict(),
                "method": self.method}


#: how the reason of a stop on a point without a flutter-mode estimate begins (the command then exits 1)
NOT_IDENTIFIED = "flutter mode not identified"


@dataclass(frozen=True)
class Decision:
    """What the procedure does next: ``next_airspeed_mps`` (None: stop) and why."""

    next_airspeed_mps: float | None
    reason: str
    trend: BoundaryPrediction | None
    zw: BoundaryPrediction | None
    prediction: BoundaryPrediction | None  # the one the decision used (the lower speed)

    @property
    def stop(self) -> bool:
        return self.next_airspeed_mps is None

    @property
    def unidentified(self) -> bool:
        """A stop because the current point gave no flutter-mode estimate: the test ended without clearing it."""
        return self.stop and self.reason.startswith(NOT_IDENTIFIED)

    def margin(self, airspeed_mps: float) -> float:
        return self.prediction.margin(airspeed_mps) if self.prediction is not None else 1.0


def tap_start(force_npm: np.ndarray | None, threshold: float = 1e-9) -> int | None:
    """Index of the first sample after the last non-zero shaker force (the free decay's start), None if no tap."""
    if force_npm is None:
        return None
    on = np.flatnonzero(np.abs(np.asarray(force_npm, float)) > threshold)
    return None if on.size == 0 else int(on[-1]) + 1


def identify_point(tip_m: np.ndarray, dt_s: float, airspeed_mps: float, bands: Sequence[tuple[float, float]],
                   force_npm: np.ndarray | None = None, ssi: SSISettings = SSISettings(),
                   min_free_decay_s: float = 2.0) -> TestPoint:
    """Identify the first mode (bands[0]) and the flutter mode (bands[1]) of one plateau: free decay after a tap
    when the force shows one with at least ``min_free_decay_s`` after it, SSI-cov on the whole record otherwise."""
    tip = np.asarray(tip_m, float)
    k = tap_start(force_npm)
    if k is not None and (tip.size - k) * dt_s >= min_free_decay_s:
        first, flut = identify_free_decay(tip[k:], dt_s, bands)
        return TestPoint(float(airspeed_mps), first, flut, "free-decay")
    first = identify_ssi(tip, dt_s, [bands[0]], ssi, max_rate_hz=FIRST_MODE_RATE_FACTOR * np.mean(bands[0]))[0]
    flut = identify_ssi(tip, dt_s, [bands[1]], ssi)[0]
    return TestPoint(float(airspeed_mps), first, flut, "ssi-cov")


def predict(points: Sequence[TestPoint], n_boot: int = 400, seed: int = 0
            ) -> tuple[BoundaryPrediction | None, BoundaryPrediction | None]:
    """Damping-trend (>= 3 airspeeds with the flutter mode) and ZW (>= 3 airspeeds with both modes) predictions."""
    fl = [p for p in points if p.flutter is not None]
    with np.errstate(invalid="ignore"):  # percentiles of bootstrap draws with no crossing (inf)
        return _predict(fl, n_boot, seed)


#: airspeeds a predictor needs: the trend's quadratic 3; the ZW line 3 too (a line through two points has no
#: residual to show their noise; one test stopped at 0.6 U_f, 34 % short, on a ZW line through a first mode
#: identified at 0.057 +- 0.25, the model's ~0.3. Over 32 seeds the tests that stopped more than 5 % short went
#: from 9 to 5 with 3 airspeeds, and to 2 with the repeat as well: docs/validation.md section 10)
MIN_TREND_AIRSPEEDS = 3
MIN_ZW_AIRSPEEDS = 3


def _predict(fl: list[TestPoint], n_boot: int, seed: int
             ) -> tuple[BoundaryPrediction | None, BoundaryPrediction | None]:
    trend = zw = None
    if _distinct(fl) >= MIN_TREND_AIRSPEEDS:  # a repeated airspeed adds a sample, not a point of the fit's curve
        trend = predict_by_damping_trend([p.airspeed_mps for p in fl], [p.flutter for p in fl], n_boot=n_boot,
                                         rng=np.random.default_rng(seed))
    both = _both_modes(fl)
    if _distinct(both) >= MIN_ZW_AIRSPEEDS:
        zw = predict_by_flutter_margin([p.airspeed_mps for p in both], [p.first for p in both],
                                       [p.flutter for p in both], n_boot=n_boot, rng=np.random.default_rng(seed))
    return trend, zw


def _distinct(points: Sequence[TestPoint]) -> int:
    """How many different airspeeds the points were taken at."""
    return len({p.airspeed_mps for p in points})


def decide(points: Sequence[TestPoint], settings: FlutterTestSettings) -> Decision:
    """The next airspeed after the points so far (the last one is the current plateau)."""
    trend, zw = predict(points, settings.n_boot)
    finite = [p for p in (trend, zw) if p is not None and np.isfinite(p.speed_mps)]
    pred = min(finite, key=lambda p: p.speed_mps) if finite else None
    u = points[-1].airspeed_mps
    last = points[-1].flutter
    if last is None:  # nothing says this airspeed is stable: no step from it
        return Decision(None, f"{NOT_IDENTIFIED} at {u:.3f} m/s: no damping to clear the next point on; excite it "
                              "more (the tunnel's turbulence, tunnel.turbulence.intensity), dwell longer, or lower the "
                              "sensor's noise (sensor.tip_noise_m) if it hides the response", trend, zw, pred)
    if last.damping_ratio < settings.min_damping:
        return Decision(None, f"flutter-mode damping {last.damping_ratio:.4f} < {settings.min_damping}", trend, zw,
                        pred)
    if pred is not None and pred.margin(u) < settings.margin:
        return _stop_or_repeat(points, settings, f"predicted margin {pred.margin(u):.3f} < {settings.margin}",
                               trend, zw, pred)
    if len(points) >= settings.max_points:
        n = settings.max_points
        return Decision(None, f"{n} test point{'s' if n != 1 else ''} done", trend, zw, pred)
    nxt = u + settings.step_mps
    reason = "step"
    if pred is not None:
        cap = (1.0 - settings.margin) * pred.speed_mps
        if nxt > cap:
            nxt, reason = cap, f"capped at (1 - M) x predicted U_f = {cap:.3f} m/s"
    if nxt - u < settings.min_step_mps:
        return _stop_or_repeat(points, settings, f"next point within {settings.min_step_mps} m/s of the cap: "
                                                 f"cleared to {u:.3f} m/s", trend, zw, pred)
    return Decision(float(nxt), reason, trend, zw, pred)


#: how the reason of a decision to take the current airspeed again begins
REPEAT = "repeat"


def uncertain(pred: BoundaryPrediction, wide_ci: float) -> bool:
    """The prediction's 95 % interval is open or wider than ``wide_ci`` x its predicted speed."""
    lo, hi = pred.ci_mps
    return not (np.isfinite(lo) and np.isfinite(hi)) or hi - lo > wide_ci * pred.speed_mps


def repeats_at(points: Sequence[TestPoint], airspeed_mps: float) -> int:
    """How many of the points right before the last one were taken at ``airspeed_mps`` too (0: none)."""
    n = 0
    for p in reversed(points[:-1]):
        if p.airspeed_mps != airspeed_mps:
            break
        n += 1
    return n


def _stop_or_repeat(points: Sequence[TestPoint], settings: FlutterTestSettings, why: str,
                    trend: BoundaryPrediction | None, zw: BoundaryPrediction | None,
                    pred: BoundaryPrediction | None) -> Decision:
    """A stop for the margin (``why``), or, when the prediction behind it is uncertain and the airspeed was taken
    again fewer than ``settings.repeats`` times, the same airspeed once more: a test that stopped at 0.6 U_f on
    two points and a wide interval (the low tail over seeds, docs/validation.md section 10) gets another record at
    an airspeed already cleared, and the predictors get a less noisy point."""
    u = points[-1].airspeed_mps
    if (pred is not None and uncertain(pred, settings.wide_ci) and repeats_at(points, u) < settings.repeats
            and len(points) < settings.max_points):
        lo, hi = pred.ci_mps
        ci = f"[{lo:.2f}, {'open' if not np.isfinite(hi) else f'{hi:.2f}'}]"
        return Decision(float(u), f"{REPEAT} the point: {why} on an uncertain prediction, {pred.speed_mps:.2f} m/s "
                                  f"(95 % interval {ci})", trend, zw, pred)
    return Decision(None, why, trend, zw, pred)


def _both_modes(points: Sequence[TestPoint]) -> list[TestPoint]:
    """The points with both modes identified: those the ZW predictor fits. A first mode identified with damping <= 0
    is left out: below the flutter speed it is the heavily damped mode (zeta ~0.2-0.6), and such an estimate is a
    failed identification (at 1 % turbulence one read -0.017 [-1.23, 1.20] and made the point's ZW margin F
    -1.5e6, "fluttering", beside a flutter mode at zeta 0.003)."""
    return [p for p in points if p.first is not None and p.first.damping_ratio > 0 and p.flutter is not None]


def _extrapolation(u: np.ndarray, y: np.ndarray, degree: int, speed_mps: float, n: int
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares polynomial of y in U^2 from the first point to ``speed_mps`` (10 % past the last point
    when it is not finite; never past 1.5 x the last point)."""
    c = np.polyfit(u**2, y, degree)
    end = speed_mps if np.isfinite(speed_mps) else 1.1 * u.max()
    uu = np.linspace(u.min(), max(u.max(), min(end, 1.5 * u.max())), n)
    return uu, np.polyval(c, uu**2)


def trend_curve(points: Sequence[TestPoint], decision: Decision | None, n: int = 50
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """The damping-trend extrapolation as (airspeeds, damping ratios), from the first point to the predicted U_f
    (or 10 % past the last point if it does not cross); None before three identified points."""
    fl = [p for p in points if p.flutter is not None]
    if len(fl) < 3 or decision is None or decision.trend is None:
        return None
    u = np.array([p.airspeed_mps for p in fl])
    z = np.array([p.flutter.damping_ratio for p in fl])
    return _extrapolation(u, z, decision.trend.degree, decision.trend.speed_mps, n)


def margin_points(points: Sequence[TestPoint]) -> tuple[np.ndarray, np.ndarray]:
    """(airspeeds, ZW flutter margins F in (rad/s)^4) of the points with both modes identified."""
    both = _both_modes(points)
    return (np.array([p.airspeed_mps for p in both]),
            flutter_margins([p.first for p in both], [p.flutter for p in both]))


def margin_curve(points: Sequence[TestPoint], decision: Decision | None, n: int = 50
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """The ZW flutter-margin extrapolation as (airspeeds, F), from the first point to its predicted U_f (or 10 %
    past the last point if it does not cross); None when the decision holds no ZW prediction."""
    if decision is None or decision.zw is None:
        return None
    u, f = margin_points(points)
    return _extrapolation(u, f, decision.zw.degree, decision.zw.speed_mps, n)


#: why a payload has no predicted U_f (the predictors' minimum points, see :func:`_predict`)
NO_PREDICTION = ("no predicted U_f from these points (the ZW margin needs 3 airspeeds with both modes, the trend 3, "
                 "and a crossing)")


def prediction_text(speed_mps: float | None, ci_mps: Sequence[float | None] | None, method: str | None,
                    digits: int = 3) -> str:
    """A payload's predicted U_f as text: the speed (m/s), its 95 % interval (an open bound as ``open``) and the
    predictor; NO_PREDICTION when there is none."""
    if speed_mps is None:
        return NO_PREDICTION

    def bound(x: float | None) -> str:
        return "open" if x is None else f"{x:.{digits}f}"

    interval = "" if ci_mps is None else f" (95 % {bound(ci_mps[0])} .. {bound(ci_mps[1])})"
    return f"predicted U_f {speed_mps:.{digits}f} m/s{interval} [{method}]"


def bands_from_model(model, flutter_mode: int) -> Callable[[float], list[tuple[float, float]]]:
    """Per airspeed: the identification bands around the model's first mode and flutter mode (pre-test V-g)."""
    from panel_rig.analysis.vg import vg_diagram

    def bands(airspeed_mps: float) -> list[tuple[float, float]]:
        f = vg_diagram(model, np.array([airspeed_mps])).frequency_hz[0]
        f1, ff = f[0], f[flutter_mode - 1]
        return [(FIRST_BAND[0] * f1, FIRST_BAND[1] * f1), (FLUTTER_BAND[0] * ff, FLUTTER_BAND[1] * ff)]

    return bands


@dataclass
class FlutterTestResult:
    """The whole test: the points, the last decision, the highest airspeed commanded, whether it fluttered, and
    what stopped it (``interrupted``: a signal, ``"SIGINT"``, or a failure, ``"a failed recording"``; None: the
    procedure ended on its own)."""

    points: list[TestPoint] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)
    max_airspeed_mps: float = 0.0
    fluttered: bool = False
    bag: str | None = None
    interrupted: str | None = None

    @property
    def final(self) -> Decision | None:
        return self.decisions[-1] if self.decisions else None

    def as_dict(self) -> dict:
        d = self.final
        pred = d.prediction if d is not None else None
        pd = None if pred is None else pred.as_dict()  # open (infinite) bounds as null
        out = {"test_points": [p.as_dict() for p in self.points],
               "predicted_flutter_speed_mps": None if pd is None else pd["predicted_flutter_speed_mps"],
               "predicted_flutter_speed_ci_mps": None if pd is None else pd["predicted_flutter_speed_ci_mps"],
               "prediction_method": None if pred is None else pred.method,
               # 1 - U/U_f at the last point, as the monitor's `margin` (the required one is the caller's)
               "margin": None if pred is None or not self.points else pred.margin(self.points[-1].airspeed_mps),
               "max_airspeed_mps": self.max_airspeed_mps,
               "fluttered": bool(self.fluttered),
               "interrupted": self.interrupted is not None,
               "stop_reason": self.stop_reason(),
               "bag": self.bag}
        for name, p in (("damping_trend", d.trend if d else None), ("zimmerman_weissenburger", d.zw if d else None)):
            out[name] = None if p is None else p.as_dict()
        return out

    def stop_reason(self) -> str | None:
        """Why the test ended (flutter, the decision's stop, or the signal that interrupted it); None if it has not."""
        d = self.final
        if self.interrupted is None and self.fluttered:  # as the node's monitor says it (a first point that
            return fluttered_reason(self.max_airspeed_mps)  # fluttered gave no reason; a later one the last go-on)
        if self.interrupted is None:
            return None if d is None else d.reason
        done = "" if d is None or not d.stop else f"; the procedure had stopped: {d.reason}"
        return f"interrupted by {self.interrupted} after {len(self.points)} test point(s){done}"


def figure_title(res: FlutterTestResult, cfg: Any, variant: str, dwell_s: float, how: str) -> str:
    """The V-g figure's title: what was tested (variant, tunnel turbulence and seed, dwell; ``how``: live node or
    in-process) and how it ended, so a figure of a test cut short does not read as a finished one."""
    tunnel = (f"turbulence {100 * cfg.turbulence_intensity:g} % (seed {cfg.turbulence_seed})"
              if cfg.turbulence_intensity > 0 else "no turbulence")
    ending = f"{len(res.points)} point(s); stop: {res.stop_reason() or 'none'}"
    # a long stop reason in lines the figure's width holds (one line of 200 characters was cut off at both edges)
    return (f"flutter test ({how}): variant {variant}, {tunnel}, dwell {dwell_s:g} s\n"
            + textwrap.fill(ending, TITLE_WIDTH_CHARS, break_on_hyphens=False))


#: characters per line of a figure title (9 pt, the V-g figure's 8 in width)
TITLE_WIDTH_CHARS = 100


def fluttered_reason(airspeed_mps: float) -> str:
    """Why a test stopped on flutter (the node's monitor publishes the same text)."""
    return f"fluttered at {airspeed_mps:.3f} m/s"


def flutter_report(airspeed_mps: float, points: Sequence[TestPoint], settings: FlutterTestSettings
                   ) -> tuple[TestPoint, Decision]:
    """The result of a plateau that fluttered, as the monitor publishes it: a point without modes (method
    "fluttered") and a stop whose reason says where, carrying the predictors of the points before it."""
    last = decide(points, settings) if points else None
    return (TestPoint(float(airspeed_mps), None, None, "fluttered"),
            Decision(None, fluttered_reason(airspeed_mps), last.trend if last else None, last.zw if last else None,
                     last.prediction if last else None))


def interrupted_result(res: FlutterTestResult, settings: FlutterTestSettings, cause: str
                       ) -> FlutterTestResult:
    """``res`` of a test stopped by ``cause`` part-way (a signal's name, "SIGINT", or a failure: "a failed
    recording"): the points identified so far with the decision (and so the prediction, if they give one) after
    the last of them, taken here when the stop came before it was."""
    if len(res.decisions) < len(res.points):
        res.decisions.append(decide(res.points, settings))
    res.interrupted = cause
    return res


def run_points(next_point: Callable[[float], tuple[TestPoint | None, bool]], settings: FlutterTestSettings,
               on_point: Callable[[TestPoint, Decision], None] | None = None,
               res: FlutterTestResult | None = None,
               on_flutter: Callable[[float], None] | None = None) -> FlutterTestResult:
    """The procedure's loop: ``next_point(U)`` sets the airspeed, dwells and returns (the identified test point,
    fluttered); a decision after each point (``on_point``); stops on the decision or on flutter (``on_flutter(U)``).
    The identification happens wherever ``next_point`` gets it from (here for :func:`run_procedure`, in the rig
    node for the live test). ``res``: the caller's result to fill (a test stopped part-way leaves the points so far
    in it)."""
    res = FlutterTestResult() if res is None else res
    u: float | None = settings.start_mps
    while u is not None:
        res.max_airspeed_mps = max(res.max_airspeed_mps, u)  # commanded: also when the point is cut short
        pt, fluttered = next_point(u)
        if fluttered or pt is None:
            res.fluttered = res.fluttered or fluttered
            if fluttered and on_flutter is not None:
                on_flutter(u)
            break
        res.points.append(pt)
        d = decide(res.points, settings)
        res.decisions.append(d)
        if on_point is not None:
            on_point(pt, d)
        u = d.next_airspeed_mps
    return res


def run_procedure(measure: Callable[[float], tuple[np.ndarray, float, np.ndarray | None, bool]],
                  bands: Callable[[float], list[tuple[float, float]]], settings: FlutterTestSettings,
                  on_point: Callable[[TestPoint, Decision], None] | None = None,
                  res: FlutterTestResult | None = None,
                  on_flutter: Callable[[float], None] | None = None) -> FlutterTestResult:
    """Drive a test: ``measure(U)`` sets the airspeed, dwells and returns (measured tip, dt, shaker force or None,
    fluttered); identification here and decision after each point; stops on the decision or on flutter. ``res``,
    ``on_flutter``: as for :func:`run_points`."""

    def next_point(u: float) -> tuple[TestPoint | None, bool]:
        tip, dt, force, fluttered = measure(u)
        if fluttered:
            return None, True
        return identify_point(tip, dt, u, bands(u), force, settings.ssi), False

    return run_points(next_point, settings, on_point, res, on_flutter)


def resample_window(t_s: np.ndarray, y: np.ndarray, t_from_s: float, t_to_s: float
                    ) -> tuple[np.ndarray, float]:
    """The samples of [t_from_s, t_to_s) linearly interpolated on a regular grid from ``t_from_s`` at the median
    sample interval of the window (the node publishes at a rate that is not a whole number of physics steps, so
    its sample intervals alternate). The live monitor and the bag replay both cut plateaus with this, so they
    identify on the same samples. Returns (samples, interval s); empty when the window holds < 2 samples."""
    t, y = np.asarray(t_s, float), np.asarray(y, float)
    inside = (t >= t_from_s) & (t < t_to_s)
    if np.count_nonzero(inside) < 2:
        return np.zeros(0), 0.0
    dt = float(np.median(np.diff(t[inside])))
    grid = np.arange(t_from_s, t_to_s - 0.5 * dt, dt)
    return np.interp(grid, t[inside], y[inside]), dt  # the window's samples only: live and replay agree


#: a plateau counts as fluttered (not subcritical) when the measured tip's RMS over a FLUTTER_WINDOW_S window
#: exceeds that of a sine of this amplitude, in panel lengths (the turbulence response below U_f is tens of
#: micrometres, an LCO tenths of L): an RMS, not one sample's peak, which 2 mm of sensor noise (an accepted
#: sensor.tip_noise_m) passed at a subcritical point; noise alone reaches it from ~0.011 L RMS (3 mm at L = 0.27 m)
FLUTTER_TIP_FRACTION = 0.02
FLUTTER_WINDOW_S = 0.25  # six periods of the flutter mode (~23 Hz); ~128 samples at the node's 512 Hz


def flutter_level_m(panel_length_m: float) -> float:
    """The flutter criterion as an RMS (m): that of a sine of FLUTTER_TIP_FRACTION x L."""
    return FLUTTER_TIP_FRACTION * panel_length_m / np.sqrt(2.0)


def flutter_mode_text(e: Any) -> str:
    """A test point's flutter-mode estimate (ModalEstimate or None) as a line shows it: frequency, damping and its
    95 % interval."""
    if e is None:
        return "flutter mode not identified"
    return "{:.3f} Hz, zeta {:.4f} [{:.4f}, {:.4f}]".format(e.frequency_hz, e.damping_ratio, *e.damping_ci())


class FlutterWatch:
    """Whether one plateau's measured tip fluttered (FLUTTER_TIP_FRACTION), fed in time order a block or a reading
    at a time: once the samples of a whole FLUTTER_WINDOW_S window, (t - W, t], have a mean square above
    (FLUTTER_TIP_FRACTION L)^2 / 2. A new plateau takes a new watch (its first window is full W after its first
    sample); the live monitor, the in-process driver and the bag's replay all decide with it."""

    def __init__(self, panel_length_m: float) -> None:
        self.limit_m2 = flutter_level_m(panel_length_m) ** 2
        self.fluttered = False
        self._t0: float | None = None
        self._t, self._sq = np.zeros(0), np.zeros(0)  # the samples a later window still needs

    def take(self, t_s: np.ndarray, tip_m: np.ndarray) -> bool:
        """Add samples (s, m); returns whether the plateau has fluttered so far."""
        t_new = np.asarray(t_s, float)
        if self.fluttered or t_new.size == 0:
            return self.fluttered
        if self._t0 is None:
            self._t0 = float(t_new[0])
        t = np.concatenate([self._t, t_new])
        sq = np.concatenate([self._sq, np.asarray(tip_m, float) ** 2])
        total = np.concatenate([[0.0], np.cumsum(sq)])
        k = np.arange(self._t.size, t.size)  # the new samples, each the end of a window
        j = np.searchsorted(t, t[k] - FLUTTER_WINDOW_S, side="right")
        whole = t[k] - FLUTTER_WINDOW_S >= self._t0
        mean_sq = (total[k + 1] - total[j]) / (k + 1 - j)
        self.fluttered = bool(np.any(whole & (mean_sq > self.limit_m2)))
        keep = t > t[-1] - FLUTTER_WINDOW_S
        self._t, self._sq = t[keep], sq[keep]
        return self.fluttered


#: a replayed window is a test point only if the measured airspeed's median is within this of the command:
#: 0.05 m/s (the plateau tolerance of the bag analysis) + 1 % (the tunnel's turbulence u' is 0.1 % r.m.s.)
AIRSPEED_MATCH_MPS, AIRSPEED_MATCH_REL = 0.05, 0.01


def _fluttered(t: np.ndarray, y: np.ndarray, t_cmd_s: float, t_from_s: float, t_end_s: float,
               force_npm: np.ndarray | None, panel_length_m: float) -> bool:
    """The plateau fluttered (:class:`FlutterWatch`): from the samples after the command on (as the live monitor and
    the in-process driver watch), or, when the shaker pushed during the plateau (a tap's forced response may pass
    that size), in the identified window only."""
    tapped = force_npm is not None and bool(np.any(np.asarray(force_npm)[(t >= t_cmd_s) & (t < t_end_s)] != 0))
    watch = ((t >= t_from_s) if tapped else (t > t_cmd_s)) & (t < t_end_s)
    return FlutterWatch(panel_length_m).take(t[watch], y[watch])


def _tunnel_at(t: np.ndarray, airspeed_mps: np.ndarray | None, t0_s: float, t1_s: float, u_mps: float) -> bool:
    """The measured airspeed's median over [t0_s, t1_s) is within AIRSPEED_MATCH of ``u_mps`` (True when there is
    no measured airspeed there)."""
    if airspeed_mps is None:
        return True
    u = np.asarray(airspeed_mps, float)[(t >= t0_s) & (t < t1_s)]
    u = u[np.isfinite(u)]
    return not u.size or abs(float(np.median(u)) - u_mps) <= AIRSPEED_MATCH_MPS + AIRSPEED_MATCH_REL * u_mps


#: the shortest dwell window that is a test point (simulated s): `flutter-test --dwell`'s least value
MIN_DWELL_S = 20.0
#: times closer than this (s) are the same time: sums of simulated seconds differ in their last bits
TIME_TOLERANCE_S = 1e-6
#: a monitored recording's window at least this fraction of the dwell long is a completed test point
COMPLETE_DWELL_FRACTION = 0.99


def kept_minimum(window_start_s: float, window_end_s: float, min_dwell_s: float) -> bool:
    """A plateau's dwell window [start, end) (simulated s) is long enough to be a test point: at least
    ``min_dwell_s``, measured in time (sums of simulated seconds differ in their last bits: TIME_TOLERANCE_S)."""
    return window_end_s - window_start_s >= min_dwell_s - TIME_TOLERANCE_S


def plateau_windows(t_last_s: float, airspeed_cmds: Sequence[tuple[float, float]], settle_s: float = DEFAULT_SETTLE_S,
                    dwell_s: float = np.inf) -> list[tuple[float, float, float, float]]:
    """Each airspeed command's dwell window as the live monitor takes it: (command time s, airspeed m/s, window
    start s, window end s), the window from the command + ``settle_s`` to the next command (or ``t_last_s``, the
    recording's end), at most ``dwell_s`` long; in time order."""
    cmds = sorted(airspeed_cmds)
    return [(tc, u, tc + settle_s,
             min(cmds[k + 1][0] if k + 1 < len(cmds) else t_last_s, tc + settle_s + dwell_s))
            for k, (tc, u) in enumerate(cmds)]


def no_point_reason(skipped: Sequence[str], settle_s: float = DEFAULT_SETTLE_S, min_dwell_s: float = MIN_DWELL_S) -> str:
    """Why :func:`replay_points` found no test point in a recording (said by `analyze`, which was silent), from the
    ``skipped`` list it filled."""
    if not skipped:
        return "no airspeed plateau above 0 m/s"
    return (f"a test point needs {min_dwell_s:g} s of an ascending plateau after its {settle_s:g} s run-in, below "
            f"flutter: {'; '.join(skipped)}")


def replay_points(t_s: np.ndarray, tip_m: np.ndarray, airspeed_cmds: Sequence[tuple[float, float]],
                  bands: Callable[[float], list[tuple[float, float]]], panel_length_m: float,
                  force_npm: np.ndarray | None = None, settle_s: float = DEFAULT_SETTLE_S, min_dwell_s: float = MIN_DWELL_S,
                  ssi: SSISettings = SSISettings(), dwell_s: float = np.inf,
                  airspeed_mps: np.ndarray | None = None, complete_only: bool = False,
                  skipped: list[str] | None = None,
                  closed_loop_s: Sequence[tuple[float, float]] = (),
                  ends_s: list[float] | None = None) -> list[TestPoint]:
    """The test points of a recording: one per airspeed command (plateau from the command + ``settle_s`` to the
    next command, at most ``dwell_s`` long: the live monitor's window), resampled by :func:`resample_window`,
    identified as live (``identify_point``). Only the subcritical ascent is kept: plateaus at U > 0 with at least
    ``min_dwell_s``, none below the last point taken (a step down is skipped, as the live monitor skips it; the same
    airspeed again is a repeated point), up to
    the first one that fluttered (:class:`FlutterWatch`)
    (:func:`_fluttered`). Given the measured ``airspeed_mps`` (m/s, on ``t_s``), a window whose median is not
    within AIRSPEED_MATCH of the command is no test point: the tunnel did not run at it (a command the rig
    refused, an aborted rig). ``complete_only`` (a recording of the monitor, whose points each took a whole
    ``dwell_s``): a window shorter than COMPLETE_DWELL_FRACTION x ``dwell_s`` (a test stopped during its dwell) is no
    test point either, unless it fluttered. ``closed_loop_s``: (start, end) times (s) in which a controller closed
    the loop (``bag_analysis.control_spans``); a window that overlaps one is no test point: its damping is the
    controlled panel's, not the panel's. ``skipped``: gets a line for each plateau at U > 0 that gave no point,
    saying why (:func:`no_point_reason`). ``ends_s``: gets each point's window end (s), when the live monitor
    identified it (a repeated airspeed's two points are one plateau of the bag's analysis, not one time)."""
    t, y = np.asarray(t_s, float), np.asarray(tip_m, float)
    if t.size < 16:
        return []
    out: list[TestPoint] = []
    why = skipped if skipped is not None else []
    for tc, u, t_from, t_end in plateau_windows(t[-1], airspeed_cmds, settle_s, dwell_s):
        if u <= 0:
            continue
        # (a window of exactly min_dwell_s computes a hair short: the 8.384 m/s point of a --dwell 20 test, commanded
        # at 63.00000000000001 s, was dropped and the prediction changed)
        if not kept_minimum(t_from, t_end, min_dwell_s):
            why.append(f"{u:.2f} m/s has {max(0.0, t_end - t_from):.1f} s")
            continue
        if not _tunnel_at(t, airspeed_mps, t_from, t_end, u):
            why.append(f"{u:.2f} m/s: the tunnel was not at it")
            continue
        if any(lo < t_end and hi > t_from for lo, hi in closed_loop_s):
            why.append(f"{u:.2f} m/s: a controller closed the loop")
            continue
        if out and u < out[-1].airspeed_mps:  # the monitor follows the ascent only: a step down is no point (the
            why.append(f"{u:.2f} m/s: a step down")  # replay stopped there, and a live test's later points, the
            continue  # monitor's too, were lost)
        if _fluttered(t, y, tc, t_from, t_end, force_npm, panel_length_m):
            why.append(f"{u:.2f} m/s fluttered")
            break
        if complete_only and t_end - tc - settle_s < COMPLETE_DWELL_FRACTION * dwell_s:
            why.append(f"{u:.2f} m/s: its dwell was cut short (the test stopped)")
            continue
        yy, dt = resample_window(t, y, t_from, t_end)
        if yy.size < 16:
            why.append(f"{u:.2f} m/s: too few samples")
            continue
        ff = None
        if force_npm is not None:
            ff = np.interp(t_from + dt * np.arange(yy.size), t, np.asarray(force_npm, float))
        out.append(identify_point(yy, dt, u, bands(u), ff, ssi))
        if ends_s is not None:
            ends_s.append(float(t_end))
    return out

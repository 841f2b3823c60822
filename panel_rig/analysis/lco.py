"""Limit-cycle runs at fixed airspeed and LCO-versus-airspeed sweeps (Sec. 3.2.2, Figs. 4-8)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from panel_rig.analysis.signals import dominant_frequency_hz, resolved_frequency_hz, rms, steady_onset_s
from panel_rig.config import PanelConfig
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import BatchStepper, DivergenceError, Stepper

INITIAL_Q = (0.0, 1e-3, 0.0)  # small 2nd-mode disturbance that starts the flutter
MEASURE_S = 5.0  # the metrics use the last 5 s, or the steady part if shorter


@dataclass(frozen=True)
class LCOResult:
    airspeed_mps: float
    rms_tip_w_over_L: float
    peak_tip_w_over_L: float
    dominant_frequency_hz: float
    steady_after_s: float | None
    diverged: bool
    diverged_at_s: float | None = None

    def as_dict(self) -> dict:
        return asdict(self)


def run_lco(cfg: PanelConfig, airspeed_mps: float, duration_s: float, variant: str = "full", aero: str = "rom",
            scheme: str = "implicit", model: AeroelasticModel | None = None, dt_s: float | None = None,
            keep: bool = False, chunk_s: float = 1.0, progress: Callable[[float], None] | None = None
            ) -> tuple[LCOResult, np.ndarray | None, Stepper]:
    """March at constant airspeed from a small disturbance; metrics over the final steady part.

    Returns the result, the tip history (if keep, else None) and the stepper (final state).
    """
    st = Stepper(cfg, variant=variant, aero=aero, scheme=scheme, model=model, dt_s=dt_s)
    st.reset(q=np.array(INITIAL_Q[: st.n_modes] + (0.0,) * max(0, st.n_modes - 3)))
    n_total = int(round(duration_s / st.dt_s))
    n_chunk = max(1, int(round(chunk_s / st.dt_s)))
    tip = np.zeros(n_total)
    done = 0
    try:
        while done < n_total:
            k = min(n_chunk, n_total - done)
            tip[done : done + k] = st.advance(k, airspeed_mps)
            done += k
            if progress:
                progress(done / n_total)
    except DivergenceError as exc:  # the history up to the last good step
        kept = np.concatenate([tip[:done], exc.tip_w_over_L])
        return diverged_result(airspeed_mps, exc.time_s), (kept if keep else None), st
    return lco_metrics(tip, st.dt_s, airspeed_mps), (tip if keep else None), st


def diverged_result(airspeed_mps: float, time_s: float) -> LCOResult:
    return LCOResult(airspeed_mps, float("nan"), float("nan"), float("nan"), None, True, time_s)


def lco_metrics(tip: np.ndarray, dt_s: float, airspeed_mps: float) -> LCOResult:
    """RMS, peak and dominant frequency of tip w/L over the last MEASURE_S seconds, or over the steady part
    when it is shorter; steady_after_s from signals.steady_onset_s."""
    onset = steady_onset_s(tip, dt_s)
    n_meas = int(round(MEASURE_S / dt_s))
    if onset is not None:
        n_meas = min(n_meas, tip.size - int(round(onset / dt_s)))
    last = tip[-max(n_meas, 16):]
    # a signal that does not move has no frequency (it reported 0.0 Hz, or a bin of round-off), nor one whose window
    # spans fewer than signals.MIN_PERIODS of its periods (a 10 ms run read 106 Hz, a mode the panel does not have)
    freq = (resolved_frequency_hz(dominant_frequency_hz(last, dt_s), last.size * dt_s) if np.ptp(last) > 0
            else float("nan"))
    return LCOResult(airspeed_mps, rms(last), float(np.max(np.abs(last))), freq, onset, False)


def lco_sweep(cfg: PanelConfig, airspeeds_mps: np.ndarray, duration_s: float, variant: str = "full",
              aero: str = "rom", scheme: str = "implicit", model: AeroelasticModel | None = None,
              progress: Callable[[float], None] | None = None) -> list[LCOResult]:
    """Independent fixed-airspeed runs (Fig. 8) marched together by a BatchStepper (leading run axis)."""
    model = model if model is not None else AeroelasticModel(cfg)
    speeds = np.asarray(airspeeds_mps, dtype=float)
    template = Stepper(cfg, variant=variant, aero=aero, scheme=scheme, model=model)
    batch = BatchStepper(template, speeds.size)
    batch.q[:, : len(INITIAL_Q)] = np.array(INITIAL_Q)[: template.n_modes]
    n_total = int(round(duration_s / template.dt_s))
    n_chunk = int(round(1.0 / template.dt_s))
    tips = np.empty((speeds.size, n_total))
    for start in range(0, n_total, n_chunk):
        k = min(n_chunk, n_total - start)
        tips[:, start : start + k] = batch.advance(k, speeds)
        if progress:
            progress((start + k) / n_total)
    out = []
    for b, u in enumerate(speeds):
        if batch.diverged[b]:
            first_nan = int(np.argmax(np.isnan(tips[b])))
            out.append(diverged_result(float(u), first_nan * template.dt_s))
        else:
            out.append(lco_metrics(tips[b], template.dt_s, float(u)))
    return out


def rms_shape(st: Stepper, airspeed_mps: float, duration_s: float, x_over_L: np.ndarray) -> np.ndarray:
    """RMS of w/L along the panel over duration_s from the stepper's current state (Fig. 5)."""
    from panel_rig.model.structure import mode_shapes

    n = int(round(duration_s / st.dt_s))
    qs = np.empty((n, st.n_modes))
    for i in range(n):
        st.advance(1, airspeed_mps)
        qs[i] = st.q
    if st.exact:  # w at the arc-length stations of the elastica
        from panel_rig.model.elastica import shape

        w = shape(qs, x_over_L, n_fine=401)[1]
    else:
        w = qs @ mode_shapes(st.n_modes, x_over_L)
    return np.sqrt(np.mean(w**2, axis=0))

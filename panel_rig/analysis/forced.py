"""Forced response without aerodynamics: the paper's protocol F0 (Sec. 3.1, Fig. 2).

A harmonic force f0 cos(omega t) at the trailing edge (generalised force f0 L phi_i(1) on mode i);
omega swept upward in steps, each held for dwell_s with the state carried over from the previous
frequency; the amplitude at each frequency is max |w/L| at the tip over the last second.
f0 = 0.05 is read as N per metre span (docs/validation.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from panel_rig.config import PanelConfig
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import DivergenceError, Stepper

F0_NPM = 0.05
BANDS_HZ = ((2.0, 7.0), (23.0, 28.0))


@dataclass(frozen=True)
class ForcedResponse:
    frequency_hz: np.ndarray
    amplitude_tip_w_over_L: np.ndarray
    peak_frequency_hz: float
    last_second: np.ndarray  # (n_freq, samples) tip w/L over the last second of each frequency (Fig. 2c, d)


def forced_sweep(cfg: PanelConfig, f_start_hz: float, f_stop_hz: float, df_hz: float = 0.1,
                 variant: str = "full", f0_npm: float = F0_NPM, dwell_s: float = 20.0,
                 model: AeroelasticModel | None = None, scheme: str = "implicit",
                 progress: Callable[[float], None] | None = None) -> ForcedResponse:
    """Protocol F0: upward stepped sine, continuous in time and phase, no aero."""
    st = Stepper(cfg, variant=variant, aero="none", scheme=scheme, model=model)
    freqs = np.round(np.arange(f_start_hz, f_stop_hz + 0.5 * df_hz, df_hz), 10)
    n_dwell = int(round(dwell_s / st.dt_s))
    n_last = int(round(1.0 / st.dt_s))
    amps, lasts = np.empty(freqs.size), np.empty((freqs.size, n_last))
    t0 = 0.0
    phase = 0.0
    for i, f in enumerate(freqs):
        t = np.arange(1, n_dwell + 1) * st.dt_s
        force = f0_npm * np.cos(phase + 2 * np.pi * f * (t - 0.5 * st.dt_s))  # mid-step force
        try:
            tip = st.advance(n_dwell, 0.0, force)
        except DivergenceError as exc:  # say at which frequency (the time alone counts over the whole sweep)
            raise DivergenceError(f"{exc.reason}, at {f:g} Hz, {exc.time_s - t0:.3f} s into its dwell",
                                  exc.time_s) from None
        phase += 2 * np.pi * f * n_dwell * st.dt_s
        t0 += n_dwell * st.dt_s
        lasts[i] = tip[-n_last:]
        amps[i] = np.max(np.abs(tip[-n_last:]))
        if progress:
            progress((i + 1) / freqs.size)
    return ForcedResponse(freqs, amps, float(freqs[int(np.argmax(amps))]), lasts)

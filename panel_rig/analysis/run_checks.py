"""Checks of a run's settings against the structure it runs, before the work: warnings, not refusals.

A physics step too coarse for the highest structural mode (:func:`coarse_step_warning`) and a forced dwell too short
for the mode nearest the band to settle (:func:`forced_settling_warning`). Both read the structure's natural
frequencies from one cached helper (:func:`natural_frequencies_hz`), so a run with both checks builds it once.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from panel_rig.config import PanelConfig

#: physics steps per period of the highest structural mode below which a run is warned of (the default step,
#: 1/2048 s, gives 28 for the paper's 73 Hz third mode)
MIN_STEPS_PER_PERIOD = 10.0

#: decay times of the mode nearest the band that a dwell should last: the start-up transient is then e^-3 (5 %)
SETTLING_DECAY_TIMES = 3.0


@lru_cache(maxsize=8)
def natural_frequencies_hz(cfg: PanelConfig) -> tuple[float, ...]:
    """The structure's undamped natural frequencies (Hz, ascending) of its linearisation at rest: one linear model
    for every variant (the exact structure's M(0) is the cubic ones' to 1.5e-9), so one for the checks of any."""
    from panel_rig.model import linearisation
    from panel_rig.model.structure import build_structure

    return tuple(float(f) for f in linearisation.natural_frequencies_hz(build_structure(cfg), "linear"))


def coarse_step_warning(cfg: PanelConfig) -> str | None:
    """A warning when ``sim.dt_s`` resolves the highest structural mode with fewer than MIN_STEPS_PER_PERIOD steps
    a period: `--set sim.dt_s=0.01` (1.4 steps of the 73 Hz mode) moved the stiffness LCO from 23.15 to 20.43 Hz
    and its RMS by 75 % without a word. The default step too: it resolves the paper's panel (28 steps), not a short
    one (`panel.length_m=0.05`: 1.0 step of its 2134 Hz mode, the LCO's RMS off by 50 %) nor 12 modes (1.3)."""
    f_max = max(natural_frequencies_hz(cfg))
    steps = 1.0 / (f_max * cfg.dt_s)
    if steps >= MIN_STEPS_PER_PERIOD:
        return None
    return (f"warning: sim.dt_s = {cfg.dt_s:g} s resolves the highest mode ({f_max:.1f} Hz) with {steps:.1f} steps a "
            f"period (fewer than {MIN_STEPS_PER_PERIOD:g}): the results are not converged in the step")


def forced_settling_warning(cfg: PanelConfig, f0_hz: float, f1_hz: float, dwell_s: float) -> str | None:
    """A warning when a dwell is shorter than SETTLING_DECAY_TIMES decay times 1/(zeta omega) of the structural
    mode nearest the band [``f0_hz``, ``f1_hz``] (the sweep has no aero: the structure's damping alone): its
    amplitudes then hold the start-up transient (`--band 3.5 5 --dwell 1` put the first mode's peak at 4.4 Hz; it
    is at 4.17)."""
    f = np.asarray(natural_frequencies_hz(cfg))
    fn = float(f[np.argmin(np.abs(f - 0.5 * (f0_hz + f1_hz)))])
    zeta = cfg.damping_ratio
    need_s = SETTLING_DECAY_TIMES / (zeta * 2 * np.pi * fn) if zeta > 0 else np.inf
    if dwell_s >= need_s:
        return None
    return (f"warning: --dwell {dwell_s:g} s is shorter than {SETTLING_DECAY_TIMES:g} decay times of the mode at "
            f"{fn:.2f} Hz (zeta {zeta:g}: {need_s:.1f} s): the amplitudes hold its start-up transient")

"""The paper's published numbers (Tang & Dowell 2002), one home for the report and the tests.

Transcribed from ``shared/paper/published_results.md`` (ids N1, F1-F4, L1, C1-C5 as there). Values read off a
plot in the paper (marked ≈ there) are marked ``approx`` in the comments.
"""

from __future__ import annotations

#: N1: natural frequencies of the first three cantilever modes, Hz
NATURAL_FREQUENCIES_HZ: tuple[float, float, float] = (4.13, 25.85, 71.67)

#: L1: linear flutter with all aero modes: speed (m/s), frequency (Hz), dominant structural mode (1-based)
FLUTTER_SPEED_MPS = 12.5
FLUTTER_FREQUENCY_HZ = 22.37
FLUTTER_DOMINANT_MODE = 2

#: F1, F3, F4: forced-response peak frequencies (1st band, 2nd band), Hz, per structural variant
FORCED_PEAKS_HZ: dict[str, tuple[float, float]] = {"full": (4.2, 25.3), "stiffness": (4.3, 26.4),
                                                   "inertia": (4.0, 25.1)}
#: F0: force amplitude of the forced-response protocol (the paper's f0; N/m here, see docs/validation.md)
FORCED_F0 = 0.05

#: C1 / C3: the LCO at U = 13.5 m/s (U/U_f = 13.5/12.5): RMS tip w/L and dominant frequency (Hz)
LCO_AIRSPEED_MPS = 13.5
C1_FULL_RMS_W_OVER_L, C1_FULL_FREQUENCY_HZ = 0.054, 22.0
C3_STIFFNESS_RMS_W_OVER_L, C3_STIFFNESS_FREQUENCY_HZ = 0.093, 22.55
#: C2: node of the RMS LCO shape, x/L (approx)
C2_NODE_X_OVER_L = 0.8
#: C4: the LCO at U = 31 m/s: peak tip w/L (approx) and frequency (Hz)
C4_AIRSPEED_MPS, C4_PEAK_W_OVER_L, C4_FREQUENCY_HZ = 31.0, 0.8, 16.65
#: C5 (Fig. 8): airspeed range (m/s); RMS tip w/L rising to (approx) and frequency falling from/to (approx, Hz)
C5_AIRSPEEDS_MPS = (12.0, 32.0)
C5_RMS_MAX_W_OVER_L = 0.5
C5_FREQUENCY_HZ = (22.0, 16.5)


def overspeed_ratio(airspeed_mps: float) -> float:
    """The paper's airspeed as a fraction of its own flutter speed (to compare at equal U/U_f)."""
    return airspeed_mps / FLUTTER_SPEED_MPS

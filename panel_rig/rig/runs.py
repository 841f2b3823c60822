"""Offline tunnel runs: the same Rig (turbulence, sensor, safety) the node drives, at a fixed airspeed, no ROS."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from panel_rig.config import PanelConfig
from panel_rig.rig.rig import RUNNING, Rig, TunnelSettings, tunnel_extras
from panel_rig.rig.safety import SafetyLimits


@dataclass(frozen=True)
class TunnelRun:
    """Per physics step: the model's tip w/L (truth); per sample the sensor's tip (m); where and why the rig
    stopped the run (None: it ran to its end)."""

    dt_s: float
    tip_w_over_L: np.ndarray
    measured_tip_m: np.ndarray
    aborted_at_s: float | None
    abort_reason: str | None = None


def run_tunnel(cfg: PanelConfig, airspeed_mps: float, duration_s: float, variant: str = "full", aero: str = "rom",
               scheme: str = "implicit", model=None, chunk_s: float = 1.0,
               progress: Callable[[float], None] | None = None) -> TunnelRun:
    """The panel at rest in the tunnel of ``cfg`` (its turbulence and sensor), airspeed set at once (no lag),
    no shaker: whatever happens comes from the tunnel. Sampled every physics step."""
    from panel_rig.model.stepper import Stepper

    st = Stepper(cfg, variant=variant, aero=aero, scheme=scheme, model=model)
    limits = SafetyLimits(max_airspeed_mps=max(airspeed_mps, 1.0) * 2, max_tip_w_over_L=cfg.max_tip_w_over_L,
                          wall_clearance_m=cfg.max_tip_w_over_L * cfg.panel_length_m)  # offline: the model's bound
    rig = Rig(st, cfg.panel_length_m, limits=limits, tunnel=TunnelSettings(0.0), **tunnel_extras(cfg, st))
    result = rig.command_airspeed(airspeed_mps)
    if not result.accepted:
        raise ValueError(result.reason)
    n_total = int(round(duration_s / rig.dt_s))
    n_chunk = max(1, int(round(chunk_s / rig.dt_s)))
    tips, meas = [], []
    done = 0
    while done < n_total and rig.state == RUNNING:
        k = min(n_chunk, n_total - done)
        blk = rig.advance_samples([1] * k)
        tips.append(blk.tip_w_over_L)
        meas.append(blk.tip_w_m)
        done += k
        if progress:
            progress(done / n_total)
    tip = np.concatenate(tips) if tips else np.zeros(0)
    measured = np.concatenate(meas) if meas else np.zeros(0)
    aborted, reason = None, None
    if rig.state != RUNNING:  # the abort's own time, not the chunk's end; the series stop there too (the block
        aborted = float(rig.abort_time_s)  # runs on to its end after an abort)
        keep = int(round(aborted / rig.dt_s))
        tip, measured = tip[:keep], measured[:keep]
        reason = rig.abort_reason
    return TunnelRun(rig.dt_s, tip, measured, aborted, reason)

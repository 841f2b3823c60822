"""The rig (no ROS) with the exact (elastica) structure: the whole airspeed range of the tunnel is usable."""

import numpy as np
import pytest

from panel_rig.config import load_config
from panel_rig.model.stepper import Stepper
from panel_rig.rig.rig import RUNNING, Rig
from panel_rig.rig.safety import SafetyLimits, tip_limit_from_wall_clearance

SAMPLE_STEPS = 16  # 128 samples per simulated second


def test_tip_limit_is_the_wall_contact():
    assert SafetyLimits().tip_limit(0.27) == pytest.approx(0.25 / 0.27)
    assert SafetyLimits(wall_clearance_m=0.1).tip_limit(0.5) == pytest.approx(0.2)
    assert SafetyLimits(wall_clearance_m=1.0).tip_limit(0.27) == 1.0  # the panel's own length first
    assert tip_limit_from_wall_clearance(1.0, 0.27) == 1.0  # an inextensible panel cannot reach farther than L
    with pytest.raises(ValueError):
        tip_limit_from_wall_clearance(0.0, 0.27)


def test_exact_rig_climbs_a_staircase_to_25_mps_without_abort(model):
    """Fast block mode, wall-contact tip limit (0.926), tunnel lag 1 s: 8 -> 25 m/s through flutter (shaker
    burst at 11 m/s); the panel flutters, stays within the walls, and the rig never aborts."""
    cfg = load_config()
    rig = Rig(Stepper(cfg, variant="exact", model=model), cfg.panel_length_m,
              limits=SafetyLimits())
    dwell = 5.0
    per_step = int(round(dwell / rig.dt_s / SAMPLE_STEPS))
    tips, rms_at = [], {}
    for u in (8.0, 10.0, 11.0, 13.0, 16.0, 19.0, 22.0, 25.0):
        assert rig.command_airspeed(u).accepted
        if u == 11.0:  # excite the flutter mode for 2 s, as in config/staircase.yaml
            rig.command_frequency(22.5)
            rig.command_amplitude(0.3)
            tips.append(rig.advance_samples([SAMPLE_STEPS] * int(2.0 / rig.dt_s / SAMPLE_STEPS)).tip_w_over_L)
            rig.command_amplitude(0.0)
        block = rig.advance_samples([SAMPLE_STEPS] * per_step)
        tips.append(block.tip_w_over_L)
        rms_at[u] = float(np.sqrt(np.mean(block.tip_w_over_L[-len(block) // 2:] ** 2)))
        assert rig.state == RUNNING, (u, rig.abort_reason)
    tips = np.concatenate(tips)
    assert rig.abort_count == 0
    assert np.max(np.abs(tips)) < rig.limits.tip_limit(cfg.panel_length_m) < 1.0  # inside the walls
    assert rms_at[8.0] < 1e-6 and rms_at[25.0] > 0.3  # at rest below flutter, a large LCO at 25 m/s

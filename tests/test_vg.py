"""V-g / V-f of the stepper's continuous-time model: tracking by continuity, agreement with the flutter search,
the stepper's own free response, and the CLI's --vg."""

import json
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg

from panel_rig.analysis.flutter import find_flutter
from panel_rig.analysis.vg import ModalTracker, model_flutter_speed, pole_damping_ratio, pole_frequency_hz, pole_from_modal, vg_diagram


@pytest.fixture(scope="module")
def vg(model):
    return vg_diagram(model, np.arange(0.0, 14.01, 0.5))


def test_pole_conventions_round_trip():
    s = pole_from_modal(np.array([4.0, 23.0]), np.array([0.4, -0.01]))
    assert pole_frequency_hz(s) == pytest.approx([4.0, 23.0])
    assert pole_damping_ratio(s) == pytest.approx([0.4, -0.01])


def test_tracked_poles_are_eigenvalues_of_the_model(model, vg):
    """Every tracked pole is an eigenvalue of Mc y' = Ac y at its airspeed (to 1e-9 relative)."""
    for u, poles in zip(vg.airspeed_mps[::4], vg.poles[::4]):
        Mc, Ac = model.continuous_matrices(u, model.cfg.rom_modes)
        eig = scipy.linalg.eigvals(Ac, Mc)
        for s in poles:
            assert np.min(np.abs(eig - s)) <= 1e-9 * abs(s)


def test_modes_at_rest_are_the_added_mass_modes(model, vg):
    """At U = 0 the three tracked modes are the in-vacuo modes lowered by the added mass, with the structural
    damping ratio (the aero states sit at s = 0)."""
    f0 = vg.frequency_hz[0]
    fs = model.structure.natural_frequencies_hz
    assert np.all(f0 < fs) and np.all(f0 > 0.8 * fs)
    assert vg.damping_ratio[0] == pytest.approx(model.cfg.damping_ratio, rel=0.1)


def test_tracking_is_continuous(vg):
    """No jumps: between neighbouring grid points (0.5 m/s) each mode moves by less than a tenth of the distance to
    the nearest other tracked mode."""
    step = np.abs(np.diff(vg.poles, axis=0))
    gaps = np.abs(vg.poles[:, :, None] - vg.poles[:, None, :]) + np.eye(vg.poles.shape[1]) * 1e9
    assert np.all(step < 0.1 * gaps.min(axis=2)[1:])


def test_tracking_does_not_depend_on_the_grid(model, vg):
    """A coarse grid (2 m/s) lands on the same poles as the fine one: the sub-steps do the tracking."""
    coarse = vg_diagram(model, [12.0, 2.0, 6.0])  # any order
    for u, p in zip(coarse.airspeed_mps, coarse.poles):
        assert p == pytest.approx(vg.poles[int(round(u / 0.5))], rel=1e-9)


def test_flutter_speed_of_the_tracked_mode_matches_the_flutter_search(model, vg):
    """The tracked mode 2 crosses zero damping where find_flutter (continuous formulation, ROM) puts U_f, and the
    crossing frequency agrees (Im s vs |s| differ by zeta^2/2 ~ 0 there)."""
    uf, mode = model_flutter_speed(model)
    ref = find_flutter(model, aero="rom", rom_modes=model.cfg.rom_modes, formulation="continuous")
    assert mode == ref.dominant_mode == 2
    assert uf == pytest.approx(ref.speed_mps, abs=1e-4)
    s = ModalTracker(model).poles(uf)[1]
    assert pole_frequency_hz(s) == pytest.approx(ref.frequency_hz, rel=1e-4)
    z = vg.damping_ratio[:, 1]
    assert np.all(z[vg.airspeed_mps < uf - 0.1] > 0) and np.all(z[vg.airspeed_mps > uf + 0.1] < 0)


def test_stepper_free_response_has_the_vg_poles(cfg, model):
    """The linear stepper (implicit midpoint at 1/2048 s) released from a mode-2 displacement decays with the V-g
    pole of mode 2: ERA on its noise-free tip gives frequency and damping ratio to 0.1 % / 1 % (the midpoint rule's
    frequency warping is (omega dt)^2/12 = 4e-4)."""
    from panel_rig.analysis.identification import identify_free_decay
    from panel_rig.model.stepper import Stepper

    u = 8.0
    st = Stepper(cfg, "linear", "rom", model=model)
    st.reset(q=np.array([0.0, 1e-4, 0.0]))
    tip = st.advance(int(4.0 / st.dt_s), u)
    ref = vg_diagram(model, [u])
    f, z = ref.frequency_hz[0, 1], ref.damping_ratio[0, 1]
    est = identify_free_decay(tip, st.dt_s, [(0.9 * f, 1.1 * f)])[0]
    assert est.frequency_hz == pytest.approx(f, rel=1e-3)
    assert est.damping_ratio == pytest.approx(z, rel=0.01)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "panel_rig.cli", *args], capture_output=True, text=True, timeout=120)


def test_cli_vg_json_and_plot(tmp_path, vg):
    png = tmp_path / "vg.png"
    out = _cli("flutter", "--json", "--vg", "6:10:2", "--plot", str(png))
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert [p["airspeed_mps"] for p in d["vg"]] == [6.0, 8.0, 10.0]
    assert d["vg_model"] == {"aero": "rom", "rom_modes": 12, "formulation": "continuous"}  # not the search's
    for p in d["vg"]:
        assert len(p["modes"]) == 3 and set(p["modes"][0]) == {"frequency_hz", "damping_ratio"}
        k = int(round(p["airspeed_mps"] / 0.5))
        # the CLI ran in another process: LAPACK may round differently there, so 1e-6, not bit equality
        assert [m["damping_ratio"] for m in p["modes"]] == pytest.approx(vg.damping_ratio[k], rel=1e-6)
    assert png.stat().st_size > 10_000


def test_a_mode_the_panel_cuts_is_named_with_where_it_leaves(model):
    """`flutter --vg 0:50:5 --plot`: the panel spans the lightly damped modes, and the first mode (zeta 0.04 at rest,
    1.0 later) was drawn cut off after U = 0 with no word; a mode entirely off the panel was named already."""
    from panel_rig.analysis.vg import damping_limits, mode_label

    d = vg_diagram(model, np.arange(0.0, 50.01, 5.0))
    limits, _ = damping_limits(d.damping_ratio)
    first = mode_label(1, d.airspeed_mps, d.damping_ratio[:, 0], limits)
    assert first.startswith("mode 1: zeta 0.0") and first.endswith("off the panel from 5 m/s"), first
    assert mode_label(2, d.airspeed_mps, np.full(11, 0.5), limits).endswith("above the panel")
    assert mode_label(3, d.airspeed_mps, np.zeros(11), limits) == "mode 3"


def test_cli_vg_bad_range():
    out = _cli("flutter", "--vg", "10:8:1")
    assert out.returncode == 2 and "--vg" in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_the_v_g_panel_is_linear_over_the_lightly_damped_modes(model):
    """`panel-rig flutter --vg --plot` drew damping on a symlog axis (linear within 0.01): the flutter mode's slope
    could not be read and its curve had a knee at -0.01. The panel is now linear over the lightly damped modes and 0;
    the first mode (zeta 0.2-0.6) is outside it and named in the legend."""
    from panel_rig.analysis.vg import LIGHT_DAMPING, damping_limits

    z = vg_diagram(model, np.arange(3.0, 14.01, 0.5)).damping_ratio  # the review's range (at rest mode 1 is ~0)
    (lo, hi), outside = damping_limits(z)
    light = [i for i in range(z.shape[1]) if z[:, i].max() <= LIGHT_DAMPING]
    assert light and lo < 0 < hi  # the flutter mode crosses zero inside the diagram
    assert lo <= z[:, light].min() and z[:, light].max() <= hi < 0.1
    assert outside == [i for i in range(z.shape[1]) if i not in light] and outside
    assert damping_limits(np.array([[0.3, 0.5], [0.4, 0.6]]))[1] == []  # all heavily damped: they set the scale

"""``panel-rig modes`` and ``panel-rig flutter`` accept every structural variant: the linear analysis of each
variant is its own linearisation at rest, which for ``exact`` (its quadrature mass matrix M(0)) is the same
linear model as the cubic variants' to 1e-6 relative."""

import json

import numpy as np
import pytest

from panel_rig.cli import main
from panel_rig.config import load_config
from panel_rig.model.linearisation import linear_mass_matrix_kg
from panel_rig.model.options import VARIANTS
from panel_rig.model.structure import build_structure


def _json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_exact_linear_mass_is_its_own_quadrature_and_equals_the_cubic_one():
    s = build_structure(load_config())
    m_exact, m_full = linear_mass_matrix_kg(s, "exact"), linear_mass_matrix_kg(s, "full")
    assert not np.array_equal(m_exact, m_full)  # computed, not copied: quadrature rounding shows
    np.testing.assert_allclose(m_exact, m_full, rtol=0, atol=1e-8 * s.modal_mass_kg)  # measured: 1.5e-9
    with pytest.raises(ValueError, match="variant"):
        linear_mass_matrix_kg(s, "cubic")


def test_modes_with_variant_exact_equals_full(capsys):
    out = {v: _json(capsys, ["modes", "--variant", v, "--json"]) for v in ("full", "exact")}
    assert out["exact"]["variant"] == "exact" and out["full"]["variant"] == "full"
    np.testing.assert_allclose(out["exact"]["natural_frequencies_hz"], out["full"]["natural_frequencies_hz"],
                               rtol=1e-6)
    assert _json(capsys, ["modes", "--json"])["variant"] == "full"  # the default


@pytest.mark.parametrize("aero", ["full", "rom"])
def test_flutter_with_variant_exact_equals_full(capsys, aero):
    out = {v: _json(capsys, ["flutter", "--variant", v, "--aero", aero, "--json"]) for v in ("full", "exact")}
    assert out["exact"]["variant"] == "exact" and out["full"]["variant"] == "full"
    for key in ("flutter_speed_mps", "flutter_frequency_hz"):
        assert out["exact"][key] == pytest.approx(out["full"][key], rel=1e-6), key
    assert out["exact"]["dominant_mode"] == out["full"]["dominant_mode"]
    assert 9.0 < out["exact"]["flutter_speed_mps"] < 13.0


@pytest.mark.parametrize("command", ["modes", "flutter"])
def test_every_variant_is_accepted_and_a_bad_one_exits_2(capsys, command):
    assert main([command, "--variant", "elastic", "--json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("panel-rig: error:") and "variant" in err, err
    if command == "modes":  # cheap: every variant's own linearisation
        f = [_json(capsys, ["modes", "--variant", v, "--json"])["natural_frequencies_hz"] for v in VARIANTS]
        np.testing.assert_allclose(f, [f[0]] * len(f), rtol=1e-6)


def test_a_mistyped_required_option_is_named_with_the_missing_one(capsys):
    """`paper --outt x` said only "the following arguments are required: --out", hiding the typo."""
    assert main(["paper", "--outt", "x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("panel-rig: error: unrecognized argument --outt (did you mean --out?); the following arguments "
                   "are required: --out"), err
    assert main(["paper"]) == 2  # nothing mistyped: argparse's message alone
    assert capsys.readouterr().err.strip() == "panel-rig: error: the following arguments are required: --out"

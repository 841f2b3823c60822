"""How each modelling choice the paper leaves open moves the linear flutter point (docs/validation.md).

Run ``python -m panel_rig.analysis.sensitivity`` to print the markdown table.
"""

from __future__ import annotations

import sys
import time

from panel_rig.analysis.flutter import find_flutter
from panel_rig.argparsing import study_parser
from panel_rig.config import PanelConfig, load_config
from panel_rig.model.aeroelastic import AeroelasticModel

CASES: list[tuple[str, dict]] = [
    ("baseline (this repo's defaults)", {}),
    ("structural damping 0", {"damping_ratio": 0.0}),
    ("structural damping 0.01", {"damping_ratio": 0.01}),
    ("air density 1.0 kg/m^3", {"air_density_kgpm3": 1.0}),
    ("air density 0.8 kg/m^3", {"air_density_kgpm3": 0.8}),
    ("load point 3/4 (collocation)", {"load_point": "three_quarter"}),
    ("load point element centre", {"load_point": "center"}),
    ("wake 30 elements", {"n_wake": 30}),
    ("wake 120 elements", {"n_wake": 120}),
    ("wake 240 elements", {"n_wake": 240}),
    ("wake relaxation 0.98", {"wake_relaxation": 0.98}),
    ("wake relaxation 0.999", {"wake_relaxation": 0.999}),
    ("30 body elements (+30 wake)", {"n_elements": 30, "n_wake": 30}),
    ("120 body elements (+120 wake)", {"n_elements": 120, "n_wake": 120}),
    ("E = 7.2e10 Pa (E read as 72 GPa)", {"youngs_modulus_pa": 7.2e10}),
    ("E = 7.2e9 Pa (E read literally)", {"youngs_modulus_pa": 7.2e9}),
    ("4 structural modes", {"n_modes": 4}),
]


def measure(cfg: PanelConfig | None = None) -> list[dict]:
    """U_f, f_f and dominant mode (full aero, Eq. 24) for each case."""
    base = cfg if cfg is not None else load_config()
    rows = []
    for label, change in CASES:
        t0 = time.perf_counter()
        fp = find_flutter(AeroelasticModel(base.replace(**change)), aero="full", u_max=80.0, n_scan=80)
        rows.append({"case": label, "change": change,
                     "flutter_speed_mps": None if fp is None else fp.speed_mps,
                     "flutter_frequency_hz": None if fp is None else fp.frequency_hz,
                     "dominant_mode": None if fp is None else fp.dominant_mode,
                     "wall_s": time.perf_counter() - t0})
    return rows


def markdown(rows: list[dict], paper_speed: float = 12.5) -> str:
    out = ["| case | U_f (m/s) | change vs baseline | f_f (Hz) | dominant mode |", "|---|---|---|---|---|"]
    base = rows[0]["flutter_speed_mps"]
    for r in rows:
        u = r["flutter_speed_mps"]
        if u is None:
            out.append(f"| {r['case']} | none < 80 | | | |")
            continue
        out.append(f"| {r['case']} | {u:.2f} | {100 * (u / base - 1):+.1f} % | {r['flutter_frequency_hz']:.2f} | "
                   f"{r['dominant_mode']} |")
    return "\n".join(out)


if __name__ == "__main__":
    study_parser(__doc__, "panel_rig.analysis.sensitivity").parse_args()
    print(markdown(measure()))
    sys.exit(0)

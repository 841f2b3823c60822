"""Convergence of the exact (elastica) structure's statics: ``python -m panel_rig.analysis.elastica_study``.

Prints the markdown tables of docs/validation.md: dead tip load against Bisshopp & Drucker (1945) over the
number of modes and quadrature points, the cubic ``full`` structure on the same loads, and the pure tip
moment against the circular arc.
"""

from __future__ import annotations

import numpy as np

from panel_rig.argparsing import study_parser
from panel_rig.model.elastica import static_tip_load, static_tip_moment

#: Bisshopp & Drucker (1945): P L^2/EI -> (tip w/L, axial shortening u/L)
BISSHOPP_DRUCKER = {1.0: (0.30172, 0.05643), 2.0: (0.49346, 0.16064), 5.0: (0.71379, 0.38763),
                    10.0: (0.81061, 0.55500)}


def dead_load_table(modes=(3, 4, 6, 12), quads=((2, 4), (4, 6), (8, 8))) -> str:
    head = "| structure | modes | quadrature | " + " | ".join(
        f"P L^2/D = {a:g}: w/L (err) ; u/L (err)" for a in BISSHOPP_DRUCKER) + " |"
    rows = [head, "|" + "---|" * (3 + len(BISSHOPP_DRUCKER))]
    rows.append("| Bisshopp & Drucker | — | — | " + " | ".join(
        f"{w:.5f} ; {u:.5f}" for w, u in BISSHOPP_DRUCKER.values()) + " |")

    def cells(variant, n, ne, ng):
        out = []
        for a, (w, u) in BISSHOPP_DRUCKER.items():
            r = static_tip_load(a, variant, n_modes=n, n_elem=ne, n_gauss=ng)
            out.append(f"{r.tip_w_over_L:.5f} ({100 * (r.tip_w_over_L / w - 1):+.2f} %) ; "
                       f"{r.tip_u_over_L:.5f} ({100 * (r.tip_u_over_L / u - 1):+.2f} %)")
        return " | ".join(out)

    for n in modes:
        for ne, ng in quads:
            rows.append(f"| exact | {n} | {ne} x {ng} | {cells('exact', n, ne, ng)} |")
    for n in (3, 6):
        rows.append(f"| full (cubic) | {n} | — | {cells('full', n, 1, 1)} |")
    rows.append(f"| linear | 3 | — | {cells('linear', 3, 1, 1)} |")
    return "\n".join(rows)


def moment_table(mus=(0.5, 1.0, 2.0), modes=(3, 6, 12)) -> str:
    rows = ["| M L/D | modes | w/L (arc) | err | u/L (arc) | err | tip angle (arc = M L/D) |", "|---|---|---|---|---|---|---|"]
    for mu in mus:
        w_ref, u_ref = (1 - np.cos(mu)) / mu, 1 - np.sin(mu) / mu
        for n in modes:
            w, u, th = static_tip_moment(mu, n_modes=n)
            rows.append(f"| {mu:g} | {n} | {w:.5f} ({w_ref:.5f}) | {100 * (w / w_ref - 1):+.2f} % | "
                        f"{u:.5f} ({u_ref:.5f}) | {100 * (u / u_ref - 1):+.2f} % | {th:.4f} |")
    return "\n".join(rows)


if __name__ == "__main__":
    study_parser(__doc__, "panel_rig.analysis.elastica_study").parse_args()
    print(dead_load_table())
    print()
    print(moment_table())

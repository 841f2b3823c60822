"""Each structural variant linearised at rest: what the linear analyses (``panel-rig modes``, ``flutter``) use.

The cubic variants (Eqs. 19-22) add terms of third order in (q, q_dot) to the linear model, so at q = 0 they are
the linear model exactly. The exact (elastica) structure's linearisation comes from its own kinematics: the
mass matrix M(0) = m_p L^3 int phi_i phi_j by the kernel's quadrature (elastica.py), dh/dq_dot(0) = 0, the tip
force vector B(1; 0) = phi(1) and the same stiffness (D/L) beta^4; M(0) equals m_p L^3 I to the quadrature's
accuracy (1.5e-9 relative with 3 modes), so every variant has, to that accuracy, one linear model (tests/test_elastica.py,
tests/test_cli_variants.py).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from panel_rig.model.elastica import exact_kinematics
from panel_rig.model.options import EXACT_VARIANT, VARIANTS
from panel_rig.model.structure import Structure


def linear_mass_matrix_kg(structure: Structure, variant: str) -> np.ndarray:
    """Structural modal mass matrix (kg/m, per unit modal coordinate) of ``variant`` linearised at q = 0:
    m_p L^3 I for the cubic variants, m_p L^3 M(0) by the exact structure's quadrature for ``exact``."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {tuple(VARIANTS)}, got {variant!r}")
    n = structure.n_modes
    if variant == EXACT_VARIANT:
        return structure.modal_mass_kg * exact_kinematics(n).mass_matrix(np.zeros(n))
    return structure.modal_mass_kg * np.eye(n)


def natural_frequencies_hz(structure: Structure, variant: str) -> np.ndarray:
    """Undamped natural frequencies (Hz) of the variant's linearisation: K phi = omega^2 M(0) phi, ascending."""
    w2 = scipy.linalg.eigvalsh(np.diag(structure.modal_stiffness_npm), linear_mass_matrix_kg(structure, variant))
    return np.sqrt(w2) / (2.0 * np.pi)

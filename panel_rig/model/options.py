"""The model's option names, in one place: structural variants, aerodynamic models, time schemes.

Every layer (stepper, node parameters, CLI choices, benchmarks, reports) derives its lists from here.
"""

from __future__ import annotations

#: structural variant -> (stiffness nonlinearity F_K on, inertia nonlinearity dM and F_M on) (Eqs. 21-22)
VARIANTS: dict[str, tuple[bool, bool]] = {
    "full": (True, True),
    "stiffness": (True, False),
    "inertia": (False, True),
    "linear": (False, False),
}
DEFAULT_VARIANT = "full"
#: the paper's four variants of the cubic (third-order) inextensible beam (Sec. 4.1)
PAPER_VARIANTS: tuple[str, ...] = ("full", "stiffness", "inertia", "linear")

#: aerodynamics: reduced-order (Ra aero eigenmodes + static correction), all aero modes, or none
AERO_MODELS: tuple[str, ...] = ("rom", "full", "none")
#: the aerodynamic models a live rig may run (air always on)
RIG_AERO_MODELS: tuple[str, ...] = ("rom", "full")
DEFAULT_AERO = "rom"

#: time schemes of the nonlinear mass (see kernel.py): consistent midpoint, the paper's Eq. 24, its literal form
SCHEMES: tuple[str, ...] = ("implicit", "paper", "paper_literal")
DEFAULT_SCHEME = "implicit"

"""The model's option names, in one place: structural variants, aerodynamic models, time schemes.

Every layer (stepper, node parameters, CLI choices, benchmarks, reports) derives its lists from here.
"""

from __future__ import annotations

#: the cubic (third-order) structure's variants -> (stiffness nonlinearity F_K on, inertia nonlinearity dM and
#: F_M on) (Eqs. 21-22)
CUBIC_VARIANTS: dict[str, tuple[bool, bool]] = {
    "full": (True, True),
    "stiffness": (True, False),
    "inertia": (False, True),
    "linear": (False, False),
}
#: the geometrically exact (elastica) structure: slope-angle kinematics, no expansion (model/elastica.py)
EXACT_VARIANT = "exact"
#: every structural variant -> (use_k, use_m) of the cubic kernel terms; ``exact`` runs neither (its
#: nonlinearity is the exact kinematics, not the cubic tensors)
VARIANTS: dict[str, tuple[bool, bool]] = {**CUBIC_VARIANTS, EXACT_VARIANT: (False, False)}
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


def stepper_problem(variant: str, aero: str, scheme: str) -> str | None:
    """Why a march cannot run these options (unknown names, or the exact structure with a scheme other than the
    implicit midpoint); None when it can. The stepper refuses with it, and a command checks it before it warns."""
    if variant not in VARIANTS:
        return f"variant must be one of {tuple(VARIANTS)}, got {variant!r}"
    if aero not in AERO_MODELS:
        return f"aero must be one of {AERO_MODELS}, got {aero!r}"
    if scheme not in SCHEMES:
        return f"scheme must be one of {tuple(SCHEMES)}, got {scheme!r}"
    if variant == EXACT_VARIANT and scheme != "implicit":
        return "the exact structure runs the implicit (midpoint) scheme only"
    return None

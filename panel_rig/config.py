"""The rig's configuration: a validated, frozen dataclass read from a ROS 2 parameters file.

The YAML is a ROS 2 parameters file (``panel_rig: ros__parameters: {...}``) with nested groups;
keys are addressed by dotted names (``panel.length_m``). Every value is checked for type, sign and
range, and the error names the offending key.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import yaml

NODE_NAME = "panel_rig"
DEFAULT_PARAMS_NAME = "tang_dowell_2002.yaml"


class ConfigError(ValueError):
    """A parameter file or override that cannot be used; the message names the key."""


@dataclass(frozen=True)
class PanelConfig:
    """Physical and numerical parameters of the rig, SI units (defaults: Tang & Dowell 2002, Sec. 3)."""

    panel_length_m: float = 0.27
    panel_thickness_m: float = 0.36e-3
    airfoil_length_m: float = 0.072
    density_kgpm3: float = 2840.0
    youngs_modulus_pa: float = 7.2e9 * 9.80665
    poisson_ratio: float = 0.3
    damping_ratio: float = 0.005
    n_modes: int = 3
    air_density_kgpm3: float = 1.225
    n_elements: int = 60
    n_wake: int = 60
    wake_relaxation: float = 0.992
    rom_modes: int = 12
    load_point: str = "quarter"
    dt_s: float = 1.0 / 2048.0
    max_tip_w_over_L: float = 2.0
    # the tunnel and the tip sensor around the model (used by panel_rig/rig/: turbulence.py, sensor.py; the model
    # itself never reads them); same values as config/tang_dowell_2002.yaml, where their sources are given
    turbulence_intensity: float = 0.001
    turbulence_length_scale_m: float = 0.1
    turbulence_spectrum: str = "von_karman"
    turbulence_seed: int = 0
    sensor_tip_noise_m: float = 5.0e-6
    sensor_resolution_m: float = 3.0e-6
    sensor_bandwidth_hz: float = 1000.0
    sensor_latency_s: float = 0.0005

    @property
    def mass_per_area_kgpm2(self) -> float:
        """m_p = rho_m h."""
        return self.density_kgpm3 * self.panel_thickness_m

    @property
    def bending_stiffness_nm(self) -> float:
        """D = E h^3 / (12 (1 - nu^2)), N m (per unit span)."""
        return self.youngs_modulus_pa * self.panel_thickness_m**3 / (12.0 * (1.0 - self.poisson_ratio**2))

    @property
    def chord_m(self) -> float:
        """c = L0 + L."""
        return self.airfoil_length_m + self.panel_length_m

    @property
    def element_length_m(self) -> float:
        """dx = c / km."""
        return self.chord_m / self.n_elements

    def replace(self, **changes: Any) -> "PanelConfig":
        """A copy with some fields changed, validated again."""
        new = dataclasses.replace(self, **changes)
        for key, spec in SCHEMA.items():
            spec.check(key, getattr(new, spec.field))
        return new


def _positive(v: float) -> bool:
    return v > 0


@dataclass(frozen=True)
class _Spec:
    field: str
    kind: type
    ok: Callable[[Any], bool]
    rule: str

    def check(self, key: str, value: Any) -> Any:
        """Coerce and validate one value; raise ConfigError naming ``key``."""
        if self.kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{key}: expected a number, got {value!r}")
            value = float(value)
            if not math.isfinite(value):
                raise ConfigError(f"{key}: must be finite, got {value!r}")
        elif self.kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{key}: expected an integer, got {value!r}")
        elif not isinstance(value, self.kind):
            raise ConfigError(f"{key}: expected {self.kind.__name__}, got {value!r}")
        if not self.ok(value):
            raise ConfigError(f"{key}: {self.rule}, got {value!r}")
        return value


LOAD_POINTS = ("quarter", "three_quarter", "center")
TURBULENCE_SPECTRA = ("dryden", "von_karman", "off")  # = panel_rig.rig.turbulence.SPECTRA (config is the top layer)

SCHEMA: dict[str, _Spec] = {
    "panel.length_m": _Spec("panel_length_m", float, _positive, "must be > 0"),
    "panel.thickness_m": _Spec("panel_thickness_m", float, _positive, "must be > 0"),
    "airfoil.length_m": _Spec("airfoil_length_m", float, lambda v: v >= 0, "must be >= 0"),
    "material.density_kgpm3": _Spec("density_kgpm3", float, _positive, "must be > 0"),
    "material.youngs_modulus_pa": _Spec("youngs_modulus_pa", float, _positive, "must be > 0"),
    "material.poisson_ratio": _Spec("poisson_ratio", float, lambda v: -1 < v < 0.5, "must lie in (-1, 0.5)"),
    "structure.damping_ratio": _Spec("damping_ratio", float, lambda v: 0 <= v < 1, "must lie in [0, 1)"),
    "structure.modes": _Spec("n_modes", int, lambda v: 1 <= v <= 12, "must lie in 1..12"),
    "air.density_kgpm3": _Spec("air_density_kgpm3", float, lambda v: v >= 0, "must be >= 0"),
    "aero.elements": _Spec("n_elements", int, lambda v: 4 <= v <= 2000, "must lie in 4..2000"),
    "aero.wake_elements": _Spec("n_wake", int, lambda v: 2 <= v <= 20000, "must lie in 2..20000"),
    "aero.wake_relaxation": _Spec("wake_relaxation", float, lambda v: 0 < v < 1, "must lie in (0, 1)"),
    "aero.rom_modes": _Spec("rom_modes", int, lambda v: v >= 1, "must be >= 1"),
    "aero.load_point": _Spec("load_point", str, lambda v: v in LOAD_POINTS, f"must be one of {LOAD_POINTS}"),
    "sim.dt_s": _Spec("dt_s", float, lambda v: 0 < v <= 0.01, "must lie in (0, 0.01]"),
    "sim.max_tip_w_over_L": _Spec("max_tip_w_over_L", float, _positive, "must be > 0"),
    "tunnel.turbulence.intensity": _Spec("turbulence_intensity", float, lambda v: 0 <= v <= 0.2,
                                         "must lie in [0, 0.2] (sigma / U)"),
    "tunnel.turbulence.length_scale_m": _Spec("turbulence_length_scale_m", float, lambda v: 1e-3 <= v <= 100,
                                              "must lie in [0.001, 100] m"),
    "tunnel.turbulence.spectrum": _Spec("turbulence_spectrum", str, lambda v: v in TURBULENCE_SPECTRA,
                                        f"must be one of {TURBULENCE_SPECTRA}"),
    "tunnel.turbulence.seed": _Spec("turbulence_seed", int, lambda v: 0 <= v < 2**63, "must lie in [0, 2^63)"),
    "sensor.tip_noise_m": _Spec("sensor_tip_noise_m", float, lambda v: 0 <= v <= 0.1, "must lie in [0, 0.1] m"),
    "sensor.resolution_m": _Spec("sensor_resolution_m", float, lambda v: 0 <= v <= 0.1, "must lie in [0, 0.1] m"),
    "sensor.bandwidth_hz": _Spec("sensor_bandwidth_hz", float, lambda v: v >= 0,
                                 "must be >= 0 (0: unlimited)"),
    "sensor.latency_s": _Spec("sensor_latency_s", float, lambda v: 0 <= v <= 1.0, "must lie in [0, 1] s"),
}


def default_params_path() -> Path:
    """The paper's parameter file: from the source tree, else from the installed ament share dir."""
    here = Path(__file__).resolve().parent.parent / "config" / DEFAULT_PARAMS_NAME
    if here.is_file():
        return here
    return Path(sys.prefix) / "share" / NODE_NAME / "config" / DEFAULT_PARAMS_NAME


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mapping to {dotted.key: value}."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def read_params_file(path: str | Path) -> dict[str, Any]:
    """Read ``panel_rig: ros__parameters:`` (or ``/**:``) from a ROS 2 parameters file, flattened."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"parameters file not found: {p}")
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise ConfigError(f"{p}: malformed YAML{where}") from None
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{p}: expected a mapping '{NODE_NAME}: ros__parameters: ...'")
    section = None
    for node_key in (NODE_NAME, f"/{NODE_NAME}", "/**"):
        if isinstance(doc.get(node_key), Mapping):
            section = doc[node_key].get("ros__parameters")
            break
    if not isinstance(section, Mapping):
        raise ConfigError(f"{p}: no '{NODE_NAME}: ros__parameters:' section")
    return flatten(section)


def parse_override(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` with VALUE parsed as a YAML scalar."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"--set expects KEY=VALUE, got {text!r}")
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ConfigError(f"{key.strip()}: cannot parse value {raw!r}") from None
    return key.strip(), value


def config_from_flat(values: Mapping[str, Any], known_extra: Iterable[str] = ()) -> PanelConfig:
    """Validate a {dotted.key: value} mapping into a PanelConfig.

    Keys in ``known_extra`` (e.g. the node's own parameters) are accepted and ignored here.
    """
    extra = set(known_extra)
    fields: dict[str, Any] = {}
    for key, value in values.items():
        if key in extra:
            continue
        spec = SCHEMA.get(key)
        if spec is None:
            raise ConfigError(f"{key}: unknown parameter (known: {', '.join(sorted(SCHEMA))})")
        fields[spec.field] = spec.check(key, value)
    return PanelConfig(**fields)


def load_config(
    path: str | Path | None = None,
    overrides: Iterable[str] = (),
    known_extra: Iterable[str] = (),
) -> PanelConfig:
    """Load the parameters file (default: the paper's) and apply ``KEY=VALUE`` overrides."""
    values = read_params_file(path if path is not None else default_params_path())
    for text in overrides:
        key, value = parse_override(text)
        values[key] = value
    return config_from_flat(values, known_extra)

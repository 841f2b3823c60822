"""The rig's configuration: a validated, frozen dataclass read from a ROS 2 parameters file.

The YAML is a ROS 2 parameters file (``panel_rig: ros__parameters: {...}``) with nested groups;
keys are addressed by dotted names (``panel.length_m``). Every value is checked for type, sign and
range, and the error names the offending key.
"""

from __future__ import annotations

import dataclasses
import math
import re
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
    running_sum: str = "inclusive"
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


@dataclass(frozen=True)
class _Spec:
    """One physics parameter: its PanelConfig field, type, check and rule; numeric bounds (``lo``/``hi``,
    ``None`` for none) are also published in the node's parameter descriptors."""

    field: str
    kind: type
    ok: Callable[[Any], bool]
    rule: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()  # a text parameter's values

    def bool_as_choice(self, value: Any) -> Any:
        """A YAML 1.1 boolean given for a choice among whose values is "off" (or "on") is that text: YAML reads
        ``spectrum: off`` and ``--set tunnel.turbulence.spectrum=off`` as false. Any other value is unchanged."""
        if isinstance(value, bool) and ("on" if value else "off") in self.choices:
            return "on" if value else "off"
        return value

    def check(self, key: str, value: Any) -> Any:
        """Coerce and validate one value; raise ConfigError naming ``key``."""
        value = self.bool_as_choice(value)
        if self.kind is float:
            value = number_if_text(value)  # `5e-6`: text to YAML 1.1, a number to rcl and to the reader
            if isinstance(value, str) and value.strip().lower().lstrip("+-.") in ("inf", "infinity", "nan"):
                raise ConfigError(f"{key}: must be a finite number, got {value!r}")  # not "expected a number"
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{key}: expected a number, got {value!r}")
            value = float(value)
            if not math.isfinite(value):
                raise ConfigError(f"{key}: must be finite, got {value!r}")
        elif self.kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{key}: expected an integer, got {value!r}")
        elif not isinstance(value, self.kind):
            hint = " (YAML reads no/off/false/yes/on/true as a boolean: quote the text)" if isinstance(value, bool) else ""
            raise ConfigError(f"{key}: expected {self.kind.__name__}, got {value!r}{hint}")
        if not self.ok(value):
            raise ConfigError(f"{key}: {self.rule}, got {value!r}")
        return value


#: the longest duration or dwell any command takes, simulated s (README: bad input)
MAX_DURATION_S = 3600.0


def interval_rule(lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False
                  ) -> tuple[Callable[[float], bool], str]:
    """(test, rule text) of the interval lo..hi, either end open or absent (None)."""
    def ok(v: float) -> bool:
        above = lo is None or (v > lo if lo_open else v >= lo)
        below = hi is None or (v < hi if hi_open else v <= hi)
        return above and below

    if lo is not None and hi is not None:
        rule = f"must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    elif lo is not None:
        rule = f"must be {'>' if lo_open else '>='} {lo:g}"
    else:
        rule = f"must be {'<' if hi_open else '<='} {hi:g}"
    return ok, rule


def _num(field: str, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
         hi_open: bool = False, kind: type = float) -> _Spec:
    """A number (``kind`` float or int) in the interval lo..hi."""
    ok, rule = interval_rule(lo, hi, lo_open, hi_open)
    return _Spec(field, kind, ok, rule, lo, hi)


def _choice(field: str, choices: tuple[str, ...]) -> _Spec:
    return _Spec(field, str, lambda v: v in choices, f"must be one of {choices}", choices=choices)


LOAD_POINTS = ("quarter", "three_quarter", "center")
RUNNING_SUMS = ("inclusive", "midpoint", "vortex")  # = panel_rig.model.aerodynamics.RUNNING_SUM_OWN's keys
TURBULENCE_SPECTRA = ("dryden", "von_karman", "off")  # = panel_rig.rig.turbulence.SPECTRA (config is the top layer)

SCHEMA: dict[str, _Spec] = {
    # physical bounds, wide for studies: a tunnel's panel and airfoil, solids from foam to the densest metal and the
    # softest rubber to diamond (1e300 m overflowed with a traceback, 1e-300 kg/m^3 gave NaN frequencies)
    "panel.length_m": _num("panel_length_m", 1e-3, 10.0),
    "panel.thickness_m": _num("panel_thickness_m", 1e-6, 0.1),
    "airfoil.length_m": _num("airfoil_length_m", 0.0, 10.0),
    "material.density_kgpm3": _num("density_kgpm3", 1.0, 1e5),
    "material.youngs_modulus_pa": _num("youngs_modulus_pa", 1e3, 1e13),
    "material.poisson_ratio": _num("poisson_ratio", -1.0, 0.5, lo_open=True, hi_open=True),
    "structure.damping_ratio": _num("damping_ratio", 0.0, 1.0, hi_open=True),
    "structure.modes": _num("n_modes", 1, 12, kind=int),
    "air.density_kgpm3": _num("air_density_kgpm3", 0.0, 1e3),
    "aero.elements": _num("n_elements", 4, 2000, kind=int),
    "aero.wake_elements": _num("n_wake", 2, 20000, kind=int),
    "aero.wake_relaxation": _num("wake_relaxation", 0.0, 1.0, lo_open=True, hi_open=True),
    "aero.rom_modes": _num("rom_modes", 1, kind=int),
    "aero.load_point": _choice("load_point", LOAD_POINTS),
    "aero.running_sum": _choice("running_sum", RUNNING_SUMS),
    # from 1 us: a step of 1 ns was taken, and `lco --duration 1` then marched 1e9 steps (~17 min) without a word
    "sim.dt_s": _num("dt_s", 1e-6, 0.01),
    # the stepper's divergence bound: |w/L| = 2 is twice past any inextensible panel (1e300 let a cubic panel
    # swing to 179 L and report it as an LCO)
    "sim.max_tip_w_over_L": _num("max_tip_w_over_L", 0.0, 2.0, lo_open=True),
    "tunnel.turbulence.intensity": _num("turbulence_intensity", 0.0, 0.2),  # sigma / U
    "tunnel.turbulence.length_scale_m": _num("turbulence_length_scale_m", 1e-3, 100.0),
    "tunnel.turbulence.spectrum": _choice("turbulence_spectrum", TURBULENCE_SPECTRA),
    "tunnel.turbulence.seed": _num("turbulence_seed", 0, 2**63 - 1, kind=int),
    "sensor.tip_noise_m": _num("sensor_tip_noise_m", 0.0, 0.1),
    "sensor.resolution_m": _num("sensor_resolution_m", 0.0, 0.1),
    "sensor.bandwidth_hz": _num("sensor_bandwidth_hz", 0.0),  # 0: unlimited
    "sensor.latency_s": _num("sensor_latency_s", 0.0, 1.0),
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


class _StrictLoader(yaml.SafeLoader):
    """yaml's safe loader, except that a key given twice in one mapping is an error (the safe loader keeps the last
    silently: a spec listing ``panel.thickness_m`` twice in ``vary`` lost the first list without a word)."""


def _unique_mapping(loader: _StrictLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key {key!r} given twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=True)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_yaml_file(path: str | Path, what: str) -> Any:
    """The YAML document of a file; ConfigError with one line ('<what> not found: PATH', or 'PATH: malformed YAML
    (line N; the parser's complaint)', not UTF-8 text, unreadable) when it cannot be read."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{what} {p} is a directory, not a file")
    if not p.is_file():
        raise ConfigError(f"{what} not found: {p}")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a UTF-8 text file (byte {exc.start}); is it the {what}?") from None
    except OSError as exc:
        raise ConfigError(f"{what} {p} cannot be read: {exc.strerror or exc}") from None
    try:
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        mark, problem = getattr(exc, "problem_mark", None), getattr(exc, "problem", None)
        detail = "; ".join(x for x in (f"line {mark.line + 1}" if mark is not None else "", problem or "") if x)
        raise ConfigError(f"{p}: malformed YAML" + (f" ({detail})" if detail else "")) from None


def read_params_file(path: str | Path) -> dict[str, Any]:
    """Read ``panel_rig: ros__parameters:`` (or ``/**:``) from a ROS 2 parameters file, flattened."""
    p = Path(path)
    doc = load_yaml_file(p, "parameters file")
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


_NUMBER_TEXT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def float_from_text(text: str) -> float | None:
    """The number a text of digits spells (``5e-06``, ``1e3``, ``7.06e10``: YAML 1.1 leaves them text, rcl's
    parameter parser reads them as numbers, and so do we), or None; not Python's wider syntax (``1_0``, ``nan``,
    ``infinity``)."""
    return float(text) if _NUMBER_TEXT.fullmatch(text.strip()) else None


def number_if_text(value: Any) -> Any:
    """``value`` as :func:`float_from_text` reads it when it is a text spelling a number; unchanged otherwise."""
    number = float_from_text(value) if isinstance(value, str) else None
    return value if number is None else number


def parse_override(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` with VALUE parsed as a YAML scalar (a number YAML 1.1 leaves as text, ``5e-6``, is taken as
    the number by the key's check, :func:`float_from_text`, as from a file)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"--set expects KEY=VALUE, got {text!r}")
    if not raw.strip():  # YAML reads nothing as null: "expected a number, got None" named no mistake of the user's
        raise ConfigError(f"--set {key.strip()}= has no value (KEY=VALUE)")
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

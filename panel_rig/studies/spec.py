"""A study file (YAML) read, validated and expanded into its cases. No dask here: this is plain data.

    kind: flutter_map            # flutter_map | uncertainty | bifurcation
    vary:                        # dotted config keys (panel_rig.config.SCHEMA, as --set accepts)
      panel.thickness_m: [0.0003, 0.00036, 0.0005]         # a list
      panel.length_m: {start: 0.20, stop: 0.30, num: 6}    # or a range (flutter_map, bifurcation)
    set: {aero.rom_modes: 12}    # fixed overrides

uncertainty: ``vary`` values are distributions ``{normal: [mean, sd]}``, ``{uniform: [lo, hi]}``,
``{choice: [...]}``, with ``samples`` and ``seed``. bifurcation: ``airspeeds`` (list or range), ``variants``,
``direction`` (up | down | both), ``duration_s``; ``vary`` optional. Every error is a ConfigError whose one-line
message names the offending key (the CLI exits 2 with it). docs/studies.md has the full reference.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from panel_rig.config import SCHEMA, ConfigError, config_from_flat, load_yaml_file, number_if_text, read_params_file
from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.model.options import DEFAULT_AERO, DEFAULT_SCHEME, DEFAULT_VARIANT, RIG_AERO_MODELS, SCHEMES, VARIANTS

KINDS = ("flutter_map", "uncertainty", "bifurcation")
FLUTTER_AERO = ("rom", "full")  # the aerodynamic models of the linear flutter analysis (panel-rig flutter --aero)
FORMULATIONS = ("discrete", "continuous")  # panel-rig flutter --formulation
DIRECTIONS = ("up", "down", "both")
DISTRIBUTIONS = ("normal", "uniform", "choice")
RANGE_KEYS = ("start", "stop", "num")
#: keys each kind accepts (anything else is rejected, naming the key)
KEYS: dict[str, tuple[str, ...]] = {
    "flutter_map": ("kind", "vary", "set", "aero", "formulation", "batch"),
    "uncertainty": ("kind", "vary", "set", "aero", "formulation", "batch", "samples", "seed"),
    "bifurcation": ("kind", "vary", "set", "aero", "scheme", "airspeeds", "variants", "direction", "duration_s"),
}
MAX_CASES = 10_000_000
#: Dask tasks of one flutter study (cases / batch): a study of 100,000 one-case tasks had stored 1,571 cases 75 s
#: after its start here; 1,000,000 made a 73 MiB graph whose submission failed after 60 s ("timed out after 60 s.")
MAX_TASKS = 100_000


@dataclass(frozen=True)
class Chain:
    """One bifurcation chain: the branches (directions) of one configuration and variant, marched together in
    one BatchStepper, airspeed step by airspeed step. ``cases[b][k]`` is the case index of branch b, step k."""

    grid_index: int
    variant: str
    directions: tuple[str, ...]
    cases: tuple[tuple[int, ...], ...]


@dataclass(frozen=True)
class Study:
    kind: str
    base: dict[str, Any]  # the flat parameters (file + set), validated
    keys: tuple[str, ...]  # the varied config keys, in spec order
    cases: list[dict[str, Any]]  # per case: {varied key: value} (+ variant, direction, airspeed_mps for bifurcation)
    options: dict[str, Any]  # aero, formulation, batch | scheme, duration_s, airspeeds, variants, direction
    spec: dict[str, Any]  # the spec as read
    fingerprint: str
    chains: list[Chain] = field(default_factory=list)
    grid: list[dict[str, Any]] = field(default_factory=list)  # bifurcation: the configurations (varied keys)
    levels: dict[str, list[Any]] = field(default_factory=dict)  # flutter_map: each key's values, in order

    def config_values(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The flat configuration of a case (base + its varied config keys)."""
        return {**self.base, **{k: params[k] for k in self.keys}}


def _fail(where: str, message: str) -> ConfigError:
    return ConfigError(f"{where}: {message}")


def _check_keys(where: str, given: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
    for k in given:
        if k not in allowed:
            raise _fail(where, f"unknown key {k!r} (known: {', '.join(allowed)})")


def _value(where: str, key: str, value: Any) -> Any:
    """One value of a config key, checked by the config schema (ints that are whole floats accepted)."""
    spec = SCHEMA[key]
    if spec.kind is int and isinstance(value, float) and value.is_integer():
        value = int(value)
    try:
        return spec.check(key, value)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _config_key(where: str, key: Any) -> str:
    if not isinstance(key, str) or key not in SCHEMA:
        raise _fail(where, f"{key}: unknown parameter (known: {', '.join(sorted(SCHEMA))})")
    return key


def _number(where: str, x: Any, positive: bool = False, integer: bool = False) -> float:
    x = number_if_text(x)  # 7.06e10: text to YAML 1.1, a number to rcl's parser and to every reader here
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise _fail(where, f"expected a number, got {x!r}")
    if integer and not float(x).is_integer():
        raise _fail(where, f"expected an integer, got {x!r}")
    if positive and x <= 0:
        raise _fail(where, f"must be > 0, got {x!r}")
    return x


def _levels(where: str, key: str, raw: Any) -> list[Any]:
    """A list, or {start, stop, num}, of values of one config key."""
    if isinstance(raw, Mapping):
        _check_keys(where, raw, RANGE_KEYS)
        missing = [k for k in RANGE_KEYS if k not in raw]
        if missing:
            raise _fail(where, f"a range needs {', '.join(RANGE_KEYS)} (missing {missing[0]})")
        num = int(_number(f"{where}.num", raw["num"], positive=True, integer=True))
        if num > MAX_CASES:
            raise _fail(f"{where}.num", f"{num} values exceed {MAX_CASES} cases")
        values = np.linspace(_number(f"{where}.start", raw["start"]), _number(f"{where}.stop", raw["stop"]), num)
        out = [float(v) for v in values]
    elif isinstance(raw, list) and raw:
        out = list(raw)
    else:
        raise _fail(where, f"expected a non-empty list or {{start, stop, num}}, got {raw!r}")
    values = [_value(where, key, v) for v in out]
    if len(set(values)) != len(values):
        raise _fail(where, "lists a value twice (a case would be computed twice)")
    return values


def _count(where: str, n: int) -> int:
    """``n`` cases, refused before they are built when they are too many."""
    if n > MAX_CASES:
        raise _fail(where, f"{n} cases exceed {MAX_CASES}")
    return n


def _samples(where: str, key: str, raw: Any, n: int, rng: np.random.Generator) -> list[Any]:
    """n draws of one config key from {normal: [mean, sd]} | {uniform: [lo, hi]} | {choice: [...]}."""
    if not isinstance(raw, Mapping) or len(raw) != 1:
        raise _fail(where, f"expected one of {{normal: [mean, sd]}}, {{uniform: [lo, hi]}}, {{choice: [...]}}, "
                           f"got {raw!r}")
    (dist, args), = raw.items()
    if dist not in DISTRIBUTIONS:
        raise _fail(where, f"unknown distribution {dist!r} (known: {', '.join(DISTRIBUTIONS)})")
    if not isinstance(args, list) or not args:
        raise _fail(f"{where}.{dist}", f"expected a list, got {args!r}")
    if dist == "choice":
        picks = rng.integers(0, len(args), n)
        values = [args[i] for i in picks]
        for v in args:
            _value(f"{where}.choice", key, v)
    else:
        if SCHEMA[key].kind is not float:
            raise _fail(f"{where}.{dist}", f"{key} takes {SCHEMA[key].kind.__name__} values: use choice")
        if len(args) != 2:
            raise _fail(f"{where}.{dist}", f"expected [a, b], got {args!r}")
        a, b = (_number(f"{where}.{dist}", x) for x in args)
        if dist == "normal":
            if b < 0:
                raise _fail(f"{where}.normal", f"sd must be >= 0, got {b!r}")
            draws = rng.normal(a, b, n)
        else:
            if b < a:
                raise _fail(f"{where}.uniform", f"needs lo <= hi, got {args!r}")
            draws = rng.uniform(a, b, n)
        values = [float(v) for v in draws]
    for i, v in enumerate(values):
        try:
            values[i] = SCHEMA[key].check(key, v)
        except ConfigError as exc:
            raise _fail(where, f"sample {i}: {exc} (narrow the distribution)") from None
    return values


def _choice(where: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise _fail(where, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


#: spec keys that tune how a study runs, not what it computes: a change of them resumes the same study
EXECUTION_KEYS = ("batch",)


def fingerprint(spec: Mapping[str, Any], base: Mapping[str, Any]) -> str:
    """Identity of a study: the spec as read (less its EXECUTION_KEYS) and the base parameters (resume refuses a
    different study); a flutter study's also the top of its airspeed scan (it was 60 m/s, now MAX_AIRSPEED_MPS: a
    store begun with the old scan is not resumed with the new one)."""
    what = {k: v for k, v in spec.items() if k not in EXECUTION_KEYS}
    identity: dict[str, Any] = {"spec": what, "base": base}
    if spec.get("kind") != "bifurcation":
        identity["flutter_scan_top_mps"] = MAX_AIRSPEED_MPS
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def load_spec(path: str | Path, params: str | Path | None = None) -> Study:
    """Read and expand a study file; ``params`` is the base parameters file (default the paper's)."""
    p = Path(path)
    raw = load_yaml_file(p, "spec file")
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{p}: expected a mapping with 'kind:'")
    from panel_rig.config import default_params_path

    base = read_params_file(params if params is not None else default_params_path())
    return parse_spec(raw, base)


def parse_spec(raw: Mapping[str, Any], base_file: Mapping[str, Any]) -> Study:
    """Validate a spec mapping against the config schema and expand it into cases."""
    kind = raw.get("kind")
    if kind not in KINDS:
        raise _fail("kind", f"must be one of {', '.join(KINDS)}, got {kind!r}")
    _check_keys("spec", raw, KEYS[kind])
    fixed = raw.get("set") or {}
    if not isinstance(fixed, Mapping):
        raise _fail("set", f"expected a mapping of dotted keys, got {fixed!r}")
    base = dict(base_file)
    for k, v in fixed.items():
        key = _config_key("set", k)
        base[key] = _value("set", key, v)
    config_from_flat(base)  # the fixed part alone must be a valid configuration
    vary = raw.get("vary") or {}
    if not isinstance(vary, Mapping):
        raise _fail("vary", f"expected a mapping of dotted keys, got {vary!r}")
    if not vary and kind != "bifurcation":
        raise _fail("vary", "needs at least one dotted config key")
    keys = tuple(_config_key("vary", k) for k in vary)
    both = [k for k in keys if k in {_config_key("set", f) for f in fixed}]
    if both:  # the varied value silently won over the set one
        raise _fail("vary", f"{both[0]} is in both set and vary: give it in one of them")
    aero_choices = RIG_AERO_MODELS if kind == "bifurcation" else FLUTTER_AERO
    options: dict[str, Any] = {"aero": _choice("aero", raw.get("aero", DEFAULT_AERO), aero_choices)}
    if kind != "bifurcation":
        options["formulation"] = _choice("formulation", raw.get("formulation", "discrete"), FORMULATIONS)
        options["batch"] = int(_number("batch", raw.get("batch", 1), positive=True, integer=True))
    study_kw: dict[str, Any] = {}
    if kind == "flutter_map":
        levels = {k: _levels(f"vary.{k}", k, v) for k, v in vary.items()}
        _count("vary", math.prod(len(v) for v in levels.values()))
        cases = [dict(zip(keys, combo)) for combo in itertools.product(*levels.values())]
        study_kw["levels"] = levels
    elif kind == "uncertainty":
        n = _count("samples", int(_number("samples", raw.get("samples", 0), positive=True, integer=True)))
        seed = int(_number("seed", raw.get("seed", 0), integer=True))
        if seed < 0:
            raise _fail("seed", f"must be >= 0, got {seed}")
        rng = np.random.default_rng(seed)
        columns = {k: _samples(f"vary.{k}", k, v, n, rng) for k, v in vary.items()}
        cases = [{k: columns[k][i] for k in keys} for i in range(n)]
        options.update(samples=n, seed=seed)
    else:
        cases, study_kw = _bifurcation(raw, vary, keys, options)
        step_s = max(config_from_flat({**base, **point}).dt_s for point in study_kw["grid"])
        if options["duration_s"] < step_s:
            raise _fail("duration_s", f"must be at least one physics step ({step_s:g} s), got {options['duration_s']:g}")
    if len(cases) > MAX_CASES:
        raise _fail("vary", f"{len(cases)} cases exceed {MAX_CASES}")
    if "batch" in options and math.ceil(len(cases) / options["batch"]) > MAX_TASKS:
        least = math.ceil(len(cases) / MAX_TASKS)
        raise _fail("batch", f"{len(cases)} cases in batches of {options['batch']} are "
                             f"{math.ceil(len(cases) / options['batch'])} Dask tasks, more than {MAX_TASKS} (the "
                             f"scheduler does not take such a graph in time): set batch: {least} or more")
    for i, c in enumerate(cases):  # every case's whole configuration is valid
        try:
            config_from_flat({**base, **{k: c[k] for k in keys}})
        except ConfigError as exc:
            raise _fail("vary", f"case {i}: {exc}") from None
    return Study(kind, base, keys, cases, options, dict(raw), fingerprint(raw, base), **study_kw)


def _bifurcation(raw: Mapping[str, Any], vary: Mapping[str, Any], keys: tuple[str, ...], options: dict[str, Any]
                 ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    if "airspeeds" not in raw:
        raise _fail("airspeeds", "required for bifurcation (a list or {start, stop, num}, m/s)")
    a = raw["airspeeds"]
    if isinstance(a, Mapping):
        _check_keys("airspeeds", a, RANGE_KEYS)
        if any(k not in a for k in RANGE_KEYS):
            raise _fail("airspeeds", f"a range needs {', '.join(RANGE_KEYS)}")
        num = _count("airspeeds.num", int(_number("airspeeds.num", a["num"], positive=True, integer=True)))
        speeds = np.linspace(_number("airspeeds.start", a["start"]), _number("airspeeds.stop", a["stop"]), num)
    elif isinstance(a, list) and a:
        speeds = np.array([_number("airspeeds", u) for u in a], dtype=float)
    else:
        raise _fail("airspeeds", f"expected a non-empty list or {{start, stop, num}}, got {a!r}")
    if np.any(speeds < 0) or np.any(speeds > MAX_AIRSPEED_MPS) or np.any(np.diff(speeds) <= 0):
        raise _fail("airspeeds", f"must increase strictly, within [0, {MAX_AIRSPEED_MPS:g}] m/s (the incompressible "
                                 "lattice holds to about Mach 0.3)")
    variants = raw.get("variants", [DEFAULT_VARIANT])
    if not isinstance(variants, list) or not variants:
        raise _fail("variants", f"expected a non-empty list of {', '.join(VARIANTS)}, got {variants!r}")
    for v in variants:
        _choice("variants", v, tuple(VARIANTS))
    if len(set(variants)) != len(variants):
        raise _fail("variants", "lists a variant twice")
    direction = _choice("direction", raw.get("direction", "both"), DIRECTIONS)
    duration = float(_number("duration_s", raw.get("duration_s", 30.0), positive=True))
    if duration > 3600:
        raise _fail("duration_s", f"must be <= 3600 s, got {duration}")
    options.update(scheme=_choice("scheme", raw.get("scheme", DEFAULT_SCHEME), SCHEMES),
                   airspeeds=[float(u) for u in speeds], variants=list(variants), direction=direction,
                   duration_s=duration)
    levels = {k: _levels(f"vary.{k}", k, v) for k, v in vary.items()}
    directions = ("up", "down") if direction == "both" else (direction,)
    _count("vary", math.prod(len(v) for v in levels.values()) * len(variants) * len(directions) * len(speeds))
    grid = [dict(zip(keys, combo)) for combo in itertools.product(*levels.values())] if keys else [{}]
    cases: list[dict[str, Any]] = []
    chains: list[Chain] = []
    for g, point in enumerate(grid):
        for variant in variants:
            branches = []
            for d in directions:
                order = speeds if d == "up" else speeds[::-1]
                branch = []
                for k, u in enumerate(order):
                    branch.append(len(cases))
                    cases.append({**point, "variant": variant, "direction": d, "airspeed_mps": float(u), "step": k})
                branches.append(tuple(branch))
            chains.append(Chain(g, variant, directions, tuple(branches)))
    return cases, {"chains": chains, "grid": grid, "levels": levels}

"""What a worker computes: a batch of flutter cases, or one link of a bifurcation chain. Pure functions of plain
data (dicts, lists, arrays), calling the analysis and model layers; no dask, no files.
"""

from __future__ import annotations

import os
import time
from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np

from panel_rig.analysis.flutter import UnstableAtScanStart, eigenvalues, find_flutter
from panel_rig.analysis.lco import INITIAL_Q, diverged_result, lco_metrics
from panel_rig.config import PanelConfig, config_from_flat, load_config
from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import BatchStepper, Stepper

#: case status (flutter kinds): flutter found, none below the scan's top (MAX_AIRSPEED_MPS, as `panel-rig flutter`),
#: the computation failed, unstable already at the scan's 1 m/s (a result, not a failure: with the ROM at low
#: damping, its error at high reduced frequency)
FOUND, NO_FLUTTER, FAILED, UNSTABLE_AT_START = 0, 1, 2, 3
#: the NO_FLUTTER count's name in a study's summary (before 2026-12-06 the scan, and the name, stopped at 60 m/s)
NO_FLUTTER_KEY = f"no_flutter_below_{MAX_AIRSPEED_MPS:g}_mps"
#: the codes' meanings, in the store as the ``status`` variable's CF flag attributes (flag_values, flag_meanings)
STATUS_MEANINGS = {FOUND: "flutter_found", NO_FLUTTER: NO_FLUTTER_KEY, FAILED: "computation_failed",
                   UNSTABLE_AT_START: "unstable_at_1_mps"}
FLUTTER_VARS = ("flutter_speed_mps", "flutter_frequency_hz", "dominant_mode", "status", "compute_s")
BIFURCATION_VARS = ("rms_tip_w_over_L", "peak_tip_w_over_L", "dominant_frequency_hz", "steady_after_s", "diverged",
                    "compute_s")

#: how many times this process warmed the kernels (a test checks: once per worker process)
WARMUPS = 0


def warm_up(kind: str = "bifurcation") -> dict[str, Any]:
    """Import the analysis stack and load the compiled kernels a study of ``kind`` calls (numba's cache), once per
    worker: the flutter kinds need only the eigenvalue path (ROM and full lattice); bifurcation the steppers."""
    global WARMUPS
    t0 = time.perf_counter()
    cfg = load_config()
    model = AeroelasticModel(cfg)
    eigenvalues(model, 10.0, aero="rom", rom_modes=cfg.rom_modes)
    if kind == "bifurcation":
        st = Stepper(cfg, model=model)
        st.advance(2, 5.0)
        BatchStepper(st, 2).advance(2, np.array([5.0, 6.0]))
    WARMUPS += 1
    return {"pid": os.getpid(), "warm_s": time.perf_counter() - t0, "warmups": WARMUPS}


def warmups() -> int:
    return WARMUPS


def flutter_case(values: Mapping[str, Any], aero: str = "rom", formulation: str = "discrete") -> dict[str, Any]:
    """The linear flutter point of one configuration, as ``panel-rig flutter --aero A --formulation F`` computes it
    (ROM with aero.rom_modes modes, scan 1..100 m/s then Brent)."""
    t0 = time.perf_counter()
    cfg = config_from_flat(values)
    out = {"flutter_speed_mps": np.nan, "flutter_frequency_hz": np.nan, "dominant_mode": 0, "status": NO_FLUTTER}
    try:
        fp = find_flutter(AeroelasticModel(cfg), aero=aero, rom_modes=cfg.rom_modes if aero == "rom" else None,
                          formulation=formulation)
    except UnstableAtScanStart:
        fp, out["status"] = None, UNSTABLE_AT_START
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):  # singular system, ...
        fp, out["status"] = None, FAILED
    if fp is not None:
        out.update(flutter_speed_mps=float(fp.speed_mps), flutter_frequency_hz=float(fp.frequency_hz),
                   dominant_mode=int(fp.dominant_mode), status=FOUND)
    out["compute_s"] = time.perf_counter() - t0
    return out


def flutter_batch(base: Mapping[str, Any], params: Sequence[Mapping[str, Any]], aero: str, formulation: str
                  ) -> list[dict[str, Any]]:
    """Several flutter cases in one task (amortises the scheduler's per-task cost on big studies)."""
    return [flutter_case({**base, **p}, aero, formulation) for p in params]


@lru_cache(maxsize=8)
def _template(cfg: PanelConfig, variant: str, aero: str, scheme: str) -> Stepper:
    """One stepper per configuration and variant, kept by the worker across the links of its chains."""
    return Stepper(cfg, variant=variant, aero=aero, scheme=scheme)


def state_size(cfg: PanelConfig, aero: str) -> int:
    """Length of a flattened state (q, q_dot, xi) for this configuration and aerodynamic model."""
    return int(_template(cfg, "linear", aero, "implicit").kernel_model.Qxi.shape[1] + 2 * cfg.n_modes)


def bifurcation_link(values: Mapping[str, Any], variant: str, aero: str, scheme: str, speeds: Sequence[float],
                     duration_s: float, prev: Mapping[str, Any] | None) -> dict[str, Any]:
    """One airspeed step of every branch of a chain, marched together by a BatchStepper (branch b at speeds[b]).

    Each branch starts from its state at the end of the previous link (``prev``: the previous result), or from
    the small second-mode disturbance of ``panel-rig lco`` for the first link; a branch that diverged stays
    diverged. Returns per-branch metrics (as ``panel-rig lco``) and the final states.
    """
    t0 = time.perf_counter()
    cfg = config_from_flat(values)
    template = _template(cfg, variant, aero, scheme)
    speeds = np.asarray(speeds, dtype=float)
    B, n = speeds.size, template.n_modes
    batch = BatchStepper(template, B)
    if prev is None:
        batch.q[:, : len(INITIAL_Q)] = np.array(INITIAL_Q)[:n]
        was_diverged = np.zeros(B, dtype=bool)
    else:
        state = np.asarray(prev["state"], dtype=float)
        batch.q[:], batch.qdot[:], batch.xi[:] = state[:, :n], state[:, n : 2 * n], state[:, 2 * n :]
        was_diverged = np.asarray(prev["diverged"], dtype=bool)
        batch.active[:] = ~was_diverged
    n_total = int(round(duration_s / template.dt_s))
    n_chunk = int(round(1.0 / template.dt_s))
    tips = np.empty((B, n_total))
    for start in range(0, n_total, n_chunk):
        k = min(n_chunk, n_total - start)
        tips[:, start : start + k] = batch.advance(k, speeds)
    results = []
    for b, u in enumerate(speeds):
        if was_diverged[b]:
            r = diverged_result(float(u), float("nan")).as_dict()
        elif batch.diverged[b]:
            r = diverged_result(float(u), int(np.argmax(np.isnan(tips[b]))) * template.dt_s).as_dict()
        else:
            r = lco_metrics(tips[b], template.dt_s, float(u)).as_dict()
        results.append({k: (np.nan if r[k] is None else r[k]) for k in BIFURCATION_VARS if k != "compute_s"})
    diverged = was_diverged | batch.diverged
    elapsed = time.perf_counter() - t0
    for r in results:
        r["compute_s"] = elapsed / B
    return {"results": results, "state": np.hstack([batch.q, batch.qdot, batch.xi]), "diverged": diverged}

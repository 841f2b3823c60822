"""Speed benchmarks: prints ratios (simulated seconds per wall second) and wall times.

    python benchmarks/run.py [--json] [--node] [--study]

One core, nonlinear `full` variant (and `exact`, keys exact_*), dt = 1/2048 s, near the flutter speed (1.05 U_f).
`turbulence_rom_realtime_factor`: the same ROM march in the configured tunnel turbulence (issue 9: at most 30 %
slower, `turbulence_cost_fraction` <= 0.3); `*_first_10s`: its first 10 s alone (small amplitude: the worst case).
--node adds the live node's 60 s real-time measurement (benchmarks/node_realtime.py), its start-up time,
cold and warm (benchmarks/startup.py), and the closed-loop latency with the 500 Hz controller attached
(benchmarks/control_latency.py). --study adds the parameter-study benchmark (benchmarks/study.py).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from panel_rig.analysis.flutter import find_flutter  # noqa: E402
from panel_rig.analysis.forced import BANDS_HZ, forced_sweep  # noqa: E402
from panel_rig.analysis.lco import lco_sweep  # noqa: E402
from panel_rig.config import load_config  # noqa: E402
from panel_rig.model.aeroelastic import AeroelasticModel  # noqa: E402
from panel_rig.model.options import PAPER_VARIANTS  # noqa: E402
from panel_rig.model.stepper import Stepper  # noqa: E402


def realtime_factor(stepper: Stepper, airspeed_mps: float, sim_s: float) -> float:
    stepper.reset(q=[0.0, 1e-3, 0.0])
    stepper.advance(16, airspeed_mps)  # compile / warm
    stepper.reset(q=[0.0, 1e-3, 0.0])
    n = int(sim_s / stepper.dt_s)
    t0 = time.perf_counter()
    stepper.advance(n, airspeed_mps)
    return sim_s / (time.perf_counter() - t0)


def turbulence_realtime_factor(stepper: Stepper, airspeed_mps: float, sim_s: float, chunk_s: float = 0.125,
                               intensity: float | None = None) -> float:
    """As realtime_factor, in blocks as the rig marches (0.125 s: the node's fast mode marches 64 publish periods of
    1/500 s per call), with the configured tunnel turbulence (the field drawn per block, u' added to the airspeed,
    w' at every collocation point into the march); ``intensity`` 0: the same blocks in a quiet tunnel. Simulated
    seconds per second of this process's CPU time: the machine's other load moved wall-time figures of the same
    march by up to 1.7x between runs, the CPU time far less."""
    from panel_rig.rig.turbulence import Turbulence, TurbulenceSettings

    cfg = stepper.cfg if intensity is None else stepper.cfg.replace(turbulence_intensity=intensity)
    turb = Turbulence(TurbulenceSettings.from_config(cfg), stepper.dt_s, stepper.x_colloc_m, cfg.chord_m)
    if not turb.on:
        m = max(1, int(round(chunk_s / stepper.dt_s)))
        stepper.reset(q=[0.0, 1e-3, 0.0])
        n = int(sim_s / stepper.dt_s)
        t0 = time.process_time()
        for _ in range(n // m):
            stepper.advance(m, airspeed_mps)
        return (n // m) * m * stepper.dt_s / (time.process_time() - t0)
    m = max(1, int(round(chunk_s / stepper.dt_s)))
    U = np.full(m, airspeed_mps)
    u_p, w_p = turb.block(U[:16])  # compile / warm
    stepper.reset(q=[0.0, 1e-3, 0.0])
    stepper.advance(16, U[:16] + u_p, gust_upwash_mps=w_p)
    stepper.reset(q=[0.0, 1e-3, 0.0])
    n = int(sim_s / stepper.dt_s)
    t0 = time.process_time()
    for _ in range(n // m):
        u_p, w_p = turb.block(U)
        stepper.advance(m, U + u_p, gust_upwash_mps=w_p)
    return (n // m) * m * stepper.dt_s / (time.process_time() - t0)


def single_step_realtime_factor(stepper: Stepper, airspeed_mps: float, n: int = 20000) -> float:
    """As the live rig calls it: one step per call."""
    stepper.reset(q=[0.0, 1e-3, 0.0])
    t0 = time.perf_counter()
    for _ in range(n):
        stepper.step(airspeed_mps, 0.0)
    return n * stepper.dt_s / (time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--node", action="store_true", help="also run the 60 s node real-time benchmark")
    ap.add_argument("--study", action="store_true", help="also the 400-case Dask flutter map (benchmarks/study.py)")
    args = ap.parse_args()
    cfg = load_config()
    out: dict[str, float] = {}
    t0 = time.perf_counter()
    model = AeroelasticModel(cfg)
    fp = find_flutter(model, aero="full")
    out["flutter_full_order_wall_s"] = time.perf_counter() - t0
    u = 1.05 * fp.speed_mps
    out["rom_realtime_factor"] = realtime_factor(Stepper(cfg, "full", "rom", model=model), u, 60.0)
    # turbulence on vs off, both marched in the rig's blocks over the march of rom_realtime_factor (60 s from the
    # same start: the flutter grows into the LCO), interleaved, best of 5 each in CPU time (the least disturbed by
    # other load); and over its first 10 s alone, where the panel is still small and a step cheapest, so the
    # turbulence's fixed cost per step weighs most
    st = Stepper(cfg, "full", "rom", model=model)
    for key, sim_s, reps in (("", 60.0, 5), ("_first_10s", 10.0, 8)):
        off, on = [], []
        for _ in range(reps):
            off.append(turbulence_realtime_factor(st, u, sim_s, intensity=0.0))
            on.append(turbulence_realtime_factor(st, u, sim_s))
        out[f"turbulence_rom_realtime_factor{key}"] = max(on)
        out[f"turbulence_cost_fraction{key}"] = max(off) / max(on) - 1.0
    out["full_realtime_factor"] = realtime_factor(Stepper(cfg, "full", "full", model=model), u, 30.0)
    out["rom_single_step_realtime_factor"] = single_step_realtime_factor(Stepper(cfg, "full", "rom", model=model), u)
    # the exact (elastica) structure: at 1.05 U_f (the same operating point) and deep in the LCO (2.5 U_f,
    # tip angles above a radian: more Newton iterations)
    out["exact_rom_realtime_factor"] = realtime_factor(Stepper(cfg, "exact", "rom", model=model), u, 60.0)
    out["exact_rom_2p5Uf_realtime_factor"] = realtime_factor(Stepper(cfg, "exact", "rom", model=model),
                                                             2.5 / 1.05 * u, 30.0)
    out["exact_full_realtime_factor"] = realtime_factor(Stepper(cfg, "exact", "full", model=model), u, 20.0)
    t0 = time.perf_counter()
    lco_sweep(cfg, np.linspace(12.0, 32.0, 21) * fp.speed_mps / 12.5, 30.0, "full", model=model)
    out["fig8_sweep_21x30s_wall_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    for var in PAPER_VARIANTS:
        for lo, hi in BANDS_HZ:
            forced_sweep(cfg, lo, hi, 0.1, var, model=model)
    out["forced_protocol_4x2_wall_s"] = time.perf_counter() - t0
    try:
        from recorder_throughput import measure as recorder

        out.update(recorder())
    except Exception as exc:  # noqa: BLE001 - the recorder extra may be absent
        print(f"recorder benchmark skipped: {exc}", file=sys.stderr)
    if args.node:
        from control_latency import measure as control_latency
        from node_realtime import measure as node
        from startup import measure as startup

        out.update(node())
        out.update(startup())
        out.update(control_latency())
    if args.study:
        from study import measure as study

        out.update(study())
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:40s} {v:12.3f}" if isinstance(v, float) else f"{k:40s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

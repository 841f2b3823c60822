"""Parameter-study speed (issue 12): a 400-case flutter map serial vs on a 2-worker LocalCluster, the scheduler's
per-task overhead, and the inputs of the 100,000-case estimate in docs/studies.md.

    python benchmarks/study.py [--json] [--spec config/studies/flutter_map.yaml] [--workers 2] [--noop 2000]
                               [--full-aero]

--full-aero also runs config/studies/flutter_map_full.yaml (the same 400 cases with the full-order lattice, as
`panel-rig flutter` computes by default; ~0.4 s a case, ~7 min for the benchmark) and reports its keys with the
suffix ``_full_aero``: with cases 10x heavier, the cluster's fixed start-up cost weighs less.

serial: the same case function (panel_rig.studies.cases.flutter_case) in a plain loop in this process, no Dask,
one BLAS thread as in a Dask worker (set before numpy is imported; `run.py --study` imports numpy first).
cluster: `run_study` end to end (cluster start, warm-up, compute, Zarr writes), and its compute phase alone.
per-task overhead: wall time per no-op task on the same cluster (scheduler + comms + worker bookkeeping), and the
study's own: (wall of the compute phase x workers - sum of case compute times) / cases.
The machine's load (os.getloadavg) is printed before and after: the ratio means little on a busy machine.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

# the serial loop gets the BLAS settings Dask's nanny gives each worker (distributed.nanny.pre-spawn-environ):
# one thread; otherwise OpenBLAS's second thread spins on the core the other "worker" would use
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def serial(study) -> dict[str, float]:
    from panel_rig.studies.cases import flutter_case, warm_up

    warm_up(study.kind)
    load = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    times = [flutter_case(study.config_values(c), study.options["aero"], study.options["formulation"])["compute_s"]
             for c in study.cases]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"serial_wall_s": wall, "serial_case_mean_s": float(np.mean(times)), "serial_cpu_per_case_s": cpu / len(times),
            "serial_load_start": load, "serial_load_end": os.getloadavg()[0]}


def cluster(study, workers: int, noop: int) -> dict[str, float]:
    from dask.distributed import Client, LocalCluster

    from panel_rig.studies.runner import run_study

    out: dict[str, float] = {"cluster_load_start": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        info = run_study(study, Path(tmp) / "study", workers=workers)
        ds = info["store"].load()
        compute_wall = info["wall_s"] - info["ready_s"]
        case_sum = float(ds["compute_s"].sum())
        out.update(cluster_wall_s=info["wall_s"], cluster_ready_s=info["ready_s"], cluster_compute_wall_s=compute_wall,
                   cluster_write_s=info["write_s"], cluster_case_mean_s=case_sum / len(study.cases),
                   study_overhead_per_case_s=(compute_wall * workers - case_sum) / len(study.cases),
                   write_per_case_s=info["write_s"] / len(study.cases), cluster_load_end=os.getloadavg()[0])
    if not noop:
        return out
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.CRITICAL) as lc, Client(lc) as client:
        client.gather(client.map(lambda i: i, range(50), pure=False))  # connections up
        t0 = time.perf_counter()
        client.gather(client.map(lambda i: i, range(noop), pure=False))
        out["noop_task_overhead_s"] = (time.perf_counter() - t0) / noop
    return out


def measure(spec: str | Path = ROOT / "config" / "studies" / "flutter_map.yaml", workers: int = 2, noop: int = 2000,
            with_serial: bool = True) -> dict[str, float]:
    """Serial, cluster, serial again: the two serial runs bracket the cluster run, so a change of the machine's
    background load shows as a difference between them (the load average of each phase is recorded too)."""
    from panel_rig.studies.spec import load_spec

    study = load_spec(spec)
    res: dict[str, float] = {"study_cases": len(study.cases), "study_workers": workers, "cpus": os.cpu_count(),
                             "study_batch": study.options["batch"]}
    if with_serial:
        res.update(serial(study))
    res.update(cluster(study, workers, noop))
    if with_serial:
        after = serial(study)
        res.update({f"{k}_after": v for k, v in after.items()})
        mean = 0.5 * (res["serial_wall_s"] + after["serial_wall_s"])
        res["study_speedup_end_to_end"] = mean / res["cluster_wall_s"]
        res["study_speedup_compute_phase"] = mean / res["cluster_compute_wall_s"]
    return res


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--spec", default=str(ROOT / "config" / "studies" / "flutter_map.yaml"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--noop", type=int, default=2000, help="no-op tasks for the per-task overhead")
    ap.add_argument("--skip-serial", action="store_true")
    ap.add_argument("--full-aero", action="store_true", help="also the 400-case map with the full-order lattice")
    args = ap.parse_args()
    res = measure(args.spec, args.workers, args.noop, not args.skip_serial)
    if args.full_aero:
        full = measure(ROOT / "config" / "studies" / "flutter_map_full.yaml", args.workers, 0, not args.skip_serial)
        res.update({f"{k}_full_aero": v for k, v in full.items()})
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:32s} {v:12.4f}" if isinstance(v, float) else f"{k:32s} {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

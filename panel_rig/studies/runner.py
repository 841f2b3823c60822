"""Run a study on Dask: a LocalCluster (N worker processes, one thread each) or an existing scheduler.

Only the missing cases of the output store are submitted (resume after Ctrl-C, a crash or a lost worker).
Results are written to the store as they arrive (gathered for at most ``flush_s`` seconds and on the way out,
Ctrl-C included). Dask re-runs the tasks of a worker that dies; a case has one slot in the store, so a re-run
cannot duplicate it. Each worker warms the kernels once, in a worker plugin, when it starts.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import sys
import threading
import time
import urllib.parse
from concurrent.futures import CancelledError
from pathlib import Path
from typing import Any, Callable, Iterator

import dask
import numpy as np
from dask.distributed import Client, LocalCluster, WorkerPlugin, as_completed

from panel_rig.config import config_from_flat
from panel_rig.studies import cases as C
from panel_rig.studies.spec import Chain, Study
from panel_rig.studies.store import Store

STATUS_NAMES = {C.FOUND: "flutter", C.NO_FLUTTER: f"none below {C.MAX_AIRSPEED_MPS:g} m/s", C.FAILED: "failed",
                C.UNSTABLE_AT_START: "unstable at 1 m/s"}
#: what a lost worker, scheduler or connection raises (CommClosedError and dask's timeouts are OSErrors)
LOST = (OSError, CancelledError)
PLUGIN_TRIES = 3


class ClusterError(ValueError):
    """The Dask cluster could not be reached, or was lost during a study (what arrived is stored)."""


class WarmUp(WorkerPlugin):
    """Warm the compiled kernels a study of ``kind`` uses, once in every worker process (also in one that the nanny
    restarts); one plugin per kind, so a shared cluster warms the steppers when its first bifurcation study comes."""

    idempotent = True

    def __init__(self, kind: str, own_cluster: bool = False) -> None:
        self.kind = kind
        self.own_cluster = own_cluster
        self.name = f"panel-rig-warm-up-{kind}"

    def setup(self, worker: Any) -> None:
        # Ctrl-C at a terminal reaches the whole process group: the study's own LocalCluster workers leave the stop
        # to the client (it keeps what arrived and closes the cluster); each printed a KeyboardInterrupt traceback.
        # Workers of a cluster the user started keep their Ctrl-C.
        if self.own_cluster and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        C.warm_up(self.kind)


#: a scheduler port that refuses connections this long is taken for a wrong address (Dask's own connect kept
#: retrying for its whole 60 s timeout before `study --scheduler tcp://127.0.0.1:1` said anything)
REFUSED_GRACE_S = 10.0


def _scheme_host_port(address: str) -> tuple[str, str | None, int | None]:
    """(scheme, host, port) of tcp://HOST:PORT or HOST:PORT; ValueError for a port that is not one (99999)."""
    parts = urllib.parse.urlsplit(address if "://" in address else f"tcp://{address}")
    return parts.scheme, parts.hostname, parts.port


def refuses_connections(address: str, grace_s: float) -> bool:
    """True if the TCP host:port of ``address`` (tcp://HOST:PORT or HOST:PORT) refused every connection for
    ``grace_s`` (a scheduler still starting gets that long); False as soon as one connects, and for any other
    outcome (no route, a timeout, another protocol), which Dask's own timeout then decides."""
    try:
        scheme, host, port = _scheme_host_port(address)
    except ValueError:  # a port that is not a number: Dask's message says so
        return False
    if scheme != "tcp" or host is None or port is None:
        return False
    deadline = time.monotonic() + grace_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=grace_s):
                return False
        except ConnectionRefusedError:
            if time.monotonic() >= deadline:
                return True
            time.sleep(0.25)  # polling a remote port, not synchronising with our own work
        except OSError:
            return False


def scheduler_problem(scheduler: str, timeout_s: float = 60.0) -> str | None:
    """Why ``scheduler`` cannot be a study's: an address Dask cannot parse (``foo``: no port), or a TCP port that
    refuses connections (:func:`refuses_connections`). None when it may be one (Dask's own timeout decides the
    rest). A study checks this before it makes its store: a refused study left an empty results.zarr behind."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler if "://" in scheduler else f"tcp://{scheduler}")
        if scheme == "tcp":
            parse_host_port(location)
    except ValueError as exc:
        return f"--scheduler {scheduler}: not a Dask scheduler address ({exc}; e.g. tcp://HOST:8786)"
    if scheme == "tcp":  # what can be known at once (both waited out Dask's whole 60 s timeout)
        try:
            _, host, port = _scheme_host_port(scheduler)
        except ValueError as exc:  # a port above 65535
            return f"--scheduler {scheduler}: not a Dask scheduler address ({exc}; e.g. tcp://HOST:8786)"
        if host is not None and port is not None:
            try:
                socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            except socket.gaierror as exc:
                return f"cannot reach the Dask scheduler at {scheduler}: the host name {host} does not resolve ({exc})"
    grace_s = min(timeout_s, REFUSED_GRACE_S)
    if refuses_connections(scheduler, grace_s):
        return (f"cannot reach the Dask scheduler at {scheduler}: connection refused (nothing listens on that port; "
                f"tried for {grace_s:g} s)")
    return None


@contextlib.contextmanager
def connect(workers: int | None = None, scheduler: str | None = None, timeout_s: float = 60.0) -> Iterator[Client]:
    """A client of ``scheduler`` (an address), else of a new LocalCluster with ``workers`` processes."""
    if scheduler:
        problem = scheduler_problem(scheduler, timeout_s)
        if problem is not None:
            raise ClusterError(problem)
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s")
        except OSError as exc:
            raise ClusterError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            try:
                client.wait_for_workers(1, timeout=timeout_s)
            except OSError:
                raise ClusterError(f"the Dask scheduler at {scheduler} has no workers (waited {timeout_s:g} s)"
                                   ) from None
            yield client
        finally:
            client.close()
        return
    # Two Dask defaults cost a study's worker time (cases of ~40 ms made of many small numpy/LAPACK calls):
    # MALLOC_TRIM_THRESHOLD_ = 64 KiB (so that workers hand memory back to the OS) makes glibc return and re-fault
    # pages all the time: a case took 1.45x as long in a process with it (0.088 vs 0.060 s), 0.074 vs 0.052 s on a
    # worker; and the statistical profiler samples the running task every 10 ms, of no use without a dashboard.
    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), "MALLOC_TRIM_THRESHOLD_": 32 << 20}
    with environ_kept(), dask.config.set({"distributed.worker.profile.enabled": False,
                                          "distributed.nanny.pre-spawn-environ": environ}):
        # the scheduler's HTTP server starts whatever the dashboard setting; None puts it on 8787, and with another
        # cluster on the machine that printed "Port 8787 is already in use" on the study's stderr: any free port
        cluster = LocalCluster(n_workers=workers or 1, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=":0", silence_logs=logging.CRITICAL)
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()


@contextlib.contextmanager
def environ_kept() -> Iterator[None]:
    """This process's environment as it was, on leaving the block. Each nanny sets its workers' variables
    (``OPENBLAS_NUM_THREADS=1`` and the like, ``MALLOC_TRIM_THRESHOLD_``) in the *parent's* ``os.environ`` before it
    spawns one, and left them there: every later child of the process (a node, a `dask worker`) ran single-threaded
    BLAS and the allocator setting that costs small cases 1.45x."""
    before = dict(os.environ)
    try:
        yield
    finally:
        for key in set(os.environ) - set(before):
            del os.environ[key]
        os.environ.update(before)


def _register_warm_up(client: Client, kind: str, own_cluster: bool = False) -> None:
    """Install the warm-up plugin on every worker; a worker that dies meanwhile (its connection closes) is restarted
    by its nanny and gets the plugin on the next try."""
    for attempt in range(PLUGIN_TRIES):
        try:
            client.register_plugin(WarmUp(kind, own_cluster))
            return
        except LOST:
            if attempt == PLUGIN_TRIES - 1:
                raise
            client.wait_for_workers(1, timeout=60)


def n_workers(client: Client) -> int:
    return len(client.scheduler_info(n_workers=-1)["workers"])


def _state_len(study: Study) -> int:
    aero = study.options["aero"]
    return max(C.state_size(config_from_flat(study.config_values(p)), aero) for p in study.grid)


def _submit_flutter(client: Client, study: Study, missing: np.ndarray) -> dict[Any, list[int]]:
    """One task per ``batch`` consecutive missing cases."""
    size = study.options["batch"]
    groups = [missing[i : i + size].tolist() for i in range(0, missing.size, size)]
    keys = [f"flutter-{study.fingerprint}-{g[0]}-{len(g)}" for g in groups]
    futures = client.map(C.flutter_batch, [study.base] * len(groups),
                         [[{k: study.cases[i][k] for k in study.keys} for i in g] for g in groups],
                         [study.options["aero"]] * len(groups), [study.options["formulation"]] * len(groups),
                         key=keys, pure=False)
    return dict(zip(futures, groups))


def _submit_chain(client: Client, study: Study, chain: Chain, ci: int, store: Store, done: np.ndarray
                  ) -> dict[Any, list[int]]:
    """The links of one bifurcation chain from the first step not done in every branch, each link depending on
    the previous one (it continues from that LCO); the first resumes from the stored states."""
    steps = len(chain.cases[0])
    k0 = min(int(np.argmin(np.append(done[list(b)], False))) for b in chain.cases)
    if k0 >= steps:
        return {}
    values = study.config_values(study.grid[chain.grid_index])
    prev: Any = None
    if k0 > 0:
        n_state = C.state_size(config_from_flat(values), study.options["aero"])
        last = [b[k0 - 1] for b in chain.cases]
        prev = {"state": np.asarray(store.group["state"].get_orthogonal_selection((last, slice(0, n_state)))),
                "diverged": np.asarray(store.group["diverged"].get_orthogonal_selection((last,)), dtype=bool)}
    o = study.options
    out = {}
    for k in range(k0, steps):
        idx = [b[k] for b in chain.cases]
        speeds = [study.cases[i]["airspeed_mps"] for i in idx]
        prev = client.submit(C.bifurcation_link, values, chain.variant, o["aero"], o["scheme"], speeds,
                             o["duration_s"], prev, key=f"bifurcation-{study.fingerprint}-{ci}-{k}", pure=False)
        out[prev] = idx
    return out


def _results(study: Study, value: Any, idx: list[int], state_len: int) -> dict[int, dict[str, Any]]:
    if study.kind != "bifurcation":
        return dict(zip(idx, value))
    out = {}
    for b, i in enumerate(idx):
        state = np.full(state_len, np.nan)
        state[: value["state"].shape[1]] = value["state"][b]
        out[i] = {**value["results"][b], "state": state}
    return out


def run_study(study: Study, out_dir: str | Path, workers: int | None = None, scheduler: str | None = None,
              progress: bool = False, flush_s: float = 1.0,
              on_flush: Callable[[Client, int], None] | None = None, timeout_s: float = 60.0) -> dict[str, Any]:
    """Compute the missing cases of ``study`` into ``out_dir``; returns {store, computed, wall_s, workers, ...}
    (``ready_s``: time until the cluster was up and warm; ``write_s``: time spent writing the store).

    ``on_flush(client, n_written)`` is called after each write (tests use it to interrupt or to kill a worker).
    ``timeout_s``: how long to wait for a ``scheduler`` and its first worker. A cluster that cannot be reached, or
    is lost on the way, raises :class:`ClusterError` (whatever arrived before is stored).
    """
    t0 = time.perf_counter()
    problem = scheduler_problem(scheduler, timeout_s) if scheduler else None
    if problem is not None:  # before the store is made
        raise ClusterError(problem)
    store = Store.open(out_dir, study, state_len=lambda: _state_len(study))
    missing = store.missing()
    info: dict[str, Any] = {"store": store, "computed": 0, "workers": 0, "cases": len(study.cases), "write_s": 0.0,
                            "ready_s": 0.0}
    if missing.size:
        from tqdm import tqdm

        state_len = store.group["state"].shape[1] if study.kind == "bifurcation" else 0
        with connect(workers, scheduler, timeout_s) as client, tqdm(
                total=len(study.cases), initial=len(study.cases) - missing.size, disable=not progress,
                file=sys.stderr, desc=study.kind, unit="case", dynamic_ncols=True) as bar:
            info["workers"] = n_workers(client)
            _register_warm_up(client, study.kind, own_cluster=scheduler is None)
            info["ready_s"] = time.perf_counter() - t0  # cluster up (or connected) and every worker warm
            if study.kind == "bifurcation":
                done = store.done_mask()
                submitted: dict[Any, list[int]] = {}
                for ci, chain in enumerate(study.chains):
                    submitted.update(_submit_chain(client, study, chain, ci, store, done))
            else:
                submitted = _submit_flutter(client, study, missing)
            pending: dict[int, dict[str, Any]] = {}
            last = time.monotonic()

            def flush() -> None:
                nonlocal last
                t = time.perf_counter()
                store.write(pending)
                info["write_s"] += time.perf_counter() - t
                info["computed"] += len(pending)
                bar.update(len(pending))
                pending.clear()
                last = time.monotonic()

            try:
                ac = as_completed(list(submitted))
                for batch in ac.batches():
                    for fut in batch:
                        pending.update(_results(study, fut.result(), submitted.pop(fut), state_len))
                    if time.monotonic() - last >= flush_s or ac.is_empty():
                        flush()
                        if on_flush:
                            on_flush(client, info["computed"])
            except LOST as exc:
                flush()
                stored = int(store.done_mask().sum())
                raise ClusterError(f"lost the Dask cluster ({type(exc).__name__}: {exc}); {stored} of "
                                   f"{len(study.cases)} cases are stored in {store.path}, the same command resumes"
                                   ) from None
            finally:
                flush()  # what arrived is complete and valid: keep it, also on Ctrl-C or a failed task
    info["wall_s"] = time.perf_counter() - t0
    return info


def case_records(study: Study, ds: Any) -> list[dict[str, Any]]:
    """The cases as JSON-ready dicts: {"params": {...}, <results>} (NaN as null; no internal state)."""
    def num(x: Any) -> Any:
        x = x.item() if hasattr(x, "item") else x
        return None if isinstance(x, float) and not np.isfinite(x) else x

    records = []
    for i, c in enumerate(study.cases):
        rec: dict[str, Any] = {"params": {k: num(v) for k, v in c.items()}}
        if study.kind == "bifurcation":
            for v in ("rms_tip_w_over_L", "peak_tip_w_over_L", "dominant_frequency_hz", "steady_after_s"):
                rec[v] = num(ds[v].values[i])
            rec["diverged"] = bool(ds["diverged"].values[i])
        else:
            rec["flutter_speed_mps"] = num(ds["flutter_speed_mps"].values[i])
            rec["flutter_frequency_hz"] = num(ds["flutter_frequency_hz"].values[i])
            rec["dominant_mode"] = int(ds["dominant_mode"].values[i]) or None
            rec["status"] = STATUS_NAMES[int(ds["status"].values[i])]
        records.append(rec)
    return records

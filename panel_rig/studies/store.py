"""The results of a study: one xarray Dataset in Zarr (``DIR/results.zarr``), one slot per case, written as results
arrive.

Layout: dimension ``case`` (one entry per case of the spec, in the spec's order); each varied key a coordinate
(named by its dotted key); result variables per kind; ``done`` (bool) says which cases are complete. The arrays
are created at full size once, so a case has exactly one place: a duplicate cannot exist, and re-computing a case
overwrites its slot. A flush writes the result variables of the arrived cases first and their ``done`` flags last;
Zarr replaces each chunk file atomically (write to a temporary file, rename), so after a crash a case is either
done with all its values or not done (and resume computes it again) -- never partial.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np
import xarray as xr
import zarr

from panel_rig.studies.cases import BIFURCATION_VARS, FLUTTER_VARS, STATUS_MEANINGS
from panel_rig.studies.spec import Study

STORE_NAME = "results.zarr"
CHUNK = 256  # cases per chunk: a flush rewrites at most a few small chunk files per variable
INT_VARS = {"dominant_mode": np.int8, "status": np.int8}
BOOL_VARS = ("diverged", "done")


class StoreError(ValueError):
    """An output directory that holds another study (or no study where one is expected)."""


def result_vars(kind: str) -> tuple[str, ...]:
    return BIFURCATION_VARS if kind == "bifurcation" else FLUTTER_VARS


def _column(values: list[Any]) -> np.ndarray:
    if all(isinstance(v, str) for v in values):
        return np.array(values, dtype=object)  # Zarr v3 variable-length strings
    return np.asarray(values)


def template(study: Study, state_len: int = 0) -> xr.Dataset:
    """The empty Dataset of a study: coordinates filled, results NaN / 0, nothing done."""
    n = len(study.cases)
    coords: dict[str, Any] = {"case": np.arange(n)}
    names = list(study.keys) + (["variant", "direction", "airspeed_mps", "step"] if study.kind == "bifurcation" else [])
    for name in names:
        coords[name] = ("case", _column([c[name] for c in study.cases]))
    data: dict[str, Any] = {}
    for var in result_vars(study.kind):
        if var in INT_VARS:
            data[var] = ("case", np.zeros(n, dtype=INT_VARS[var]))
        elif var in BOOL_VARS:
            data[var] = ("case", np.zeros(n, dtype=bool))
        else:
            data[var] = ("case", np.full(n, np.nan))
    if study.kind == "bifurcation":
        data["state"] = (("case", "state_index"), np.full((n, state_len), np.nan))
    data["done"] = ("case", np.zeros(n, dtype=bool))
    if "status" in data:  # a reader of the store alone learns what the codes mean (CF flag attributes)
        data["status"] = ("case", data["status"][1], {
            "long_name": "flutter case status", "flag_values": list(STATUS_MEANINGS),
            "flag_meanings": " ".join(STATUS_MEANINGS.values())})
    attrs = {"kind": study.kind, "fingerprint": study.fingerprint, "spec": json.dumps(study.spec, default=str),
             "base": json.dumps(study.base, default=str), "options": json.dumps(study.options, default=str)}
    return xr.Dataset(data, coords=coords, attrs=attrs)


class Store:
    """A study's Zarr store: created once (atomically), then filled case by case."""

    def __init__(self, path: Path, study: Study):
        self.path = path
        self.study = study
        self.group = zarr.open_group(str(path), mode="r+")
        self.vars = result_vars(study.kind) + (("state",) if study.kind == "bifurcation" else ())
        # the client is the only writer: keep a copy of each array, so that a flush only writes (never reads)
        self._mirror = {v: np.asarray(self.group[v][:]) for v in self.vars + ("done",)}

    @classmethod
    def open(cls, out_dir: str | Path, study: Study, state_len: Callable[[], int] | None = None) -> "Store":
        """Open DIR/results.zarr for this study, creating it if absent; refuse a store of another study."""
        path = Path(out_dir) / STORE_NAME
        if (Path(out_dir) / "zarr.json").is_file():  # --out DIR/results.zarr: a store inside the store
            raise StoreError(f"{out_dir} is a Zarr store itself: give the study's directory (its parent) as --out")
        if (path / "zarr.json").is_file():
            found = zarr.open_group(str(path), mode="r").attrs.get("fingerprint")
            if found != study.fingerprint:
                raise StoreError(f"{path} holds another study (fingerprint {found}, this spec {study.fingerprint}): "
                                 "use another --out or remove it")
            return cls(path, study)
        if path.is_symlink() or (path.exists() and (not path.is_dir() or any(path.iterdir()))):
            # creation is one rename, so a crash never leaves a half store here: this is somebody else's
            raise StoreError(f"{path} exists and is not a panel-rig study store: use another --out or remove it")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create the output directory {path.parent}: {exc.strerror or exc}") from None
        tmp = path.with_name(path.name + ".creating")
        shutil.rmtree(tmp, ignore_errors=True)
        ds = template(study, state_len() if (study.kind == "bifurcation" and state_len) else 0)
        chunk = min(CHUNK, max(1, len(study.cases)))
        enc = {v: {"chunks": (chunk,) + ds[v].shape[1:]} for v in ds.data_vars}
        try:
            ds.to_zarr(str(tmp), mode="w", encoding=enc, consolidated=False)
        except OSError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise StoreError(f"cannot write the study store in {path.parent}: {exc.strerror or exc}") from None
        if path.exists():  # an empty directory (checked above)
            path.rmdir()
        os.replace(tmp, path)
        return cls(path, study)

    def done_mask(self) -> np.ndarray:
        return np.asarray(self.group["done"][:], dtype=bool)  # from the files: what a resume would see

    def missing(self) -> np.ndarray:
        """Indices of the cases not yet done."""
        return np.flatnonzero(~self.done_mask())

    def write(self, results: Mapping[int, Mapping[str, Any]]) -> None:
        """Write the arrived cases: every result variable, then the ``done`` flags."""
        if not results:
            return
        idx = np.array(sorted(results), dtype=np.int64)
        for var in self.vars:
            self._put(var, idx, [results[i][var] for i in idx])
        self._put("done", idx, [True] * idx.size)

    def _put(self, var: str, idx: np.ndarray, values: Iterable[Any]) -> None:
        """Set the cases' values in the mirror, then write each touched chunk whole (one atomic file each)."""
        arr, mirror = self.group[var], self._mirror[var]
        for i, v in zip(idx, values):
            mirror[i] = v
        chunk = arr.chunks[0]
        for c in np.unique(idx // chunk):
            lo, hi = int(c) * chunk, min(int(c + 1) * chunk, mirror.shape[0])
            arr[lo:hi] = mirror[lo:hi]

    def load(self) -> xr.Dataset:
        return xr.open_zarr(str(self.path), consolidated=False).load()

"""Summaries and figures of a finished study: flutter-map contours, the U_f histogram with percentiles and a
sensitivity ranking, bifurcation diagrams with their up and down branches."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import rankdata, spearmanr

from panel_rig.studies.spec import Study

PERCENTILES = (5, 25, 50, 75, 95)
LCO_RMS = 0.005  # tip w/L RMS above which a run counts as in LCO (as panel-rig analyze)


def _numeric(values: np.ndarray) -> bool:
    return np.issubdtype(np.asarray(values).dtype, np.number)


def ranked_flutter_speeds(ds: Any) -> tuple[np.ndarray, np.ndarray]:
    """(which cases, the ranks of their U_f): every case but the failed ones. A case unstable already at the scan's
    first airspeed has a U_f below every found one, a case without flutter below the scan's end one above: their
    U_f is unknown but its rank is not (tied among themselves). Leaving them out biased the ranking: in the
    README's uncertainty example all 27 unstable cases had a damping ratio below 0.002."""
    from panel_rig.studies.cases import NO_FLUTTER, UNSTABLE_AT_START

    u = np.asarray(ds["flutter_speed_mps"].values, float).copy()
    status = np.asarray(ds["status"].values)
    u[status == UNSTABLE_AT_START] = -np.inf
    u[status == NO_FLUTTER] = np.inf
    ok = ~np.isnan(u)
    return ok, rankdata(u[ok])


#: the sensitivity measure when the flutter speeds have no spread to rank (spearmanr warned and gave NaN)
NO_SPREAD = "none (U_f has no spread)"


def sensitivity_ranking(study: Study, ds: Any) -> list[dict[str, Any]]:
    """How strongly each uncertain input drives U_f: |Spearman rank correlation| for numbers, the correlation
    ratio (eta) of the ranks for choices of strings; over every case but the failed ones
    (:func:`ranked_flutter_speeds`); sorted, strongest first. When every case ranks alike, each key's measure is
    NO_SPREAD with the value None."""
    ok, r = ranked_flutter_speeds(ds)
    if np.unique(r).size < 2:  # every case ranks alike (all unstable at the start, say): no correlation is defined
        return [{"key": key, "measure": NO_SPREAD, "value": None, "importance": 0.0} for key in study.keys]
    out = []
    for key in study.keys:
        x = ds[key].values[ok]
        if _numeric(x) and np.unique(x).size > 1:
            rho = float(spearmanr(x, r).statistic)
            out.append({"key": key, "measure": "spearman", "value": rho, "importance": abs(rho)})
        elif np.unique(x).size > 1:
            groups = [r[x == g] for g in np.unique(x)]
            total = np.sum((r - r.mean()) ** 2)
            between = sum(g.size * (g.mean() - r.mean()) ** 2 for g in groups)
            eta = float(np.sqrt(between / total)) if total > 0 else 0.0
            out.append({"key": key, "measure": "eta", "value": eta, "importance": eta})
        else:
            out.append({"key": key, "measure": "constant", "value": 0.0, "importance": 0.0})
    return sorted(out, key=lambda r: -r["importance"])


def summarize(study: Study, ds: Any) -> dict[str, Any]:
    """Headline numbers of a study (written as summary.json)."""
    if study.kind == "bifurcation":
        rows = []
        for ch in study.chains:
            row: dict[str, Any] = {"variant": ch.variant, **study.grid[ch.grid_index]}
            for d, branch in zip(ch.directions, ch.cases):
                u = ds["airspeed_mps"].values[list(branch)]
                rms = ds["rms_tip_w_over_L"].values[list(branch)]
                lco = u[np.nan_to_num(rms) >= LCO_RMS]
                diverged = u[ds["diverged"].values[list(branch)].astype(bool)]
                if d == "up":
                    row["lco_onset_up_mps"] = float(lco.min()) if lco.size else None
                else:
                    row["lco_lowest_down_mps"] = float(lco.min()) if lco.size else None
                # no LCO is not "nothing happens": a branch that left the physical range has no amplitude at all.
                # Where it first diverged, going its way (it stays diverged after): the lowest airspeed going up,
                # the highest going down (the lowest said "9 m/s" for a down branch lost at its 13 m/s start)
                first = (diverged.min() if d == "up" else diverged.max()) if diverged.size else None
                row[f"diverged_{d}_from_mps"] = None if first is None else float(first)
            up, down = row.get("lco_onset_up_mps"), row.get("lco_lowest_down_mps")
            row["hysteresis"] = bool(up is not None and down is not None and down < up)
            # cases whose response never settled: their RMS is a transient's, and so is a hysteresis read from it
            # (a 5 s spec reported hysteresis with no case settled, and said nothing)
            cases = [i for branch in ch.cases for i in branch]
            steady = np.asarray(ds["steady_after_s"].values[cases], float)
            row["unsettled_cases"] = int(np.sum(np.isnan(steady) & ~ds["diverged"].values[cases].astype(bool)))
            rows.append(row)
        return {"kind": study.kind, "branches": rows, "lco_rms_threshold": LCO_RMS}
    u = ds["flutter_speed_mps"].values
    ok = u[np.isfinite(u)]
    out: dict[str, Any] = {"kind": study.kind, "cases": int(u.size), "with_flutter": int(ok.size)}
    out.update(status_counts(ds))
    if ok.size:
        out.update(flutter_speed_min_mps=float(ok.min()), flutter_speed_max_mps=float(ok.max()),
                   flutter_speed_mean_mps=float(ok.mean()), flutter_speed_sd_mps=float(ok.std(ddof=1)) if ok.size > 1
                   else 0.0, percentiles_mps={str(p): float(np.percentile(ok, p)) for p in PERCENTILES})
    if study.kind == "uncertainty":
        out["sensitivity"] = sensitivity_ranking(study, ds)
    return out


def status_counts(ds: Any) -> dict[str, int]:
    """How many cases ended without a flutter speed, and why (the statistics above cover only the others)."""
    from panel_rig.studies.cases import FAILED, NO_FLUTTER, NO_FLUTTER_KEY, UNSTABLE_AT_START

    status = ds["status"].values[ds["done"].values.astype(bool)]
    return {NO_FLUTTER_KEY: int(np.sum(status == NO_FLUTTER)),
            "unstable_at_1_mps": int(np.sum(status == UNSTABLE_AT_START)), "failed": int(np.sum(status == FAILED))}


def _without(summary: dict[str, Any]) -> str:
    """'; 27 unstable at 1 m/s, ...': the cases a figure leaves out, for its title."""
    from panel_rig.studies.cases import MAX_AIRSPEED_MPS, NO_FLUTTER_KEY

    parts = [f"{summary[k]} {label}" for k, label in (("unstable_at_1_mps", "unstable at 1 m/s"),
             (NO_FLUTTER_KEY, f"without flutter below {MAX_AIRSPEED_MPS:g} m/s"), ("failed", "failed"))
             if summary.get(k)]
    return f"\nnot shown: {', '.join(parts)}" if parts else ""


def _map(fig: Any, ax: Any, x: np.ndarray, y: np.ndarray, z: np.ndarray, label: str) -> None:
    """Contours of z (x, y) where there are enough values, and every case as a dot (a cross: no value), so a map
    with holes or failed cases still shows what was computed; the levels in any order."""
    ix, iy = np.argsort(x, kind="stable"), np.argsort(y, kind="stable")
    x, y, z = x[ix], y[iy], z[np.ix_(ix, iy)]
    ok = np.isfinite(z)
    values = z[ok]
    lo, hi = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    from matplotlib.colors import Normalize

    norm = Normalize(lo, hi)
    contoured = ok.any(axis=1).sum() >= 2 and ok.any(axis=0).sum() >= 2 and values.size >= 4
    if contoured:
        cs = ax.contourf(x, y, z.T, levels=np.linspace(lo, hi, 15), cmap="viridis", norm=norm)
        ax.contour(cs, colors="k", linewidths=0.4)
    X, Y = np.meshgrid(x, y, indexing="ij")
    # over contours the cases are white dots (filled with their own value they vanished into the contour of the
    # same colour); without contours the dots carry the values
    fill = {"facecolors": "white"} if contoured else {"c": values, "cmap": "viridis", "norm": norm}
    ax.scatter(X[ok], Y[ok], s=18, edgecolors="k", linewidths=0.6, clip_on=False, zorder=3, label="case computed",
               **fill)
    if (~ok).any():
        ax.scatter(X[~ok], Y[~ok], marker="x", color="C3", s=24, label="no flutter speed (see summary.json)",
                   clip_on=False, zorder=3)
    ax.legend(fontsize=7, loc="best", framealpha=0.8)
    from matplotlib.cm import ScalarMappable

    fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), ax=ax, label=label)


def _axis(levels: list[Any]) -> tuple[np.ndarray, list[str] | None]:
    if all(isinstance(v, (int, float)) for v in levels):
        return np.asarray(levels, dtype=float), None
    return np.arange(len(levels), dtype=float), [str(v) for v in levels]


def _mark_height(row: int) -> float:
    """Axes-fraction height of the k-th row of a bifurcation panel's "diverged" marks, from the top."""
    return 0.97 - 0.035 * row


def _room_above_data(ax: Any, below: float) -> None:
    """Raise the y-limit so that every data point sits below the axes fraction ``below`` (the "diverged" marks
    above it sat on an LCO point at the top of the panel)."""
    lo, _ = ax.get_ylim()
    top = ax.dataLim.y1
    if np.isfinite(top) and top > lo:
        ax.set_ylim(lo, lo + (top - lo) / below)


def plot(study: Study, ds: Any, summary: dict[str, Any], out_dir: Path) -> list[Path]:
    """The study's figures as PNG in out_dir."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    if study.kind == "flutter_map":
        keys = list(study.keys)
        shape = [len(study.levels[k]) for k in keys]
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        for ax, var, label in zip(axes, ("flutter_speed_mps", "flutter_frequency_hz"), ("U_f, m/s", "f_f, Hz")):
            grid = ds[var].values.reshape(shape)
            x, xt = _axis(study.levels[keys[0]])
            if len(keys) == 1 or shape[1] == 1:
                order = np.argsort(x, kind="stable")
                ax.plot(x[order], grid.reshape(shape[0], -1)[order, 0], "o-")
                ax.set_ylabel(label)
            else:
                y, yt = _axis(study.levels[keys[1]])
                z = grid[(slice(None), slice(None)) + (0,) * (len(keys) - 2)]
                _map(fig, ax, x, y, z, label)
                ax.set_ylabel(keys[1])
                if yt:
                    ax.set_yticks(y, yt)
            if xt:
                ax.set_xticks(x, xt)
            ax.set_xlabel(keys[0])
            rest = ", ".join(f"{k} = {study.levels[k][0]}" for k in keys[2:])
            ax.set_title(f"{label.split(',')[0]} ({study.options['aero']} aero){'; ' + rest if rest else ''}")
        fixed = ", ".join(f"{k} = {v}" for k, v in (study.spec.get("set") or {}).items())
        fig.suptitle(f"flutter map: {len(study.cases)} cases ({' x '.join(str(n) for n in shape)}), "
                     f"{study.options['aero']} aero{'; ' + fixed if fixed else ''}", fontsize=10)
        files.append(out_dir / "flutter_map.png")
    elif study.kind == "uncertainty":
        u = ds["flutter_speed_mps"].values
        u = u[np.isfinite(u)]
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
        a1.hist(u, bins=max(5, min(60, int(np.sqrt(max(u.size, 1))) * 2)), color="0.6")
        for p, v in summary.get("percentiles_mps", {}).items():
            a1.axvline(v, color="C3" if p == "50" else "C0", ls="-" if p == "50" else "--")
            if p in ("5", "50", "95"):
                a1.text(v, a1.get_ylim()[1] * 0.95, f"P{p}\n{v:.2f}", fontsize=7, ha="center", va="top")
        a1.set_xlabel("flutter speed U_f, m/s")
        a1.set_ylabel("cases")
        a1.set_title(f"U_f over {u.size} of {summary['cases']} samples (seed {study.options['seed']})"
                     f"{_without(summary)}", fontsize=9)
        rank = summary.get("sensitivity", [])
        a2.barh([r["key"] for r in rank][::-1], [r["importance"] for r in rank][::-1], color="C0")
        for i, r in enumerate(rank[::-1]):
            a2.text(r["importance"], i, f" {r['measure']}" + ("" if r["value"] is None else f" {r['value']:+.2f}"),
                    va="center", fontsize=7)
        a2.set_xlim(0, 1.15)
        a2.set_xlabel("|rank correlation| with U_f")
        a2.set_title("sensitivity ranking")
        files.append(out_dir / "uncertainty.png")
    else:
        n = len(study.grid)
        fig, axes = plt.subplots(1, n, figsize=(6 * n, 4.2), squeeze=False)
        marker_rows: dict[Any, int] = {}  # per panel: how many rows of "diverged" marks it has at the top
        for ci, ch in enumerate(study.chains):
            ax = axes[0, ch.grid_index]
            color = f"C{study.options['variants'].index(ch.variant)}"
            for d, branch in zip(ch.directions, ch.cases):
                u = ds["airspeed_mps"].values[list(branch)]
                rms = ds["rms_tip_w_over_L"].values[list(branch)]
                ax.plot(u, rms, ("^-" if d == "up" else "v--"), color=color, label=f"{ch.variant}, {d}",
                        mfc="none" if d == "down" else color)
                div = ds["diverged"].values[list(branch)].astype(bool)
                if div.any():  # no amplitude to draw: mark the airspeed at the top edge, a row per variant and way
                    row = 2 * study.options["variants"].index(ch.variant) + (d == "down")
                    ax.plot(u[div], np.full(div.sum(), _mark_height(row)), "x", color=color,
                            transform=ax.get_xaxis_transform(), clip_on=False)
                    marker_rows[ax] = max(marker_rows.get(ax, 0), row + 1)
            point = study.grid[ch.grid_index]
            title = ", ".join(f"{k} = {v}" for k, v in point.items()) or "bifurcation diagram"
            ax.set_title(f"{title}\n(x at the top: diverged, |tip w/L| over the bound)", fontsize=9)
            ax.set_xlabel("airspeed, m/s")
            ax.set_ylabel("RMS tip w/L")
            ax.legend(fontsize=7)
        for ax, rows in marker_rows.items():
            _room_above_data(ax, _mark_height(rows - 1) - 0.06)
        files.append(out_dir / "bifurcation.png")
    fig.tight_layout()
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files

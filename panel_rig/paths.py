"""Output locations of the commands."""

from __future__ import annotations

from pathlib import Path


def make_output_dir(path: str | Path, option: str) -> Path:
    """Make an output directory now (parents too), before any work; ValueError naming the option when it cannot
    be made (a result that could not be written after the run lost the run)."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"{option}: cannot create the directory {path}: {exc.strerror or exc}") from None
    return path

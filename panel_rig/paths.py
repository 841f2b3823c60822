"""Output locations of the commands."""

from __future__ import annotations

import errno
import tempfile
from pathlib import Path


def make_output_dir(path: str | Path, option: str) -> Path:
    """Make an output directory now (parents too) and check that a file can be written in it, before any work;
    ValueError naming the option when it cannot (a result that could not be written after the run lost the run:
    /proc exists, but nothing can be written there)."""
    if not str(path).strip():  # '' is the working directory: outputs spread into a checkout
        raise ValueError(f"{option} must name a directory, got an empty string")
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ValueError(f"{option}: {path} is a file, not a directory") from None
    except OSError as exc:
        raise ValueError(f"{option}: cannot create the directory {path}: {exc.strerror or exc}") from None
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:  # /proc refuses a file with ENOENT: "No such file or directory" named the directory
        reason = "it takes no files" if exc.errno == errno.ENOENT and path.is_dir() else (exc.strerror or exc)
        raise ValueError(f"{option}: cannot write in the directory {path}: {reason}") from None
    return path


def check_output_dir(path: str | Path, option: str) -> Path:
    """`make_output_dir`'s check without leaving a trace: the directories it had to make are removed again (a
    command refused for another option left an empty directory behind); the writer makes them when it writes."""
    path = Path(path)
    missing = [d for d in (path, *path.parents) if not d.exists()]
    make_output_dir(path, option)
    for made in missing:  # deepest first
        try:
            made.rmdir()
        except OSError:  # something was put there meanwhile: it stays
            break
    return path


def rrd_path_problem(path: str | Path) -> str | None:
    """Why a Rerun recording cannot be saved at ``path``, or None: it must name a .rrd file (rerun replaces
    whatever is there: a typo once overwrote a profile YAML) under no ancestor that is a file. A missing directory
    is no problem: `prepare_rrd_path` makes it, as the bag's and the plots' directories are made."""
    path = Path(path)
    if path.suffix.lower() != ".rrd":
        return f"a Rerun recording is saved to a .rrd file, not {str(path)!r}"
    if path.is_dir():
        return f"{path} is a directory: name the .rrd file in it"
    for ancestor in path.parents:
        if ancestor.exists():
            return None if ancestor.is_dir() else f"{ancestor} is a file, not a directory"
    return None


def prepare_rrd_path(path: str | Path, option: str) -> Path:
    """Check ``path`` for a Rerun recording and make its directory (parents too), before any work; ValueError
    naming the option when it cannot be used."""
    problem = rrd_path_problem(path)
    if problem:
        raise ValueError(f"{option}: {problem}")
    make_output_dir(Path(path).parent, option)
    return Path(path)

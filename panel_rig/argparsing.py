"""The programs' argument parsers: a usage error is one stderr line and status 2, as every subcommand's."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn


class OneLineParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose usage errors print ``PROG: error: MESSAGE`` alone (argparse prints its usage
    block first: `control-demo --bogus` gave two lines where `panel-rig lco --bogus` gives one) and exit 2."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def study_parser(doc: str | None, prog: str) -> OneLineParser:
    """The parser of a ``python -m panel_rig.analysis.<study>`` script: its docstring as the help, so ``--help``
    describes the study (minutes of computation) instead of starting it, and an unknown option is one line."""
    lines = (doc or "").strip().splitlines()
    return OneLineParser(prog=f"python -m {prog}", description=lines[0] if lines else None,
                         epilog="\n".join(lines[1:]).strip() or None, formatter_class=argparse.RawDescriptionHelpFormatter)

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

"""Console entry points (``panel-rig``, ``rig_node``, ``rig_operator``, ``rig_controller``).

Each imports its program only when called: numpy, numba and rclpy take about half a second to load, and a Ctrl-C
in that time raised KeyboardInterrupt inside the import, where no program's handler stands yet (a traceback of
importlib frames). Here it ends as a Ctrl-C later does: one line, status 130.
"""

from __future__ import annotations

import importlib
import sys

from panel_rig.processes import INTERRUPTED_STATUS


def launch(module: str, program: str) -> int:
    """Import ``module`` and return what its ``main()`` returns; a Ctrl-C during the import: one line on stderr,
    status 130."""
    try:
        main = importlib.import_module(module).main
    except KeyboardInterrupt:
        print(f"{program}: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    return main()


def panel_rig() -> int:
    return launch("panel_rig.cli", "panel-rig")


def rig_node() -> int:
    return launch("panel_rig.ros.rig_node", "rig_node")


def rig_operator() -> int:
    return launch("panel_rig.ros.operator", "rig_operator")


def rig_controller() -> int:
    return launch("panel_rig.ros.controller", "rig_controller")

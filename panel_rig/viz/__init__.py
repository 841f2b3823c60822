"""Rerun logging of the rig (live viewer or `.rrd` file)."""

from panel_rig.viz.logger import RerunLogger, VizError, blueprint, modal_entity

__all__ = ["RerunLogger", "VizError", "blueprint", "modal_entity"]

"""panel_rig: a wind-tunnel aeroelastic panel rig after Tang & Dowell (2002).

The physics (``panel_rig.model``) is pure numpy/scipy; ROS, recording and Rerun are thin layers.
"""

__version__ = "0.1.0"

"""One ROS program's session (node, controller, operator): rclpy initialised without its own signal handlers,
SIGINT / SIGTERM only setting the program's stop flag (:func:`panel_rig.processes.signals_set`), and the context
shut down however the program ends."""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import rclpy
from rclpy.signals import SignalHandlerOptions

from panel_rig.processes import signals_set


@contextmanager
def ros_session(args: Sequence[str], stop: threading.Event) -> Iterator[None]:
    """``rclpy.init(args)`` for the block; a signal sets ``stop`` (the program's spin loop ends between rclpy calls);
    the context is shut down on leaving (the program destroys its node before), then the previous handlers return."""
    with signals_set(stop):
        rclpy.init(args=list(args), signal_handler_options=SignalHandlerOptions.NO)
        try:
            yield
        finally:
            if rclpy.ok():
                rclpy.shutdown()

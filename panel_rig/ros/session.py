"""One ROS program's session (node, controller, operator): rclpy initialised without its own signal handlers,
SIGINT / SIGTERM only setting the program's stop flag (:func:`panel_rig.processes.signals_set`), and the context
shut down however the program ends."""

from __future__ import annotations

import faulthandler
import re
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import rclpy
from rclpy.signals import SignalHandlerOptions

from panel_rig.processes import follow_parent, signals_set
from panel_rig.ros.discovery import use_quick_announcements


@contextmanager
def ros_session(args: Sequence[str], stop: threading.Event) -> Iterator[None]:
    """``rclpy.init(args)`` for the block; a signal sets ``stop`` (the program's spin loop ends between rclpy calls);
    the context is shut down on leaving (the program destroys its node before), then the previous handlers return,
    unless ``stop`` is set: the program is stopping, and ignores further signals until it exits."""
    if not faulthandler.is_enabled():  # a native crash (rcl, the DDS) prints the Python stacks of every thread
        faulthandler.enable()
    with signals_set(stop, restore_when_stopped=False):
        follow_parent()  # a child of a one-command session stops with it (its SIGTERM sets ``stop``)
        use_quick_announcements()  # a program started after this one sees it within 0.5 s, not 3 s
        rclpy.init(args=list(args), signal_handler_options=SignalHandlerOptions.NO)
        try:
            yield
        finally:
            if rclpy.ok():
                rclpy.shutdown()


def ros_arguments_problem(args: Sequence[str]) -> str | None:
    """One line on what rcl cannot take in ``args`` (a ``--params-file`` that is missing or not YAML, ``-p``
    without NAME:=VALUE, ``-r __ns:=/rig/``), or None. rcl raised these as tracebacks from ``remove_ros_args`` or
    from the node's creation."""
    from rclpy.utilities import remove_ros_args

    try:
        remove_ros_args(["program", *args])
    except Exception as exc:  # noqa: BLE001 - rclpy's RCLInvalidROSArgsError, a class of its private extension
        text = _without_source_places(str(exc))
        if "parameter override rule" in text:
            text += " (the value after := is read as YAML: quote it, e.g. -p 'NAME:=\"text:with:colons\"')"
        return "bad --ros-args: " + text
    for namespace in _remapped_namespaces(args):
        problem = namespace_problem(namespace)
        if problem:
            return f"bad --ros-args: -r __ns:={namespace}: {problem}"
    return None


def namespace_problem(namespace: str) -> str | None:
    """Why ``namespace`` is not a ROS namespace (rclpy's reason, first line), or None."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    try:
        validate_namespace(namespace if namespace.startswith("/") else "/" + namespace)
    except InvalidNamespaceException as exc:
        return str(exc).splitlines()[0].removeprefix("Invalid namespace: ").rstrip(":")
    return None


def ros_rules(args: Sequence[str], flags: tuple[str, ...]) -> list[str]:
    """The rules given after any of ``flags`` (e.g. ``-p``, ``--param``) inside ``--ros-args ... [--]`` blocks."""
    rules: list[str] = []
    inside, expect_rule = False, False
    for token in args:
        if token == "--ros-args":
            inside = True
        elif token == "--":
            inside = False
        elif inside and expect_rule:
            rules.append(token)
            expect_rule = False
        elif inside and token in flags:
            expect_rule = True
    return rules


def _remapped_namespaces(args: Sequence[str]) -> list[str]:
    """The X of every ``-r [NODE:]__ns:=X``."""
    rules = (rule.partition(":=") for rule in ros_rules(args, ("-r", "--remap")))
    return [value for lhs, _, value in rules if lhs.rsplit(":", 1)[-1] == "__ns"]


def _without_source_places(text: str) -> str:
    """rcl's messages end in ", at /project/src/parser.c:271, at ...": the user needs none of them."""
    return re.sub(r",? at /\S+:\d+", "", text).strip()

"""Topic-name conventions shared by the node (live topics) and the recording (bags), with no dependencies."""

#: a command the rig refused is echoed live and recorded on ``<command topic>/rejected``
REJECTED_SUFFIX = "/rejected"

#: the rig's status on /diagnostics (diagnostic_updater's "<node>: <task>" form); its hardware_id is the rig node's
#: namespace. Its values include the aborts: ``aborts`` (count), ``abort_reason``, ``last_abort_time_s`` (rig time),
#: ``last_abort_reason``
RIG_STATUS_NAME = "panel_rig: tunnel"

#: the flutter monitor's results (``diagnostic_msgs/DiagnosticArray``, one per test point; see
#: :mod:`panel_rig.ros.flutter_monitor`), under the rig's namespace
FLUTTER_MONITOR_TOPIC = "flutter_monitor"

#: a controller's commands to the rig's control actuator (``geometry_msgs/WrenchStamped``), under its namespace
CONTROL_TOPIC = "control/force_cmd"

#: the control actuator's watchdog default (s): no command for longer zeroes the control force. The rig's
#: ``ControlSettings.timeout_s`` (node parameter ``control.timeout_s``), and what the bag analysis assumes of a run
#: that did not record its own
CONTROL_TIMEOUT_S = 0.1

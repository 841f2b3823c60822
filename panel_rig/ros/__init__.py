"""The rclpy adapter around :mod:`panel_rig.rig`: parameters, topics, services, timers; no physics."""

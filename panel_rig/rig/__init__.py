"""The emulated wind tunnel around the model: actuator, shaker, sensors, safety; no ROS."""

"""The physics of the rig (numpy/scipy only, no ROS, no files, no wall-clock time)."""

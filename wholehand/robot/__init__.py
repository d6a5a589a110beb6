"""The controller on a robot: its loop over ROS 2 and the safety rules between it and the
drives (torque guard, arm guard, stop requests)."""

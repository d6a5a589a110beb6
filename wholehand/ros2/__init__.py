"""ROS 2 without a ROS installation: the hardware config, the messages and their checks, and the
two transports (zenoh as rmw_zenoh speaks it, DDS as rmw_cyclonedds does) with the streams the
controller reads."""

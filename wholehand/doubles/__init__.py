"""Robot doubles: MuJoCo plays the robot (hand, arm, tracker, person) over ROS 2 messages, so
the robot path can be tried and tested without hardware (``wholehand hw-sim``)."""

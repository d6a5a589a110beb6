"""MCAP recordings of a run in rosbag2's layout, and reading them back."""

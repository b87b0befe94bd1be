"""Readers that turn flight logs (ROS1, ROS2 sqlite3/MCAP, plain MCAP, TUM, EuRoC csv) into arrays."""

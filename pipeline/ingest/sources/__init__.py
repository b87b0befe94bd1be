"""Flight logs (ROS1, ROS2 sqlite3/MCAP, plain MCAP, TUM, EuRoC csv) to arrays and back: one
subpackage per format with its reader beside its writer (``ros1``, ``rosbag2``, ``mcap``,
``text``), the message types in ``msgtypes``, every bag reader behind
:class:`~qsls.pipeline.ingest.sources.base.BagReader` (docs/ingest.md#formats)."""

"""Plain MCAP files: the reader (:mod:`.reader`, its chunk reader :mod:`.chunks`, which a
rosbag2's MCAP storage shares) beside the writer (:mod:`.writer`)."""

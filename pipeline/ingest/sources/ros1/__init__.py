"""ROS1 ``.bag`` files: the reader (:mod:`.reader`, its numpy index :mod:`.index`) beside the
writer (:mod:`.writer`)."""

"""rosbag2 bags (a folder with ``metadata.yaml``, or a lone ``.db3``): the reader
(:mod:`.reader`, with its storage plugins :mod:`.sqlite` and the MCAP chunk reader of
:mod:`..mcap.chunks`, and the listing :mod:`.listing`) beside the writer (:mod:`.writer`)."""

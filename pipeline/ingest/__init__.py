"""``qsls ingest``: flight logs to one clock, one frame, one ``dt`` grid (``flight.parquet``).

``sources/`` reads bags and text trajectories into arrays; ``streams`` picks and prepares
the VIO and truth streams; ``timesync`` finds the clock offset; ``align`` the frame;
``flight`` is the flight table every later stage reads.
"""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "IngestOptions": "options",
        "IngestResult": "stage",
        "ingest": "stage",
        "estimate_offset": "timesync",
        "fit_alignment": "align",
        "read_flight": "flight",
        "make_flight_frame": "flight",
        "flight_table": "flight",
    },
)

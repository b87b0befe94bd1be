"""``qsls ingest``: flight logs to one clock, one frame, one ``dt`` grid (``flight.parquet``).

``sources/`` reads bags and text trajectories into arrays (one subpackage per format, its
reader beside its writer); ``streams`` picks, reads and prepares the VIO and truth streams;
``assemble`` is the pure core (:func:`flight_from_streams`: two streams in, a flight out, no
I/O), with ``velocity``, ``timesync`` (the clock offset), ``align`` (the frame) and
``resample`` (the grid); ``flight`` is the flight table every later stage reads; ``stage``
reads, calls the core and writes (docs/ingest.md).
"""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "IngestOptions": "options",
        "IngestResult": "stage",
        "ingest": "stage",
        "flight_from_streams": "assemble",
        "IngestedFlight": "assemble",
        "estimate_offset": "timesync",
        "fit_alignment": "align",
        "read_flight": "flight",
        "make_flight_frame": "flight",
        "flight_table": "flight",
    },
)

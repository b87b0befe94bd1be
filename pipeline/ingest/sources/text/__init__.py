"""Text trajectories (TUM, EuRoC csv): the reader (:mod:`.reader`) beside the TUM writer
(:mod:`.writer`, what ``qsls ingest --export-tum`` writes)."""

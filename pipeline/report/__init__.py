"""``qsls report``: one self-contained HTML page and its Markdown twin from a run folder."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {"report": "stage", "ReportResult": "stage", "Section": "document"},
)

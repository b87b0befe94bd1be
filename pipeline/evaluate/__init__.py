"""``qsls evaluate``: the guarantee checked on held-out flights."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "EvaluateOptions": "options",
        "evaluate": "stage",
    },
)

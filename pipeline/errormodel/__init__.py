"""``qsls fit``: the perception error model (docs/errormodel.md): ``eps_e``, S-slopes, ``delta``."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "ErrorModel": "model",
        "load_error_model": "model",
        "FitOptions": "fit",
        "FitResult": "fit",
        "FitData": "fit",
        "Fitted": "fit",
        "fit_model": "fit",
        "load_fit_data": "fit",
        "pair_slopes": "slopes",
        "PairSlopes": "slopes",
        "nearest_distance": "slopes",
    },
)

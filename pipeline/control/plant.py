"""The plant model lives in :mod:`qsls.pipeline.core.plant` (every stage needs it); this name is
kept for code written against ``qsls.pipeline.control.plant``."""

from qsls.pipeline.core.plant import (
    GRAVITY,
    NU,
    NX,
    PAPER_DT_S,
    PAPER_MASS_KG,
    LinearModel,
    continuous_model,
    quadrotor_model,
    zoh,
)

__all__ = [
    "GRAVITY", "NU", "NX", "PAPER_DT_S", "PAPER_MASS_KG", "LinearModel", "continuous_model",
    "quadrotor_model", "zoh",
]  # fmt: skip

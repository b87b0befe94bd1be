"""The perception error model artifact, ``error_model.yaml`` (docs/errormodel.md#output).

This module fixes the file's schema and how later stages read it; the estimator that
writes it lives in :mod:`qsls.pipeline.errormodel.fit`.

Names a later stage may use for a number of the model (``S`` and ``eps_e`` in synth):
``max``; ``pNN`` (a percentile over pair slopes, or over ``||e_i||``); ``local_pNN``
(a percentile of each sample's largest slope, S only); the premise looks them up
(:mod:`qsls.pipeline.premise.choose`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field

from qsls.pipeline.core.artifacts import check_stage_file, load_yaml
from qsls.pipeline.core.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

ERROR_MODEL_FILE = "error_model.yaml"
TRAINING_FILE = "training_states.parquet"
W_COLS = ("w_px", "w_py", "w_pz", "w_vx", "w_vy", "w_vz")
"""The realized disturbance's columns in ``training_states.parquet``."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AxisStats(_Frozen):
    mean: float
    std: float
    rms: float
    max_abs: float


class SlopeStats(_Frozen):
    """S-slope estimates with radius ``r``: ``||e_i - e_j|| / ||x_i - x_j||``, ``||x_i - x_j|| < r``."""

    max: float
    percentiles: dict[str, float] = Field(default_factory=dict)
    local_max_percentiles: dict[str, float] = Field(default_factory=dict)
    percentile_rel_error: float = 0.0
    """Upper bound on the relative error of ``percentiles`` (0 when exact)."""
    n_samples_with_partners: int | None = None
    """Samples with at least one counted pair (the population of ``local_max_percentiles``)."""


class WorstPair(_Frozen):
    flight: str
    """Flight of sample i (``flight_j``: of sample j, when the pair spans two flights)."""
    t_i: float
    t_j: float
    x_i: list[float]
    x_j: list[float]
    e_i: list[float]
    e_j: list[float]
    distance: float
    slope: float
    flight_j: str | None = None


class DisturbanceStats(_Frozen):
    """The realized disturbance ``||w_k||_inf`` of the training flights through the model
    (:mod:`qsls.pipeline.errormodel.disturbance`)."""

    max: float
    percentiles: dict[str, float] = Field(default_factory=dict)
    source: str
    """``inputs`` (measured with the logged inputs) or ``input_free_residual`` (no inputs
    logged: the smallest disturbance any input leaves, a lower bound on a controller's)."""
    n_steps: int


class ErrorModel(_Frozen):
    """Everything ``qsls fit`` learned about ``e = y - x`` on the training flights."""

    eps_e: float
    eps_e_percentiles: dict[str, float] = Field(default_factory=dict)
    per_axis: dict[str, AxisStats] = Field(default_factory=dict)
    radius: float
    min_separation: float = 0.0
    min_separation_rule: str | None = None
    """How ``min_separation`` was chosen (``auto``: a multiple of the noise floor)."""
    noise_floor: dict[str, float] = Field(default_factory=dict)
    """Per-axis white-noise std of ``e`` estimated from the data."""
    state_scale: list[float] = Field(default_factory=lambda: [1.0] * 6)
    s_slope: SlopeStats
    R0: float
    delta: float = 0.0
    delta_reference: str | None = None
    """The reference ``delta`` was computed for (None: no reference given, delta = 0)."""
    n_samples: int
    n_pairs: int
    n_pairs_below_min_separation: int = 0
    n_excluded: int = 0
    exclusions: dict[str, int] = Field(default_factory=dict)
    """Excluded samples by reason (nonfinite, skip_start, outliers)."""
    worst_pairs: list[WorstPair] = Field(default_factory=list)
    bootstrap: dict[str, Any] | None = None
    flights: list[str] = Field(default_factory=list)
    disturbance: DisturbanceStats | None = None
    """``eps_w`` measured on the training flights (None: an error model from before it was)."""
    plant: str = "hover"
    """The model the disturbance ``eps_w`` was measured through (``FitOptions.plant``)."""
    dt: float | None = None
    """The training flights' sample period (s): windows, ``eps_w`` and the outlier counts are
    measured on steps of this length, so a controller of another ``dt`` cannot use them."""


def error_model_file(path: Path) -> Path:
    """``error_model.yaml`` given either the file or the ``qsls fit`` folder that holds it."""
    p = Path(path)
    f = p / ERROR_MODEL_FILE if p.is_dir() else p
    if not f.is_file():
        raise InputError(f"{p}: no {ERROR_MODEL_FILE}; pass the output of 'qsls fit'")
    return f


def resolve_model(path: Path) -> tuple[Path, Path]:
    """``(error_model.yaml, fit folder)`` from either."""
    f = error_model_file(path)
    return f, f.parent


def load_error_model(path: Path) -> ErrorModel:
    """Read ``error_model.yaml`` (or a fit folder holding it); clear errors when malformed."""
    import yaml
    from pydantic import ValidationError

    f = error_model_file(path)
    try:
        data = load_yaml(f.read_text(), f)
    except yaml.YAMLError:
        raise InputError(f"{f}: not valid YAML; regenerate it with 'qsls fit'") from None
    if not isinstance(data, dict):
        raise InputError(
            f"{f}: not an error model (expected a mapping); regenerate it with 'qsls fit'"
        )
    try:
        return ErrorModel.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(x) for x in first.get("loc", ()))
        raise InputError(
            f"{f}: malformed error model ('{loc}': {first.get('msg')}); regenerate it with 'qsls fit'"
        ) from None


def load_training_states(fit_dir: Path) -> pd.DataFrame:
    """``FITDIR/training_states.parquet``: the states (``x_*``, with ``e_*``) the model was fitted on."""
    import pandas as pd

    path = Path(fit_dir) / TRAINING_FILE
    if not path.is_file():
        raise InputError(
            f"{fit_dir}: no {TRAINING_FILE} beside {ERROR_MODEL_FILE}; pass the folder written "
            "by 'qsls fit'"
        )
    fix = "run 'qsls fit' again to rewrite it"
    check_stage_file(Path(fit_dir), TRAINING_FILE, fix)
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types for a corrupt or truncated file
        raise InputError(
            f"{path}: not a readable parquet file ({exc.__class__.__name__}); {fix}"
        ) from None
    return df

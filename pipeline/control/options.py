"""The options of ``qsls synth`` and ``qsls sweep`` (and their ``synth:`` / ``sweep:`` config
sections), apart from the stages: this module imports only pydantic, numpy and the plant's
constants, so ``qsls run`` validates a run config (:class:`qsls.pipeline.run.runner.RunConfig`)
without loading the solver. :mod:`qsls.pipeline.control.synth` and
:mod:`qsls.pipeline.control.sweep` re-export them."""

from __future__ import annotations

import math
from typing import Any, Literal, get_args

import numpy as np
from pydantic import Field, field_validator, model_validator

from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.core.cluster import DASK_SCHEMES as DASK_SCHEMES
from qsls.pipeline.core.cluster import SchedulerAddress
from qsls.pipeline.core.cluster import check_scheduler as check_scheduler
from qsls.pipeline.core.config import Options
from qsls.pipeline.core.plant import NU, NX, PAPER_DT_S, PAPER_MASS_KG, Plant


def psd_sqrt(m: np.ndarray, what: str = "matrix") -> np.ndarray:
    """Symmetric square root of a symmetric positive-definite matrix; ValueError otherwise."""
    m = np.atleast_2d(np.asarray(m, dtype=float))
    if m.shape[0] != m.shape[1] or not np.allclose(m, m.T, atol=1e-12 * max(1.0, np.abs(m).max())):
        raise ValueError(f"{what} must be a symmetric square matrix")
    w, v = np.linalg.eigh(m)
    if w.min() <= 0:
        raise ValueError(f"{what} must be positive definite (smallest eigenvalue {w.min():.3g})")
    return (v * np.sqrt(w)) @ v.T


Number = float | str


def _matrix(value: Any, n: int, what: str, psd: bool) -> list[list[float]]:
    """A list of ``n`` numbers (diagonal) or an ``n x n`` nested list -> nested list."""
    a = np.asarray(value, dtype=float)
    if a.ndim == 1:
        if a.shape != (n,):
            raise ValueError(
                f"{what} needs {n} diagonal entries or an {n}x{n} matrix, got {a.size}"
            )
        a = np.diag(a)
    if a.shape != (n, n):
        raise ValueError(f"{what} must be {n}x{n}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} has non-finite entries")
    if psd:
        psd_sqrt(a, what)
    return a.tolist()


class ProblemOptions(Options):
    """One synthesis problem's settings (shared by ``synth`` and ``sweep``)."""

    T: int = Field(20, ge=2, le=500)
    """FIR horizon T: the controller's taps 0..T (2 to 500)."""
    norm: Literal["l1", "h2"] = "l1"
    """The norm synthesized in: l1 (the paper's, peak to peak) or h2."""
    cost: Literal["qr", "imitation"] = "qr"
    """The cost: qr (the weights Q and R) or imitation (close to the controller ``imitate``
    names); with ``controllers: single``."""
    robust: bool = True
    """Impose the robustness constraint (with ``controllers: single``)."""
    strictly_proper: bool = False
    """u[k] from y up to k-1 only (Phi_uy(0) = 0)."""
    Q: list[list[float]] = Field(default_factory=lambda: np.diag([10.0, 10, 10, 1, 1, 1]).tolist())
    """State weight: 6 diagonal entries or a 6x6 matrix."""
    R: list[list[float]] = Field(default_factory=lambda: np.diag([1.0, 1, 0.1]).tolist())
    """Input weight: 3 diagonal entries or a 3x3 matrix."""
    eps_w: Number | None = None
    """Disturbance bound ||w|| <= eps_w: a number, max or pNN of the training flights' realized
    disturbance; default: its max (0.01 without an error model)."""
    H: list[list[float]] | None = None
    """The disturbance's input matrix H (x+ = A x + B u + H w): 6 diagonal entries or a 6x6
    matrix; default: the identity."""
    plant: Plant = "hover"
    """The linear model synthesized for: hover (the paper's 6 states) or attitude (with the
    attitude loop and the rotor lag as states, docs/model.md); the error model's disturbance
    must be measured through the same."""
    mass: float = Field(PAPER_MASS_KG, gt=0)
    """Vehicle mass in kg."""
    dt: float = Field(PAPER_DT_S, gt=0)
    """Controller period in s."""
    S: Number = "lofo"
    """S-slope: lofo (leave-one-flight-out, every left-out sample satisfies the premise), max /
    pNN / local_pNN (the error model's pair slopes), or a number."""
    eps_e: Number = "max"
    """Bound on the dense error |d|_e: max (training maximum), pNN or a number."""
    eps_groups: dict[Literal["position", "velocity"], float | Literal["max", "clip"]] | None = None
    """A bound on the dense error per channel group (the theorem with a vector of bounds,
    docs/guarantee.md#channel-groups): a number, max (the group's training maximum) or clip
    (velocities: w_e,v beta, which d = clip_beta(e) never exceeds); a group not named keeps
    eps_e; default: none (eps_e for every channel)."""
    measure: Literal["full", "position"] = "full"
    """Error channels the controller reads: full, or position only."""
    beta: float | None = Field(None, gt=0)
    """Velocity clip of the dense part: what it clips off is an outlier; default: none (no
    sparse part)."""
    error_scale: tuple[float, float, float, float, float, float] = (1.0,) * 6
    """W_e: 6 weights (x, y, z, vx, vy, vz) of the error norm |e|_e = ||W_e e||_inf."""
    m: int | Literal["auto"] = "auto"
    """Outliers allowed per window of T steps: a number, or auto (from outlier_risk, a binomial
    risk)."""
    eps_o: float | None = Field(None, ge=0)
    """Bound on one outlier (a physical bound; never the sample max); give it or gate when
    beta is set; default: none (2V - beta with a gate)."""
    outlier_risk: float = Field(1e-3, gt=0, lt=1)
    """Risk of a window holding more than m outliers."""
    gate: float | None = Field(None, gt=0)
    """Velocity gate V: the controller reads clip(y_v, v_ref +/- V), so an outlier is at most
    2V - beta (eps_o); needs beta; default: none (no gate)."""
    radius: float | None = Field(None, gt=0)
    """Radius r of the premise around the training states; default: the error model's."""
    delta: Number | None = None
    """Delta, the reference's largest distance to the training states; default: the error
    model's."""
    R0: Number | None = None
    """R0 for gamma_strict; default: the eps_e in use (so gamma_strict <= gamma)."""
    eps_b: float = Field(0.0, ge=0, le=5.0)
    """Bound on a constant acceleration bias, m/s^2 per axis (a heavier vehicle, a steady wind):
    the controller removes it by integral action and the premise allows it besides eps_w
    (docs/guarantee.md#the-bias-term); 0: neither."""
    pd: PDGains = PDGains()
    """The PD controller's gains (the baseline, and the imitation target pd)."""
    imitate: str = "pd"
    """Imitation target: pd, l1_nominal, h2_nominal or a controller folder."""
    solver: str = "CLARABEL"
    """cvxpy solver name."""

    @field_validator("Q", mode="before")
    @classmethod
    def _q(cls, v: Any) -> Any:
        return _matrix(v, NX, "Q", True)

    @field_validator("R", mode="before")
    @classmethod
    def _r(cls, v: Any) -> Any:
        return _matrix(v, NU, "R", True)

    @field_validator("H", mode="before")
    @classmethod
    def _h(cls, v: Any) -> Any:
        return None if v is None else _matrix(v, NX, "H", False)

    @field_validator("S", "eps_e", "eps_w", "delta", "R0")
    @classmethod
    def _nonneg(cls, v: Any) -> Any:
        if isinstance(v, int | float) and not (math.isfinite(v) and v >= 0):
            raise ValueError(f"must be a finite number >= 0, got {v}")
        return v

    @field_validator("eps_groups")
    @classmethod
    def _groups(cls, v: Any) -> Any:
        for g, b in (v or {}).items():
            if isinstance(b, int | float) and not (math.isfinite(b) and b > 0):
                raise ValueError(f"{g}: a group's bound must be a finite number > 0, got {b}")
        return v

    @field_validator("error_scale", mode="before")
    @classmethod
    def _scale_count(cls, v: Any) -> Any:
        if isinstance(v, list | tuple) and len(v) != NX:
            raise ValueError(f"needs {NX} weights (x, y, z, vx, vy, vz), got {len(v)}")
        return v

    @field_validator("m", mode="before")
    @classmethod
    def _m(cls, v: Any) -> Any:
        if v == "auto":
            return v
        if isinstance(v, bool) or not isinstance(v, int | float) or v < 0 or v != int(v):
            raise ValueError("must be a whole number >= 0 or 'auto'")
        return int(v)

    @field_validator("error_scale")
    @classmethod
    def _scale(cls, v: Any) -> Any:
        if any(not (math.isfinite(w) and w > 0) for w in v):
            raise ValueError(f"weights must be finite and > 0, got {list(v)}")
        return v


PaperRobust = Literal["l1_robust", "l1_robust_imitation"]


class PaperModeOptions(Options):
    """The paper's design beside the honest one (docs/paper.md,
    :mod:`qsls.pipeline.control.papermode`): its premise with a hand-picked S."""

    margin: float = Field(0.1, ge=0, lt=1)
    """``S_paper = min(S_hat, (1 - margin) S_max)``: the measured slope lowered only as far
    as the synthesis becomes feasible, then by this share of the largest feasible S."""
    controllers: list[PaperRobust] = Field(default_factory=lambda: list(get_args(PaperRobust)))
    """The robust controllers also synthesized under the paper's premise (named ``*_paper``)."""
    eps_e: Number = "max"
    """The paper's norm bound on the whole (unweighted) error: the training maximum, or a
    number."""


class SynthOptions(ProblemOptions):
    """Options of ``qsls synth``."""

    norm: Literal["l1", "h2", "both"] = "l1"  # type: ignore[assignment]
    """The norm synthesized in: l1 (the paper's, peak to peak), h2, or both (the H2 variants
    too)."""
    controllers: Literal["paper", "single"] = "paper"
    """paper (pd, then the nominal, robust and robust imitation controllers) or single (one,
    set by norm, cost and robust)."""
    paper_mode: PaperModeOptions | None = None
    """Also synthesize the paper's design (its premise, a chosen S; status ``chosen``)."""

    @model_validator(mode="after")
    def _single(self) -> SynthOptions:
        if self.controllers == "single" and self.norm == "both":
            raise ValueError("controllers: single needs norm l1 or h2")
        return self


AXES = (
    "S", "eps_e", "radius", "delta", "T", "q_scale", "r_scale", "eps_w", "norm", "cost",
    "robust", "strictly_proper",
)  # fmt: skip


class SweepOptions(ProblemOptions):
    """Options of ``qsls sweep``: the base problem plus ``grid`` (axis -> list of values)."""

    grid: dict[str, list[Any]] = Field(
        default_factory=lambda: {"S": [0.05, 0.1, 0.2], "T": [10, 20]}  # type: ignore[arg-type]
    )
    """Grid axes (S, eps_e, radius, delta, T, q_scale, r_scale, eps_w, norm, cost, robust,
    strictly_proper) and their values; every point is one synthesis. On the command line one
    axis per flag, ``AXIS=V1,V2,..`` (repeatable; replaces that axis of the config)."""
    certify: bool = True
    """Certify every feasible point (else only solve it)."""
    s_max_curve: bool = True
    """Also compute the largest feasible S for every T and error setting of the grid."""
    chunks_per_job: int = Field(4, ge=1)
    """Chunks handed to each worker (more: better balance, more scheduling)."""

    @field_validator("grid")
    @classmethod
    def _grid(cls, g: dict[str, list[Any]]) -> dict[str, list[Any]]:
        import difflib

        for key, values in g.items():
            if key not in AXES:
                near = difflib.get_close_matches(key, AXES, n=1)
                hint = f"; did you mean '{near[0]}'?" if near else f"; axes: {', '.join(AXES)}"
                raise ValueError(f"unknown grid axis '{key}'{hint}")
            if not isinstance(values, list) or not values:
                raise ValueError(f"grid axis '{key}' needs a non-empty list of values")
        return g


class SweepSection(SweepOptions):
    """The ``sweep:`` section of a config file, the same for ``qsls sweep --config`` and
    ``qsls run``: the sweep's options plus where it runs (which changes no result, so only
    :meth:`options` is the stage's record and cache key)."""

    jobs: int | None = Field(None, ge=0)
    """Local worker processes; default: all cores."""
    scheduler: SchedulerAddress | None = None
    """Dask scheduler address ``SCHEME://HOST:PORT``, e.g. tcp://127.0.0.1:8786 (instead of
    ``jobs``); default: none, local processes."""
    wait_workers: float = Field(60.0, gt=0)
    """With ``scheduler``: seconds to wait for a first worker, and for one to come back when
    all have left, before giving up."""

    @model_validator(mode="after")
    def _one_executor(self) -> SweepSection:
        if self.jobs is not None and self.scheduler is not None:
            raise ValueError("give jobs or scheduler, not both")
        return self

    def options(self) -> SweepOptions:
        """The sweep's own options (without ``jobs``, ``scheduler``, ``wait_workers``)."""
        return SweepOptions.model_validate({k: getattr(self, k) for k in SweepOptions.model_fields})

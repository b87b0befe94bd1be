"""The paper mode (docs/paper.md): the paper's design beside the honest one.

The paper measured ``S_hat = 11.7`` in simulation, found the synthesis infeasible and "took
the estimate of the S-slope far less conservative, such that the SLS procedure is feasible"
(paper, Perception Error Profile). Its premise is Dean et al.'s, unweighted: one norm bound
``eps_e`` on the whole error (the training maximum, no outlier channel, no gate), its
constraint ``(S + eps_e / r) ||Phi_xe|| + (eps_w N_w + Delta) / r <= 1`` (the paper's
``||Phi_xw H w - x_d||`` as qsls bounds it, docs/guarantee.md). qsls picks S as code, the way
the paper did, with a stated margin:

    S_max   = the largest S for which that synthesis is feasible   (largest_s, Dinkelbach)
    S_paper = min(S_hat, (1 - margin) S_max)

``S_hat`` is the error model's largest pair slope (the paper's estimator): lowered only as
far as the synthesis becomes feasible, then by ``margin`` of ``S_max`` so that the robust
problem keeps room for its cost. Every check of the certificate is run on the taps, but the
premise's S was chosen, not measured: the status is ``chosen`` (never ``certified``), its
reason states ``S_hat``, ``S_max``, the margin and ``S_paper``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.design import (
    Built,
    certified_controller,
    controller_plan,
    design,
    imitation_target,
)
from qsls.pipeline.control.options import PaperModeOptions, SynthOptions
from qsls.pipeline.control.problem import Resolved, resolve
from qsls.pipeline.control.status import CHOSEN, RELAXED
from qsls.pipeline.core.errors import InfeasibleError
from qsls.pipeline.premise.choose import ModelInput, largest_pair_slope

SUFFIX = "_paper"
"""A paper-mode controller is named after its honest twin with this suffix."""


@dataclass(frozen=True)
class PaperChoice:
    """The S the paper mode picked and the numbers it was picked from (module docstring)."""

    S: float
    S_max: float
    S_hat: float
    margin: float
    eps_e: float
    radius: float

    def reason(self) -> str:
        """The certificate's ``status_reason``: the premise was chosen, not measured."""
        return (
            f"paper mode: S = {self.S:.4g} was chosen, not measured (the paper's procedure: the "
            f"measured S_hat = {self.S_hat:.4g} lowered to (1 - margin) S_max, S_max = "
            f"{self.S_max:.4g} the largest S at which the synthesis is feasible, margin "
            f"{self.margin:g}); eps_e = {self.eps_e:.4g} is the training maximum, no outlier "
            "channel; no guarantee is claimed for any flight"
        )

    def record(self) -> dict[str, float]:
        return {
            "S": self.S, "S_max": self.S_max, "S_hat": self.S_hat, "margin": self.margin,
            "eps_e": self.eps_e, "radius": self.radius,
        }  # fmt: skip


def paper_options(opts: SynthOptions, S: float, eps_e: float | str = "max") -> SynthOptions:
    """The paper's premise on ``opts``'s problem: S given, ``eps_e`` the training maximum of
    the unweighted error (or ``eps_e``), one bound on every channel (no ``eps_groups``), no
    outlier channel (no beta, gate or ``eps_o``); the plant, cost, horizon, radius, ``H`` and
    ``eps_w`` stay the honest design's."""
    return opts.model_copy(
        update={
            "S": float(S), "eps_e": eps_e, "measure": "full", "beta": None, "gate": None,
            "eps_o": None, "error_scale": [1.0] * len(opts.error_scale), "eps_groups": None,
            "paper_mode": None,
        }
    )  # fmt: skip


def choose_s(s_hat: float, s_max: float, margin: float) -> float:
    """``S_paper = min(S_hat, (1 - margin) S_max)`` (module docstring)."""
    return min(s_hat, (1.0 - margin) * s_max)


def largest_feasible_s(r: Resolved, T: int, strictly_proper: bool, solver: str) -> float:
    """``S_max`` of the resolved premise (its own S plays no part)."""
    ms = largest_s.max_feasible_s(
        r.model, T, r.numbers, shape=r.shape, strictly_proper=strictly_proper, solver=solver
    )
    return ms.s_max


def paper_choice(
    opts: SynthOptions, mode: PaperModeOptions, source: ModelInput
) -> tuple[PaperChoice, Resolved]:
    """The chosen S and the paper's premise resolved at it; :class:`InfeasibleError` when
    no S >= 0 makes the paper's synthesis feasible."""
    r0 = resolve(paper_options(opts, 0.0, mode.eps_e), source)
    p = r0.numbers
    s_max = largest_feasible_s(r0, opts.T, opts.strictly_proper, opts.solver)
    if not s_max >= 0:
        raise InfeasibleError(
            f"paper mode: no S >= 0 is feasible under the paper's premise (eps_e = "
            f"{p.eps:.4g}, r = {p.radius:.4g}, eps_w = {p.eps_w:.4g}, Delta = "
            f"{p.delta:.4g}); raise radius or T, or drop paper_mode",
            {"eps_e": p.eps, "radius": p.radius},
        )
    s_hat = largest_pair_slope(source.model)
    S = choose_s(s_hat, s_max, mode.margin)
    choice = PaperChoice(S, s_max, s_hat, mode.margin, p.eps, p.radius)
    return choice, resolve(paper_options(opts, S, mode.eps_e), source)


def paper_controllers(
    opts: SynthOptions,
    source: ModelInput,
    done: Mapping[str, sls.Taps],
    extra: dict[str, Any],
    folder: sls.Taps | None = None,
) -> tuple[PaperChoice, dict[str, Built]]:
    """The paper-mode controllers (``l1_robust_paper``, ...) as :class:`Built`, each
    imitating what its honest twin imitates (``done``: the honest responses by name)."""
    assert opts.paper_mode is not None
    choice, r = paper_choice(opts, opts.paper_mode, source)
    plan = dict(controller_plan(opts))
    out: dict[str, Built] = {}
    for name in opts.paper_mode.controllers:
        st = plan[name]
        st = r.structure(st.T, st.norm, st.cost, st.robust, st.strictly_proper)
        nominal, ex = None, dict(extra)
        if st.cost.imitates:
            nominal = imitation_target(opts.imitate, opts.T, done, folder)
            ex["imitate"] = opts.imitate
        d = design(r, st, nominal=nominal, solver=opts.solver)
        if d.solution.taps is None or d.body is None:
            raise InfeasibleError(
                f"paper mode: {name} at the chosen S = {choice.S:.4g} did not solve "
                f"({d.solution.solver_status}); raise the margin",
                choice.record(),
            )
        built = certified_controller(name + SUFFIX, d, r, extra=ex)
        cert = built.certificate
        reason = choice.reason() if cert.status == RELAXED else (
            f"{cert.status_reason}; {choice.reason()}"
        )  # fmt: skip
        status = CHOSEN if cert.status == RELAXED else cert.status
        cert = cert.model_copy(update={"status": status, "status_reason": reason})
        out[name + SUFFIX] = Built(built.name, built.controller, cert, built.timings)
    return choice, out


__all__ = [
    "SUFFIX",
    "PaperChoice",
    "choose_s",
    "largest_feasible_s",
    "paper_choice",
    "paper_controllers",
    "paper_options",
]

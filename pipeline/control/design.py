"""One controller (:mod:`qsls.pipeline.control.synth` makes the paper's set of them): its
problem solved and its taps certified (:func:`design`), built into a controller with its
certificate (:func:`certified_controller`, :func:`pd_controller` for the PD reference), the
responses an imitation controller imitates (:func:`imitation_target`), and the plan of the
controllers a synth configuration asks for (:func:`controller_plan`). Below both
:mod:`~qsls.pipeline.control.synth` and :mod:`~qsls.pipeline.control.papermode`, which build on
it."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import (
    CONTROLLER_FILE,
    Certificate,
    CertificateBody,
    Controller,
)
from qsls.pipeline.control.certify import PREMISE_VIOLATED, certify, guarantee_fields
from qsls.pipeline.control.certify import certify as check  # design() has a `certify` flag
from qsls.pipeline.control.costs import IMITATION, QR, cost_of, name_of
from qsls.pipeline.control.guarantee import Norms
from qsls.pipeline.control.nominal import pd_responses, spectral_radius, static_gain_norms
from qsls.pipeline.control.options import SynthOptions
from qsls.pipeline.control.pdgain import PDGains
from qsls.pipeline.control.problem import Resolved
from qsls.pipeline.control.status import Status
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.premise.record import RESIDUAL


@dataclass(frozen=True)
class Design:
    """One solved controller problem (:func:`design`): the solver's answer and, when it gave
    taps, the certificate's body and the cost. ``qsls synth`` writes it as a controller folder
    (:func:`certified_controller`); a sweep row is its projection."""

    structure: sls.Structure
    solution: sls.Solution
    body: CertificateBody | None = None
    cost_value: float = math.nan


def design(
    r: Resolved,
    structure: sls.Structure,
    *,
    nominal: sls.Taps | None = None,
    solver: str = "CLARABEL",
    certify: bool = True,
) -> Design:
    """Solve one controller's problem and certify its taps (infeasible and failed solves are
    returned, not raised); ``certify=False`` only measures them (a ``reference`` body).
    ``relaxed`` instead of ``certified`` when the premise does not hold on all the training
    data."""
    values = r.values(nominal)
    sol = sls.solve(r.model, structure, values, solver=solver)
    if sol.taps is None:
        return Design(structure, sol)
    shape = replace(r.shape, gate=structure.gate)
    if certify:
        holds = r.premise is None or r.premise.holds
        body = check(
            sol.taps, r.model, r.numbers, shape, solver_status=sol.status, premise_holds=holds
        )
    else:
        body = check(sol.taps, r.model, r.numbers, shape, reference=True)
    cost = structure.cost.value(sol.taps, r.model, values, structure.norm)
    return Design(structure, sol, body, cost)


@dataclass(frozen=True)
class Built:
    """One synthesized (or reference) controller with its certificate, ready to write."""

    name: str
    controller: Controller
    certificate: Certificate
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def status(self) -> Status:
        return self.certificate.status

    @property
    def taps(self) -> sls.Taps:
        return self.controller.taps


def _built(
    name: str, ctrl: Controller, body: CertificateBody, setting: dict[str, Any],
    timings: dict[str, float],
) -> Built:  # fmt: skip
    premise = setting.get("premise")
    if body.status_reason and premise is not None and premise.S.violated is None:
        others = [e for k, e in premise.entries().items() if k != "S"]
        reason = body.status_reason
        if premise.n_excluded == 0 and all(e.violated == 0.0 for e in others):
            reason = reason.replace("; " + PREMISE_VIOLATED, "")  # nothing violated: untested
        body = body.model_copy(update={"status_reason": reason + "; " + S_UNTESTED})
    if body.status_reason and premise is not None and premise.eps_w_source == RESIDUAL:
        body = body.model_copy(update={"status_reason": body.status_reason + "; " + NO_INPUTS})
    cert = Certificate.of(body, **setting, controller_sha256=ctrl.sha256())
    return Built(name, ctrl, cert, timings)


S_UNTESTED = (
    "S cannot be tested: no two training flights share an environment (leave-one-flight-out "
    "needs a second flight of the same room and frame), so its value is assumed; certifiable "
    "with a second flight there"
)
NO_INPUTS = (
    "eps_w cannot be measured: the flights logged no inputs, and the input-free residual is a "
    "lower bound on any controller's disturbance; certifiable with the commands flown logged "
    "(qsls fit --inputs) on flights this controller flies (qsls calibrate)"
)


def certified_controller(
    name: str, d: Design, r: Resolved, *, extra: dict[str, Any] | None = None
) -> Built:
    """The controller of a solved :class:`Design` with its certificate."""
    sol, structure = d.solution, d.structure
    assert sol.taps is not None and d.body is not None
    setting = {
        "controller": name,
        "robust": structure.robust,
        "norm": structure.norm,
        "cost": name_of(structure.cost),
        "cost_value": d.cost_value,
        "objective": sol.objective,
        "strictly_proper": structure.strictly_proper,
        "T": structure.T,
        **r.record(),
        "gate": r.numbers.gate
        if structure.gate
        else None,  # only a gated design reads through the gate
        "tested_range": r.premise.tested_range if r.premise else None,
        "solver_status": sol.solver_status,
        "dt": r.model.dt,
        "mass": r.model.mass,
        "Q": r.Q.tolist(),
        "R": r.R.tolist(),
        **(extra or {}),
        "premise": r.premise,
    }
    timings = {"build_time_s": sol.build_time_s, "solve_time_s": sol.solve_time_s}
    return _built(name, Controller(sol.taps, r.model), d.body, setting, timings)


def pd_controller(r: Resolved, gains: PDGains, T: int, extra: dict[str, Any]) -> Built:
    """The PD reference: its responses truncated to ``T`` taps are stored, but its norms and
    guarantee numbers are the true closed loop's (:func:`nominal.static_gain_norms`), never the
    truncated ones, which underestimate them."""
    K, taps = pd_responses(r.model, gains, T)
    body = certify(taps, r.model, r.numbers, r.shape, reference=True)
    norms = static_gain_norms(r.model, K, T)
    # weighted norms of the closed loop bounded through its unweighted ones:
    # ||W_x Phi W_e^-1|| <= max w_x ||Phi|| max 1/w_e, G_m <= max w_x ||Phi_xy||, and
    # G_b <= max w_x ||Phi_xx H|| ||D_w|| (a partial sum is at most the sum of all taps)
    wx, we = max(r.shape.state_scale), 1.0 / min(r.shape.error_scale)
    nxy, nxx = norms["phi_xy"].value, norms["phi_xx_h"].value
    d_w = float(np.abs(r.model.bias_dirs).sum(axis=1).max())
    true = Norms(
        N=wx * nxy * we, N_w=wx * nxx, G_m=wx * nxy if r.numbers.m > 0 else 0.0, G_b=wx * nxx * d_w
    )
    true_norms = {f"norm_{k}": n.value for k, n in norms.items()}
    body = body.model_copy(update=true_norms | guarantee_fields(r.numbers, true))
    setting = {
        "controller": "pd",
        "robust": False,
        "norm": None,
        "cost": None,
        "strictly_proper": False,
        "T": T,
        **r.record(),
        "gate": None,
        "closed_loop_norms": norms,
        "closed_loop_spectral_radius": spectral_radius(r.model, K),
        "kp": list(gains.kp),
        "kd": list(gains.kd),
        "dt": r.model.dt,
        "mass": r.model.mass,
        **extra,
    }
    return _built("pd", Controller(taps, r.model, "static_gain", K), body, setting, {})


def nominal_from_folder(path: Path, T: int) -> sls.Taps:
    """The responses of the controller in ``path``, truncated (or padded) to ``T`` taps."""
    if not (Path(path) / CONTROLLER_FILE).is_file():
        raise InputError(
            f"imitate: {path} has no {CONTROLLER_FILE}; give pd, l1_nominal or a controller folder"
        )
    return Controller.load(Path(path)).taps.truncated(T)


IMITATE_NAMED = ("pd", "l1_nominal", "h2_nominal")
"""Imitation targets synthesized with the controllers; any other ``imitate`` is a folder."""


def imitation_target(
    target: str, T: int, done: Mapping[str, sls.Taps], folder: sls.Taps | None = None
) -> sls.Taps:
    """The responses an imitation controller imitates: the PD reference's or a nominal
    controller's among the responses already ``done`` (by name), or ``folder`` (a controller
    folder's, read by the stage)."""
    if target == "pd":
        return done["pd"]
    if target in done:
        return done[target].truncated(T)
    if target in IMITATE_NAMED:
        raise InputError(f"imitate: {target} is not synthesized by this configuration")
    if folder is None:
        raise InputError(f"imitate: {target}: the controller folder was not read")
    return folder


def controller_plan(opts: SynthOptions) -> list[tuple[str, sls.Structure]]:
    """``(name, structure)`` of every synthesized controller, in solve order."""
    T, sp_ = opts.T, opts.strictly_proper
    if opts.controllers == "single":
        rob = "robust" if opts.robust else "nominal"
        cost = cost_of(opts.cost)  # the config's name: the cost
        name = f"{opts.norm}_{rob}" + ("_imitation" if cost.imitates else "")
        return [(name, sls.Structure(T, cast(sls.Norm, opts.norm), cost, opts.robust, sp_))]
    norms: list[sls.Norm] = ["l1", "h2"] if opts.norm == "both" else [opts.norm]
    plan = []
    for n in norms:
        plan += [
            (f"{n}_nominal", sls.Structure(T, n, QR, False, sp_)),
            (f"{n}_robust", sls.Structure(T, n, QR, True, sp_)),
            (f"{n}_robust_imitation", sls.Structure(T, n, IMITATION, True, sp_)),
        ]
    return plan

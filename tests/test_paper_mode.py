"""The paper mode (docs/paper.md): S chosen the paper's way, checked against feasibility
solved independently just below and above the largest feasible S, and a status that says
the premise was chosen, not measured."""

from __future__ import annotations

from dataclasses import replace

import pytest

from qsls.pipeline.control import sls
from qsls.pipeline.control.options import SynthOptions
from qsls.pipeline.control.papermode import paper_choice, paper_controllers
from qsls.pipeline.control.status import CHOSEN
from qsls.pipeline.premise.choose import ModelInput

OPTS = SynthOptions(
    T=8, S=0.0, eps_e=0.02, eps_w=0.01, radius=1.0, delta=0.05,
    paper_mode={"margin": 0.2, "eps_e": 0.03, "controllers": ["l1_robust"]},
)  # fmt: skip


def _feasible(r, S: float) -> bool:
    st = r.structure(OPTS.T, "l1", "qr", True, False)
    v = sls.Values(Q=r.Q, R=r.R, numbers=replace(r.numbers, S=S))
    return sls.solve(r.model, st, v).status == "optimal"


def test_the_chosen_s_is_the_largest_feasible_less_the_margin():
    assert OPTS.paper_mode is not None
    choice, r = paper_choice(OPTS, OPTS.paper_mode, ModelInput())
    n = r.numbers
    assert (n.S, n.eps, n.eps_o, n.m) == (choice.S, 0.03, 0.0, 0)
    assert pytest.approx(0.8 * choice.S_max, rel=1e-12) == choice.S
    assert choice.S_max > 0
    assert _feasible(r, choice.S) and _feasible(r, 0.999 * choice.S_max)
    assert not _feasible(r, 1.01 * choice.S_max)


def test_the_status_says_chosen_not_certified():
    done = {}
    choice, built = paper_controllers(OPTS, ModelInput(), done, {"error_model": None})
    ((name, b),) = built.items()
    cert = b.certificate
    assert name == "l1_robust_paper" and cert.status == CHOSEN
    assert "was chosen, not measured" in (cert.status_reason or "")
    assert cert.S == choice.S and cert.robustness_lhs <= 1.0
    assert cert.S * cert.norm_phi_xy < 1.0  # the paper's strict bound is defined


def test_the_papers_premise_has_one_bound_even_when_the_honest_design_has_groups():
    """An honest design with a bound per channel group (eps_groups) leaves the paper's premise
    one unweighted bound: the groups' rescaled weights and S' = S eps / min eps_g would
    otherwise charge the chosen S twice, and the synthesis at 0.9 S_max was infeasible."""
    grouped = OPTS.model_copy(
        update={"eps_e": 0.4, "eps_groups": {"position": 0.4, "velocity": 0.1}}
    )
    assert grouped.paper_mode is not None
    choice, r = paper_choice(grouped, grouped.paper_mode, ModelInput())
    plain, _ = paper_choice(OPTS, OPTS.paper_mode, ModelInput())  # type: ignore[arg-type]
    assert choice.S_max == pytest.approx(plain.S_max, rel=1e-9)
    assert (r.numbers.S, r.numbers.eps) == (choice.S, 0.03)
    assert list(r.shape.error_scale) == [1.0] * 6
    assert _feasible(r, choice.S) and not _feasible(r, 1.01 * choice.S_max)
    _, built = paper_controllers(grouped, ModelInput(), {}, {"error_model": None})
    assert built["l1_robust_paper"].certificate.status == CHOSEN

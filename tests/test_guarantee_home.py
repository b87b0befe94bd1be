"""Every formula of the guarantee lives in ``control/guarantee.py`` (issue 36): evaluate,
calibration, synthesis and the report call it, so a change to the theorem is one change."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.control import guarantee

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"
FORMULAS = {
    "1 - S N": re.compile(r"\b1(\.0)?\s*-\s*[A-Za-z_.]*\bS\s*\*"),
    "1 - L N (any slope)": re.compile(
        r"\b1(\.0)?\s*-\s*[A-Za-z_.]+\s*\*\s*[A-Za-z_.]*(norm_phi_xy|\bN)\b"
    ),
    "eps + S d": re.compile(r"\beps(_e)?\s*\+\s*[A-Za-z_.]*\bS\s*\*"),
    "a = eps_w N_w + Delta": re.compile(r"eps_w\s*\*\s*[A-Za-z_.]*(N_w|norm_phi_xx_h)"),
}


def test_the_guarantee_formulas_are_written_only_in_guarantee_py():
    found = []
    for f in sorted(PIPELINE.rglob("*.py")):
        if f.name == "guarantee.py" and f.parent.name == "control":
            continue
        for n, line in enumerate(f.read_text().splitlines(), 1):
            code = line.split("#")[0]
            if code.strip().startswith(('"', 'f"', "'")):
                continue  # prose in a docstring or message
            for name, pat in FORMULAS.items():
                if pat.search(code):
                    found.append(f"{f.relative_to(PIPELINE)}:{n}: {name}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_formulas_against_hand_computation():
    assert guarantee.denominator(0.2, 3.0) == pytest.approx(0.4)
    assert guarantee.gamma_of(0.1, 0.2, 3.0, 0.5) == pytest.approx((0.1 + 0.2 * 0.5) / 0.4)
    np.testing.assert_allclose(
        guarantee.gamma_of(0.1, 0.2, 3.0, np.array([0.0, 1.0])), [0.25, 0.75]
    )
    assert guarantee.gamma_of(0.1, 0.5, 3.0, 1.0) == np.inf  # S N >= 1: no bound
    assert guarantee.gamma_strict_of(0.1, 0.5, 3.0) == np.inf
    assert guarantee.gamma_strict_of(0.1, 0.2, 3.0) == pytest.approx(0.25)
    assert guarantee.a_value(0.05, 4.0, 0.1) == pytest.approx(0.3)
    n = guarantee.Norms(N=2.0, N_w=4.0, G_m=1.0)
    given = guarantee.PremiseNumbers(eps=0.0, S=0.0, radius=2.0, eps_w=0.05, delta=0.1, eps_o=0.2)
    rho = guarantee.largest_slope(n, given)
    assert rho == pytest.approx((1 - 0.05 - (0.2 + 0.2) / 2) / 2)
    # the largest slope is where the robustness condition binds (eps = 0)
    p = guarantee.PremiseNumbers(eps=0.0, S=rho, radius=2.0, eps_w=0.05, delta=0.1, eps_o=0.2)
    assert guarantee.robustness_lhs(p, n) == pytest.approx(1.0)

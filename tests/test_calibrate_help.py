"""``qsls calibrate --help`` and its hints (issue 50): the example can certify (range flights
over a tube: the defaults, 0 and 0, can only give ``extrapolated``), hints name the command
line's flags, and the counts are stated right (conformal needs 9 for any calibrated premise
at alpha 0.1, certified needs 19)."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.calibrate.core import Rule, Scores, decide
from qsls.pipeline.calibrate.options import CalibrateOptions
from qsls.pipeline.control import conformal
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.premise.numbers import PremiseNumbers


def test_the_help_example_flies_what_certified_needs():
    text = CliRunner().invoke(app, ["calibrate", "--help"], terminal_width=200).output
    example = text.split("Example:")[1]
    first = next(ln for ln in example.splitlines() if ln.strip().startswith("qsls calibrate"))
    flights = re.search(r"--range-flights (\d+)", first)
    tube = re.search(r"--tube ([0-9.]+)", first)
    assert flights and tube, first
    opts = CalibrateOptions(range_flights=int(flights.group(1)), tube=float(tube.group(1)))
    assert opts.range_flights > 0 and opts.tube > 0
    assert CalibrateOptions().range_flights == 0  # the defaults cannot reach rho*
    assert opts.flights >= conformal.MIN_FLIGHTS  # the default count is enough for certified
    assert str(conformal.MIN_FLIGHTS) in example and "extrapolated" in example


def test_hints_name_the_flags():
    with pytest.raises(ConfigError, match=r"^--range-flights needs --tube > 0"):
        CalibrateOptions(range_flights=5).seed_lists()
    with pytest.raises(ConfigError, match=r"move --seed past them \(calibrate\.seed in a config\)"):
        CalibrateOptions(design_seeds=[1003]).seed_lists()
    with pytest.raises(ConfigError, match=r"move --validation-seed past them"):
        CalibrateOptions(flights=20, seed=2000).seed_lists()


def test_too_few_flights_say_both_counts():
    assert conformal.smallest_flights(0.1, "conformal") == 9
    numbers = PremiseNumbers(eps=0.1, S=0.0, radius=1.0, eps_w=0.01, delta=0.0)
    d = decide(Scores((0.5,) * 5, reached=(0.1,) * 5), numbers, None, Rule(0.1))  # type: ignore[arg-type]
    status, reason, lam = d.status, d.reason, d.lambda_hat
    assert status == "relaxed" and lam == float("inf")
    assert reason == (
        "5 calibration flights cannot support alpha 0.1 (conformal needs 9 for any calibrated "
        "premise, certified needs 19: --flights 19)"
    )

"""The console gives the answer (issue 16, item 10): `qsls evaluate` and `qsls run` end with
each controller's verdict (holds / FAILS, worst ratio), exit 0 for a completed evaluation."""

from __future__ import annotations

import re

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from tests.test_evaluate import circle_states, setup, write_flight  # noqa: F401 (fixture)


def _verdict_lines(output: str) -> dict[str, str]:
    return {
        m.group(1): m.group(2)
        for m in re.finditer(r"^  (\S+): (holds|FAILS|no certified bound), .*$", output, re.M)
    }


def test_evaluate_ends_with_the_verdict_per_controller(setup):  # noqa: F811 (the fixture)
    tmp, model, ctrl, spiky = setup
    res = CliRunner().invoke(
        app, ["evaluate", "--model", str(model), "--controller", str(ctrl),
              "--flights", str(spiky), "--out", str(tmp / "ev"), "--no-figures"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    tail = res.output.strip().splitlines()[-2:]
    assert tail[0] == "Certified bound on the held-out flights:"
    # the planted spike 0.2 against gamma = (0.05 + 0.2 (0.01*2 + 0.1)) / (1 - 0.2*2.5)
    gamma = (0.05 + 0.2 * (0.01 * 2.0 + 0.1)) / (1 - 0.2 * 2.5)
    assert (
        tail[1] == f"  l1_robust: FAILS, worst ||e||/gamma {0.2 / gamma:.3g} (held_out), 1 flight"
    )

    quiet = write_flight(tmp / "quiet", circle_states(100, z=1.05), np.full((100, 6), 0.02))
    res = CliRunner().invoke(
        app, ["evaluate", "--model", str(model), "--controller", str(ctrl),
              "--flights", str(quiet), "--out", str(tmp / "ev2"), "--no-figures"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert _verdict_lines(res.output) == {"l1_robust": "holds"}
    ratio = float(re.search(r"worst \|\|e\|\|/gamma ([0-9.e-]+)", res.output).group(1))
    # ||e|| = 0.02 everywhere, 0.05 from the training states: gamma = (0.05 + 0.2 (0.02 + 0.05)) / 0.5
    assert ratio == pytest.approx(0.02 / ((0.05 + 0.2 * (0.02 + 0.05)) / 0.5), abs=5e-4)

"""The console gives the answer (issue 16, item 10): `qsls evaluate` and `qsls run` end with
each controller's verdict (holds / FAILS, worst ratio), exit 0 for a completed evaluation."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from tests.test_evaluate import circle_states, setup, taps, write_flight  # noqa: F401 (fixtures)


def _verdict_lines(output: str) -> dict[str, str]:
    return {
        m.group(1): m.group(2)
        for m in re.finditer(
            r"^  (\S+): (holds|FAILS|no certified bound|premise only), .*$", output, re.M
        )
    }


def _evaluate(model, ctrl, flight, out, *extra):
    return CliRunner().invoke(
        app, ["evaluate", "--model", str(model), "--controller", str(ctrl),
              "--flights", str(flight), "--out", str(out), "--no-figures", *extra],
    )  # fmt: skip


def test_evaluate_ends_with_the_verdict_per_controller(setup):  # noqa: F811 (the fixture)
    tmp, model, ctrl, spiky = setup
    # a recorded flight: the theorem does not apply, the premise is what is checked
    res = _evaluate(model, ctrl, spiky, tmp / "ev0")
    assert res.exit_code == 0, res.output
    tail = res.output.strip().splitlines()[-3:]
    assert tail[0] == "Certified bound on the held-out flights:"
    # each controller's verdict is led by what its certificate promises, in one sentence
    assert tail[1].startswith("  With probability at least 0.9, a next 20 s flight of l1_robust")
    assert tail[2] == (
        "  l1_robust: premise only, dense premise holds at 99.5% of samples "
        "(not flown by it: the theorem does not apply; its disturbance, dist(x_hat) and "
        "invariance are not read); premise broken on held_out, 1 flight"
    )
    # flown by it: the planted spike 0.2 against gamma_nominal (x_hat = x - 2.5 e_{k-1})
    res = _evaluate(model, ctrl, spiky, tmp / "ev", "--flown-by", "l1_robust")
    assert res.exit_code == 0, res.output
    # the controller the fixture solves (test_evaluate.write_controller) has gamma_nominal
    # 0.075: the spike fails it (the fixture's hand-made certificate claimed more)
    assert _verdict_lines(res.output) == {"l1_robust": "FAILS"}
    row = pd.read_parquet(tmp / "ev" / "evaluation.parquet").iloc[0]
    assert f"worst ||e||/gamma_nominal {0.2 / row['gamma_nominal']:.3g} (held_out)" in res.output

    # the last sample's error 0.3 never reaches x_hat: a_nominal stays small and the bound
    # (eps_e + S a) / (1 - S ||Phi_xy||) <= (0.05 + 0.2 * 0.1) / 0.5 = 0.14 fails
    e = np.full((100, 6), 0.02)
    e[-1, 0] = 0.3
    late = write_flight(tmp / "late", circle_states(100, z=1.05), e)
    res = _evaluate(model, ctrl, late, tmp / "ev1", "--flown-by", "l1_robust")
    assert res.exit_code == 0, res.output
    assert _verdict_lines(res.output) == {"l1_robust": "FAILS"}

    quiet = write_flight(tmp / "quiet", circle_states(100, z=1.05), np.full((100, 6), 0.02))
    res = _evaluate(model, ctrl, quiet, tmp / "ev2", "--flown-by", "l1_robust")
    assert res.exit_code == 0, res.output
    assert _verdict_lines(res.output) == {"l1_robust": "holds"}
    ratio = float(re.search(r"worst \|\|e\|\|/gamma_nominal ([0-9.e-]+)", res.output).group(1))
    row = pd.read_parquet(tmp / "ev2" / "evaluation.parquet").iloc[0]
    assert ratio == pytest.approx(0.02 / row["gamma_nominal"], abs=5e-4)

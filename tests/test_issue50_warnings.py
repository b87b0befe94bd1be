"""Issue 50's last input-handling items: the warnings a user needs (an evaluated flight that
is a training flight's twin; ingest streams that look swapped; an implausible ingest error),
the calibration's refusal naming the premise quantity it found broken, the certificate
reader's alias refusal naming its file, and refusals that lead with what to do."""

from __future__ import annotations

import pytest

from qsls.pipeline.core.errors import InputError


def _bomb(levels: int = 9) -> list[str]:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 9)}]" for k in range(1, levels + 1)]
    return lines


def test_a_certificate_alias_bomb_refusal_names_the_file(tmp_path):
    from qsls.pipeline.control.artifacts import Certificate

    cert = tmp_path / "ctrl" / "certificate.yaml"
    cert.parent.mkdir()
    cert.write_text("controller: l1\n" + "".join(f"{ln}\n" for ln in _bomb()) + "b: *a9\n")
    with pytest.raises(InputError, match="expands to more than") as exc:
        Certificate.load(cert.parent)
    assert str(exc.value).startswith(f"{cert}:")


# --------------------------------------------------------------------------- no inflation covers
def _premise(**kw):
    from qsls.pipeline.control.guarantee import PremiseNumbers

    base = dict(eps=0.05, S=0.2, radius=1.0, eps_w=0.06, delta=0.3, eps_o=0.5, m=2)
    return PremiseNumbers(**{**base, **kw})


def _row(**kw):
    row = dict(dense=0.4, disturbance=0.7, reference=0.5, outliers=0.5, score=0.7,
               reached=0.2, w_max=0.04, window_max=1.0, ref_max=0.15, outlier_max=0.1)  # fmt: skip
    return {**row, **kw}


def test_the_calibration_refusal_names_the_reference_its_value_and_the_fix():
    """The issue's case: fitted without a reference, Delta is 0 and every calibration flight's
    reference part is inf; the refusal said only 'a premise quantity no inflation covers'."""
    import math

    from qsls.pipeline.evaluate.calibrate import decide
    from qsls.pipeline.evaluate.options import CalibrateOptions

    nominal = _premise(delta=0.0)
    rows = [_row(reference=math.inf, score=math.inf, ref_max=0.2 + 0.01 * k) for k in range(20)]
    status, reason, lam, *_ = decide(
        [r["score"] for r in rows], [r["reached"] for r in rows], nominal, None,
        CalibrateOptions(), broken=rows,
    )  # fmt: skip
    assert status == "relaxed" and math.isinf(lam)
    assert "reference (20 flights): dist(x_ref) reaches 0.39 over Delta 0" in reason
    assert "qsls fit --reference" in reason and "qsls synth --delta" in reason
    assert "disturbance" not in reason and len(reason) < 300


def test_the_refusal_names_each_infinite_quantity_once_with_its_largest_value():
    import math

    from qsls.pipeline.evaluate.broken import broken_premise

    rows = [
        _row(outliers=math.inf, score=math.inf, outlier_max=0.9),
        _row(outliers=math.inf, disturbance=math.inf, score=math.inf, outlier_max=1.3,
             w_max=0.02),
    ]  # fmt: skip
    text = broken_premise(rows, _premise(eps_w=0.0))
    assert "outliers (2 flights): an outlier of 1.3 exceeds eps_o 0.5" in text
    assert "disturbance (1 flight): ||H^-1 w|| reaches 0.02 over eps_w 0" in text
    assert text.index("disturbance") < text.index("outliers")  # the score table's order
    m0 = broken_premise([_row(outliers=math.inf, window_max=3.0)], _premise(m=0))
    assert "outliers (1 flight): 3 outliers in a window of T ticks over m 0" in m0

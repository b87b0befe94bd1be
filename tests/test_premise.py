"""The premise package (issue 49): one function chooses the premise, control reads what it
returns, and the record states the norms the synthesis used, with or without training data."""

from __future__ import annotations

import pytest

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.synth import SynthOptions, synthesize
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.premise.choose import ModelInput, choose_premise
from qsls.pipeline.premise.numbers import PremiseNumbers

W_E = (1.0, 1.0, 1.0, 2.0, 2.0, 2.0)


def test_choose_premise_numbers_and_record():
    """Given numbers are taken as they are; the record states each and how it was chosen."""
    opts = SynthOptions(T=6, S=0.1, eps_e=0.05, eps_w=0.004, radius=1.5, error_scale=W_E)
    numbers, premise = choose_premise(None, None, opts)
    assert numbers == PremiseNumbers(0.05, 0.1, 1.5, 0.004, 0.0, 0.0, 0, 0.05, None, 0.0)
    assert numbers.slope_ratio == pytest.approx(0.1 + 0.05 / 1.5)
    assert premise.error_scale == list(W_E)
    assert (premise.eps_e.chosen, premise.r.chosen, premise.Delta.chosen) == (
        "number",
        "number",
        "default",
    )
    with pytest.raises(InputError, match="S = 'lofo' names a number of an error model"):
        choose_premise(None, None, SynthOptions(T=6, eps_e=0.05, radius=1.0))


def test_certificate_without_training_data_states_its_weights(tmp_path):
    """Without an error model the premise record states the error weights the synthesis used,
    so the certificate's numbers recompute from its own file (a record of unit weights made
    its loader refuse it: robustness_lhs 0.267 stored, 0.302 recomputed)."""
    opts = SynthOptions(T=8, S=0.0, eps_e=0.05, eps_w=0.005, radius=1.0, error_scale=W_E,
                        controllers="single", robust=True)  # fmt: skip
    built = synthesize(ModelInput(), opts).controllers["l1_robust"]
    cert = built.certificate
    assert cert.premise is not None and cert.premise.error_scale == list(W_E)
    folder = tmp_path / "c"
    built.controller.save(folder)
    cert.save(folder)
    loaded = load_controller_dir(folder).certificate
    assert loaded.robustness_lhs == pytest.approx(cert.robustness_lhs, rel=1e-12)

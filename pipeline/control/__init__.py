"""``qsls synth`` and ``qsls sweep``: the plant, SLS synthesis, realization and certificates.

``plant`` is the quadrotor's LTI model (DESIGN.md, Model); ``sls`` the FIR synthesis problem;
``realize`` the filter bank; ``certify`` the checks behind every certificate.
"""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "LinearModel": "plant",
        "quadrotor_model": "plant",
        "Taps": "sls",
        "solve": "sls",
        "filter_bank": "realize",
        "load_controller": "realize",
        "certify": "certify",
        "SynthOptions": "synth",
        "synth": "synth",
        "SweepOptions": "sweep",
        "sweep": "sweep",
    },
)

"""``qsls synth`` and ``qsls sweep``: SLS synthesis, realization and certificates.

The quadrotor's LTI model is :mod:`qsls.pipeline.core.plant`; ``sls`` the FIR synthesis problem;
``realize`` the filter bank; ``certify`` the checks behind every certificate.
"""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "Taps": "sls",
        "solve": "sls",
        "filter_bank": "realize",
        "load_controller_dir": "artifacts",
        "Certificate": "artifacts",
        "CertificateBody": "artifacts",
        "synthesize": "synth",
        "SynthOptions": "options",
        "SweepOptions": "options",
    },
)

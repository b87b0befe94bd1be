"""``qsls export`` and ``qsls replay``: the certified controller as C or stdlib Python, and a dry
run of it on a recorded VIO stream.

``bank`` the exported layout, sizes and the certificate gate; ``c`` and ``python`` the code
generators; ``attitude`` the ``u`` + feedforward -> thrust + quaternion conversion; ``cbuild``
the system compiler and ctypes; ``stage`` the export command; ``replay`` the dry run.
"""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "ExportOptions": "options",
        "export": "stage",
        "c_runtime": "cbuild",
        "CController": "cbuild",
        "ReplayOptions": "options",
    },
)

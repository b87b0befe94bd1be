"""The premise a controller is designed and certified under: its numbers chosen from an error
model and the training flights (docs/guarantee.md, "The premise package"). One function,
:func:`~qsls.pipeline.premise.choose.choose_premise`, turns an error model, its training states
and the options into the premise's numbers and its record; control reads only what it returns."""

from qsls.pipeline.core.api import lazy_api

__all__, __getattr__ = lazy_api(
    __name__,
    {
        "choose_premise": "choose",
        "ModelInput": "choose",
        "read_model": "choose",
        "PremiseNumbers": "numbers",
        "Premise": "record",
        "PremiseEntry": "record",
        "TrainingStates": "measure",
    },
)

"""The certificates' bounds in the error model's norms (docs/guarantee.md#weighted-norms,
docs/evaluation.md#weighted-error-models): with ``W_x = diag(state_scale)`` and the
certificate's ``W_e`` the S-slope is a slope in the weighted distance, so the bound reads
``N = ||W_x Phi_xy W_e^-1||`` and ``N_w = ||W_x Phi_xx H||``, recomputed from the controller's
taps (its folder is read for them when the model is weighted)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import replace

from qsls.pipeline.control import guarantee
from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.control.nominal import static_gain_responses
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.evaluate.certified import ControllerBound


def weighted_bounds(
    bounds: Iterable[ControllerBound], state_scale: Sequence[float]
) -> list[ControllerBound]:
    """The bounds in the error model's norms (docs/guarantee.md#weighted-norms): with
    ``W_x = diag(state_scale)`` and the certificate's ``W_e``, the S-slope is a slope in the
    weighted distance, so the bound reads ``N = ||W_x Phi_xy W_e^-1||`` and
    ``N_w = ||W_x Phi_xx H||`` in place of ``||Phi_xy||`` and ``||Phi_xx H||`` (a static gain's
    tail beyond its taps weighted by the largest weight). Unchanged for an unweighted model;
    a certificate stating its premise in other state weights than the model's is refused."""
    scale = tuple(float(v) for v in state_scale)
    out = []
    for b in bounds:
        premise = b.certificate.get("premise") or {}
        stated = tuple(float(v) for v in premise.get("state_scale") or (1.0,) * len(scale))
        if stated != scale:
            raise InputError(
                f"{b.name}: its certificate states the premise in state_scale {list(stated)}, "
                f"the error model in {list(scale)}; check it against the error model it was "
                "synthesized from"
            )
        if all(v == 1.0 for v in scale):
            out.append(b)
            continue
        ctrl = load_controller_dir(b.folder).controller
        taps, model = ctrl.taps, ctrl.model
        tails = {"phi_xy": 0.0, "phi_xx_h": 0.0}
        if ctrl.kind == "static_gain" and ctrl.K is not None:
            true = ctrl.norms()
            tails = {k: true[k].tail_bound for k in tails}
            taps = static_gain_responses(model, ctrl.K, true["phi_xy"].horizon)
        extra = model.nx - len(scale)  # the attitude plant's states: unweighted, error-free
        sx = (*scale, *(0.0,) * extra)
        se = (*b.error_scale, *(1.0,) * (taps.Phi_xy.shape[2] - len(b.error_scale)))
        # every error channel, read or not, as the unweighted ||Phi_xy|| (a FIR controller's
        # unread columns vanish; a PD reads them all)
        channels = tuple(range(len(se)))
        norms = guarantee.system_norms(
            taps.Phi_xy, taps.Phi_xx @ model.H, state_scale=sx, error_scale=se, measured=channels
        )
        inv_e = guarantee.error_weights(se, channels)
        w = max(scale)
        out.append(
            replace(
                b,
                norm_phi_xy=norms.N + w * float(inv_e.max()) * tails["phi_xy"],
                norm_phi_xx_h=norms.N_w + w * tails["phi_xx_h"],
            )
        )
    return out

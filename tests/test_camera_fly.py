"""The fly stage with camera flights: no true Lipschitz constant is claimed for them."""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.evaluate.fly import FlyOutcome, _true_lipschitz


def _outcome(condition: str, lipschitz: float | None) -> FlyOutcome:
    z = np.zeros((0, 6))
    return FlyOutcome(
        name=f"{condition}_{lipschitz}", controller="pd", condition=condition, seed=0,
        metrics={}, ingest_error=None, t_ctrl=np.zeros(0), x_ctrl=z, ref_ctrl=z,
        u_ctrl=np.zeros((0, 3)), y_ctrl=z, t_vio=np.zeros(0), e_norm=np.zeros(0),
        u_pd=np.zeros((0, 3)), extra={"lipschitz": lipschitz},
    )  # fmt: skip


def test_camera_flights_claim_no_true_lipschitz():
    """Emulator flights give the largest L per condition; camera flights (L None) give none,
    so the findings skip the 'bound with the true L' comparison instead of reading L = 0."""
    emu = [_outcome("regular", 0.2), _outcome("regular", 0.3), _outcome("degraded", 0.5)]
    assert _true_lipschitz(emu) == {"regular": 0.3, "degraded": 0.5}
    cam = [_outcome("regular", None), _outcome("degraded", None)]
    assert _true_lipschitz(cam) == {}
    assert _true_lipschitz([*cam, emu[2]]) == {"degraded": 0.5}


def test_camera_flight_log_has_no_lipschitz():
    from qsls.pipeline.sim.closedloop import FlightOptions, fly

    cam = fly(FlightOptions.model_validate({"duration": 0.5, "vio": {"kind": "camera"}}))
    emu = fly(FlightOptions.model_validate({"duration": 0.5}))
    assert cam.lipschitz is None
    assert emu.lipschitz is not None and emu.lipschitz > 0


@pytest.mark.slow
def test_degraded_flight_that_diverged_now_resets_instead_of_crashing():
    """Degraded light, seed 4 (one of the fly stage's crashes): without the reset the
    estimate drifts until the vehicle is 3 m off the reference; with it the filter is
    re-initialized when the camera contradicts it and the flight completes."""
    from qsls.pipeline.sim.closedloop import FlightOptions, fly

    def flight(reset: bool):
        return fly(
            FlightOptions.model_validate(
                {
                    "seed": 4,
                    "duration": 30.0,
                    "controller": {"kind": "se3"},
                    "vio": {"kind": "camera", "perception": "degraded", "camera": {"reset": reset}},
                }
            )
        )

    off = flight(False)
    assert off.crashed and "3.00 m from the reference" in str(off.crash_reason)
    on = flight(True)
    assert not on.crashed and on.emulator["resets"] >= 1
    assert np.abs(on.vio_e[:, :3]).max() < 1.0

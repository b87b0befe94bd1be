"""The fast closed loop flies the same bits as the straightforward one (docs/performance.md#flights).

The plain-float RK4 step and the emulator's errors batched per controller tick
(:func:`qsls.pipeline.sim.closedloop.fly`) against ``stepwise=True`` (whole-array numpy
vehicle, one emulator call per VIO sample), and a short flight's end pinned to the numbers
the code before the change gave.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qsls.pipeline.sim.closedloop import FlightOptions, fly

# 3 s PD flight, degraded perception, a fault from 1 s: seed 7; computed by the code before
# the fast path (commit ffcada8): final [p, v, q, w], last VIO error, last command.
PINNED_STATE = [
    -0.12839786475810425, -0.18203037927412385, 0.3410149420145038, 0.051663437030805705,
    -0.04601828652955468, -0.0015897016715208509, 0.001034004958230387, 0.012509266655775855,
    -1.9299792139911302e-05, 0.999921221251454, -0.07000844154541347, -0.21526335042160216,
    0.001606205339813056,
]  # fmt: skip
PINNED_VIO_E = [
    0.0830263740983028, 0.030626086249946723, -0.017420552668817257, 0.09061418290940187,
    0.15710458510467354, 0.03479811546264294,
]  # fmt: skip
PINNED_U = [-0.019046537861807863, -0.000878540028047145, 2.5089502470662484]


def _options(crash: dict | None = None, **vio: object) -> FlightOptions:
    return FlightOptions.model_validate(
        {"duration": 3.0, "controller": {"kind": "pd"}, "seed": 7, "crash": crash or {},
         "vio": {"perception": "degraded", **vio}}
    )  # fmt: skip


def test_fast_flight_equals_stepwise_flight_bit_for_bit():
    opts = _options(fault={"start_s": 1.0, "bias": [0.05, 0, 0, 0, 0.1, 0]})
    fast, slow = fly(opts), fly(opts, stepwise=True)
    for f in dataclasses.fields(fast):
        a, b = getattr(fast, f.name), getattr(slow, f.name)
        if isinstance(a, np.ndarray):
            assert a.shape == b.shape and a.tobytes() == b.tobytes(), f.name
        else:
            assert a == b, f.name
    end = np.r_[fast.x[-1], fast.q[-1], fast.w[-1]]
    # the same machine gives the same bits; another BLAS may sum the 3x3 products otherwise
    np.testing.assert_allclose(end, PINNED_STATE, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.vio_e[-1], PINNED_VIO_E, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.ctrl_u[-1], PINNED_U, rtol=0, atol=1e-12)
    assert (len(fast.t_ns), len(fast.vio_t_ns), len(fast.ctrl_t_ns)) == (601, 301, 30)


def test_crashed_flight_keeps_every_sample_error():
    """A flight ending between two controller ticks (0.845 s; ticks every 0.1 s) still makes
    the errors of the samples since the last tick (0.81 to 0.84 s)."""
    opts = _options({"max_deviation": 0.12}, fault={"start_s": 0.5, "bias": [1.0, 0, 0, 0, 0, 0]})
    fast, slow = fly(opts), fly(opts, stepwise=True)
    assert fast.crashed and fast.crash_time_s == slow.crash_time_s == 0.845
    assert (len(fast.vio_t_ns), len(fast.ctrl_t_ns)) == (85, 9)
    assert np.array_equal(fast.vio_e, slow.vio_e) and np.array_equal(fast.x, slow.x)

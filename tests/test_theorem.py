"""The theorem-level verdict (issue 11): ``x_hat``, ``a_nominal``, ``gamma_nominal`` and
``bound_holds`` on closed loops with a known answer.

The adversary: a perception error ``e = b(x) = v * (eps_e + S_true d(x))`` with ``d(x)`` the
infinity-norm distance to the training states (a distance function: 1-Lipschitz) and
``|v_i| < 1``, one entry near 1: exactly ``S_true``-Lipschitz, ``||b|| <= eps_e`` on the training
states, and as large as the premise allows everywhere. The training states are a small
cloud ``Delta = 0.5`` away from where the vehicle hovers, so the distance term dominates. It
drives the certified controller (a real ``qsls synth`` output, run through its realized
filter bank) on the linear plant with bounded process noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.evaluate.certified import load_controller_bound
from qsls.pipeline.evaluate.check import check_flight
from qsls.pipeline.evaluate.theorem import nominal_states
from qsls.pipeline.evaluate.training import TrainingData
from qsls.pipeline.ingest.flight import make_flight_frame

S_CERT, EPS_E, EPS_W, RADIUS, DELTA = 0.05, 0.05, 0.01, 1.0, 0.5
SEEDS, STEPS = 200, 120


def test_nominal_states_equal_an_independent_convolution():
    rng = np.random.default_rng(7)
    T, n = 12, 300
    phi = rng.normal(size=(T + 1, 6, 6))
    x = rng.normal(size=(n, 6))
    e = rng.normal(size=(n, 6))
    want = x.copy()
    for i in range(6):  # state i = sum_j (Phi_ij * e_j), each by np.convolve
        for j in range(6):
            want[:, i] -= np.convolve(phi[:, i, j], e[:, j])[:n]
    np.testing.assert_allclose(nominal_states(x, e, phi), want, rtol=0, atol=1e-12)
    # a non-finite error poisons exactly the T + 1 samples whose sum it enters
    e[100, 2] = np.nan
    bad = ~np.isfinite(nominal_states(x, e, phi)).all(axis=1)
    assert np.flatnonzero(bad).tolist() == list(range(100, 100 + T + 1))


@pytest.fixture(scope="module")
def certified(tmp_path_factory):
    out = tmp_path_factory.mktemp("theorem") / "synth"
    args = ["synth", "--controllers", "single", "--S", str(S_CERT), "--eps-e", str(EPS_E),
            "--radius", str(RADIUS), "--delta", str(DELTA), "--eps-w", str(EPS_W), "-T", "20",
            "--out", str(out)]  # fmt: skip
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    return out / "l1_robust"


CLOUD = 0.005


def _training(seed: int = 0) -> np.ndarray:
    """Training states: a small cloud ``DELTA`` away (in ``px``) from hover at the origin."""
    x = np.random.default_rng(seed).uniform(-CLOUD, CLOUD, (300, 6))
    x[:, 0] += DELTA
    return x


class Adversary:
    """``b(x) = v * (eps_e + S_true d(x))`` for every seed at once (columns)."""

    def __init__(self, s_true: float, seeds: int, rng: np.random.Generator) -> None:
        self.s_true = s_true
        v = rng.uniform(-0.999, 0.999, (6, seeds))
        v[rng.integers(0, 6, seeds), np.arange(seeds)] = rng.choice([-0.999, 0.999], seeds)
        self.v = v
        self.training = TrainingData.build(_training(), np.ones(6))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """``x`` ``(6, seeds)`` -> ``e`` ``(6, seeds)``."""
        return self.v * (EPS_E + self.s_true * self.training.distance(x.T))[None, :]


def _fly(folder, s_true: float, seeds: int, steps: int, with_e: bool = True):
    """All seeds at once (the filter bank runs columns in parallel): ``(x, e, b)`` with
    ``x, e`` as ``(steps, 6, seeds)``; ``x_0 = 0``, ``||w_k|| <= eps_w``."""
    from qsls.pipeline.control.realize import RealizedController

    d = load_controller_dir(folder)
    model = d.controller.model
    runtime = RealizedController(d.controller.bank, model.dt)
    runtime.reset(seeds)
    rng = np.random.default_rng(1)
    b = Adversary(s_true, seeds, rng)
    w = rng.uniform(-EPS_W, EPS_W, (steps, 6, seeds))
    x = np.zeros((6, seeds))
    xs, es = np.zeros((steps, 6, seeds)), np.zeros((steps, 6, seeds))
    for k in range(steps):
        e = b(x) if with_e else 0 * x
        u = runtime.step(model.C @ x + e)
        xs[k], es[k] = x, e
        x = model.A @ x + model.B @ u + model.H @ w[k]
    return xs, es, b


def _rows(folder, xs, es, b):
    bound = load_controller_bound(folder)
    train_x = _training()
    training = TrainingData.build(train_x, np.ones(6))
    stamps = (np.arange(xs.shape[0]) * bound.dt * 1e9).round().astype(np.int64)
    rows = []
    for s in range(xs.shape[2]):
        frame = make_flight_frame(stamps, xs[:, :, s], xs[:, :, s] + es[:, :, s])
        row, _ = check_flight(f"s{s}", frame, bound, training, flown_by=bound.name)
        rows.append(row)
    return bound, rows


@pytest.mark.slow
def test_adversarial_closed_loop_bound_holds_on_every_seed(certified):
    xs, es, b = _fly(certified, S_CERT, SEEDS, STEPS)
    # the adversary's premise, checked independently: |b| <= eps_e on the training states
    # and S-Lipschitz on random pairs of states
    rng = np.random.default_rng(5)
    for x_d in _training()[::30]:
        assert np.abs(b(np.repeat(x_d[:, None], SEEDS, axis=1))).max() <= EPS_E
    x1, x2 = rng.normal(scale=0.3, size=(2, 6, SEEDS))
    lhs = np.abs(b(x1) - b(x2)).max(axis=0)
    assert np.all(lhs <= S_CERT * np.abs(x1 - x2).max(axis=0) + 1e-15)
    bound, rows = _rows(certified, xs, es, b)
    assert bound.has_guarantee and S_CERT * bound.norm_phi_xy < 1
    # x_hat is what the loop does without perception error: the same loop with e = 0
    xs0, _, _ = _fly(certified, S_CERT, SEEDS, STEPS, with_e=False)
    for s in (0, 17, 199):
        x_hat = nominal_states(
            xs[:, :, s], es[:, :, s], load_controller_dir(certified).controller.taps.Phi_xy
        )
        np.testing.assert_allclose(x_hat, xs0[:, :, s], rtol=0, atol=1e-12)
    assert all(r["theorem_applies"] for r in rows)
    assert all(r["frac_premise_holds"] == 1.0 for r in rows)  # the adversary obeys the premise
    assert all(bool(r["bound_holds"]) for r in rows), [
        r["verdict"] for r in rows if not r["bound_holds"]
    ]
    tight = np.array([r["nominal_ratio"] for r in rows])
    print(f"\ntightness max ||e|| / gamma_nominal over {SEEDS} seeds: "
          f"min {tight.min():.3f} median {np.median(tight):.3f} max {tight.max():.3f}")  # fmt: skip
    # the adversary pushes the error close to the bound: a loose or wrong gamma shows here
    assert 0.5 < tight.max() <= 1.0
    # a_nominal is the error-free loop's largest distance to the training states (brute force
    # over all pairs), not the flown state's max d_k
    train_x = _training()
    for s in (0, 17, 199):
        d = np.abs(xs0[:, None, :, s] - train_x[None, :, :]).max(axis=2).min(axis=1)
        assert rows[s]["a_nominal"] == pytest.approx(d.max(), rel=1e-9, abs=1e-12)
        assert rows[s]["a_nominal"] != pytest.approx(rows[s]["max_distance_to_training"])


@pytest.mark.slow
def test_half_the_true_slope_is_flagged_by_the_premise_check(certified):
    s_true = 2 * S_CERT
    xs, es, b = _fly(certified, s_true, SEEDS, STEPS)
    _, rows = _rows(certified, xs, es, b)
    failed = [r for r in rows if not r["bound_holds"]]
    assert failed, "certified at half the true slope, some flights should break the bound"
    for r in failed:  # every failure is explained by the premise failing on that flight
        assert r["frac_premise_holds"] < 1.0 and not r["assumption_holds"]
        assert "premise violated" in r["verdict"] and r["verdict"].startswith("FAILS")
    print(f"\nS certified at half the true slope: bound fails on {len(failed)} of {SEEDS} seeds")


def test_reference_pd_gets_its_closed_loop_norm_and_long_responses(certified):
    """The PD beside the certified controller is a closed loop, not a FIR: the bound uses its
    true ``||Phi_xy||`` (above the truncated taps') and ``x_hat`` from its responses to the
    horizon where the tail is negligible, which equals the loop flown without the error."""
    from qsls.pipeline.control.artifacts import load_runtime
    from qsls.pipeline.control.sls import l1_norm

    folder = certified.parent / "pd"
    bound = load_controller_bound(folder)
    ctrl = load_controller_dir(folder).controller
    assert ctrl.kind == "static_gain"
    assert bound.norm_phi_xy > l1_norm(ctrl.taps.Phi_xy) + 0.05  # truncation underestimates
    assert bound.phi_xy is not None and bound.phi_xy.shape[0] > ctrl.taps.T + 1
    assert bound.phi_xy_tail < 1e-9
    model, runtime = ctrl.model, load_runtime(folder)
    rng = np.random.default_rng(3)
    steps = 300
    e = rng.uniform(-0.05, 0.05, (steps, 6))
    w = rng.uniform(-EPS_W, EPS_W, (steps, 6))
    xs = np.zeros((2, steps, 6))
    for run, scale in enumerate((1.0, 0.0)):
        runtime.reset()
        x = np.zeros(6)
        for k in range(steps):
            xs[run, k] = x
            x = model.A @ x + model.B @ runtime.step(model.C @ x + scale * e[k]) + model.H @ w[k]
    np.testing.assert_allclose(nominal_states(xs[0], e, bound.phi_xy), xs[1], rtol=0, atol=1e-9)

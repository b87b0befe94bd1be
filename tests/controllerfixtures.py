"""Controllers built in memory for the direct export tests: a real SLS solve (Clarabel), the
certificate from ``certify()``, and a :class:`ControllerDir` that no file backs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qsls.pipeline.control import sls
from qsls.pipeline.control.artifacts import Certificate, Controller, ControllerDir
from qsls.pipeline.control.certify import certify
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.premise.numbers import PremiseNumbers

SETTING = PremiseNumbers(eps=0.05, S=0.05, radius=1.0, eps_w=0.01, delta=0.05, R0=0.05)
RECORD = {"S": 0.05, "eps_e": 0.05, "radius": 1.0, "eps_w": 0.01, "delta": 0.05, "R0": 0.05}


def independent_bank(taps: sls.Taps, ys: np.ndarray) -> np.ndarray:
    """The filter bank written from the export equations of docs/export.md with explicit tap loops::

    u[k]      = sum_{t>=1} Phi_ux(t) beta[k+1-t] + sum_{t>=0} Phi_uy(t) y[k-t]
    beta[k+1] = -sum_{t>=2} Phi_xx(t) beta[k+2-t] - sum_{t>=1} Phi_xy(t) y[k+1-t]

    (zero history before k = 0); ``u`` for every ``y`` in ``ys``."""
    T = taps.T
    n = len(ys)
    beta = np.zeros((n + 1, taps.Phi_xx.shape[1]))
    us = np.zeros((n, taps.Phi_ux.shape[1]))
    for k in range(n):
        u = sum(taps.Phi_uy[t] @ ys[k - t] for t in range(0, T + 1) if k - t >= 0)
        u = u + sum(taps.Phi_ux[t] @ beta[k + 1 - t] for t in range(1, T + 1) if k + 1 - t >= 0)
        us[k] = u
        nb = -sum(taps.Phi_xy[t] @ ys[k + 1 - t] for t in range(1, T + 1) if k + 1 - t >= 0)
        nb = nb - sum(
            (taps.Phi_xx[t] @ beta[k + 2 - t] for t in range(2, T + 1) if k + 2 - t >= 0),
            np.zeros_like(nb),
        )
        beta[k + 1] = nb
    return us


def synthesized(
    T: int = 8,
    *,
    strictly_proper: bool = False,
    name: str = "l1_robust",
    calibrated: Path | None = None,
) -> ControllerDir:
    """A robust L1 controller at horizon ``T`` with its certificate, as objects; with
    ``calibrated`` (a folder), written there and calibrated by :func:`as_calibrated`."""
    model = quadrotor_model()
    sol = sls.solve(
        model, sls.Structure(T, "l1", "qr", True, strictly_proper), sls.Values(numbers=SETTING)
    )
    assert sol.status == "optimal" and sol.taps is not None, sol.solver_status
    c = certify(sol.taps, model, SETTING)
    cert = Certificate.of(
        c,
        controller=name,
        robust=True,
        norm="l1",
        cost="qr",
        strictly_proper=strictly_proper,
        T=T,
        dt=model.dt,
        mass=model.mass,
        controller_sha256=Controller(sol.taps, model).sha256(),
        **RECORD,
    )
    if calibrated is not None:
        from qsls.pipeline.control.artifacts import load_controller_dir

        folder = Path(calibrated) / name
        folder.mkdir(parents=True, exist_ok=True)
        Controller(sol.taps, model).save(folder)
        cert.save(folder)
        return load_controller_dir(as_calibrated(folder))
    return ControllerDir(Path("/nowhere") / name, Controller(sol.taps, model), cert)


def gated(
    folder: Path,
    *,
    T: int = 20,
    eps_w: float = 0.01,
    radius: float = 2.0,
    gate: float | None = 1.5,
    beta: float | None = 0.2,
    m: int = 3,
    measure: str = "full",
    error_scale: tuple[float, ...] = (1, 1, 1, 0.5, 0.5, 0.5),
    H: tuple[float, ...] = (0.1, 0.1, 0.1, 1.0, 1.0, 1.0),
    name: str = "l1_gated",
    extra: dict | None = None,
) -> ControllerDir:
    """A certified robust L1 controller in the quickstart's shape (its ``H``, ``W_e``, ``beta``,
    gate and ``m``; ``eps`` 0.1, ``S`` 0, ``Delta`` 0), solved, certified and written to
    ``folder`` (``controller.npz`` and ``certificate.yaml`` with its premise record); ``extra``
    adds keys to the certificate file (a calibration block)."""
    import yaml

    from qsls.pipeline.control.artifacts import load_controller_dir
    from qsls.pipeline.premise.record import Premise, PremiseEntry

    model = quadrotor_model(H=np.diag(H))
    sparse = m if beta is not None and measure == "full" else 0
    eps_o = 2 * gate - beta if gate is not None and sparse else 0.0
    numbers = PremiseNumbers(
        eps=0.1, S=0.0, radius=radius, eps_w=eps_w, delta=0.0, eps_o=eps_o, m=sparse, gate=gate
    )
    shape = sls.Shape((1.0,) * 6, tuple(map(float, error_scale)), measure, sparse, gate is not None)
    st = sls.replace(shape.structure(T, "qr", False), robust=True)
    sol = sls.solve(model, st, sls.Values(numbers=numbers))
    assert sol.taps is not None, sol.solver_status
    body = certify(sol.taps, model, numbers, shape)
    assert body.status == "relaxed" and body.checks["robustness"]["passed"], body.checks

    def entry(v: float) -> PremiseEntry:
        return PremiseEntry(value=v, chosen="number")

    premise = Premise(
        eps_e=entry(0.1), S=entry(0.0), r=entry(radius), Delta=entry(0.0), eps_w=entry(eps_w),
        m=entry(sparse) if sparse else None, eps_o=entry(eps_o) if sparse else None,
        measure=measure, beta=beta, error_scale=list(map(float, error_scale)), gate=gate,
        eps_w_source="inputs", tested_range=0.3,
    )  # fmt: skip
    ctrl = Controller(sol.taps, model)
    cert = Certificate.of(
        body, controller=name, robust=True, norm="l1", cost="qr", strictly_proper=False, T=T,
        dt=model.dt, mass=model.mass, controller_sha256=ctrl.sha256(), S=0.0, eps_e=0.1,
        radius=radius, delta=0.0, eps_w=eps_w, R0=0.1, m=sparse, eps_o=eps_o, measure=measure,
        gate=gate, tested_range=0.3, premise=premise,
    )  # fmt: skip
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ctrl.save(folder)
    cert.save(folder)
    as_calibrated(folder)
    if extra:
        f = folder / "certificate.yaml"
        f.write_text(f.read_text() + yaml.safe_dump(extra, sort_keys=False))
        return ControllerDir(folder, ctrl, cert)  # the certificate model does not know the keys
    return load_controller_dir(folder)


def as_calibrated(folder: Path, n: int = 20) -> Path:
    """``folder``'s controller (written by synth, its design check passed) rewritten in place
    as the calibration stage writes one: the real decision and record
    (:func:`qsls.pipeline.calibrate.core.decide`, :func:`~.core.calibrated_certificate`) on a
    stand-in for ``n`` calibration flights that each scored exactly 1 and reached ``rho*``,
    so the premise is the design one and the status ``certified``. For tests of what reads a
    certified controller (export, replay), not of the calibration itself."""
    from qsls.pipeline.calibrate import core
    from qsls.pipeline.calibrate.core import Record, Rule, Scores
    from qsls.pipeline.control.artifacts import CERTIFICATE_FILE, load_controller_dir
    from qsls.pipeline.evaluate.certified import premise_of

    folder = Path(folder)
    d = load_controller_dir(folder)
    c = premise_of(d)
    assert c is not None, f"{folder}: no premise to calibrate"
    rule = Rule(0.1)
    scores = Scores((1.0,) * n, reached=(c.rho_star,) * n)
    o = core.decide(scores, c.numbers, core.responses(d), rule)
    assert o.status == "certified", o.reason
    parts = (dict.fromkeys(core.SCORED, 1.0),) * n
    conditions = {"perception": "regular", "stand_in": True}
    seeds = tuple(range(1000, 1000 + n))
    flown = (*seeds, *range(2000, 2020))  # and the default validation seeds
    record = Record(rule, conditions, 20.0, seeds, evidence_seeds=flown, parts=parts)
    cert = core.calibrated_certificate(d.certificate, c, o, record)
    (folder / CERTIFICATE_FILE).write_text(cert.to_yaml())
    return folder


def record_of(numbers: PremiseNumbers) -> dict:
    """The certificate's record of ``numbers`` (its keys: ``eps_e``, ``S``, ``radius``, ...)."""
    return {
        "S": numbers.S, "eps_e": numbers.eps, "radius": numbers.radius, "eps_w": numbers.eps_w,
        "delta": numbers.delta, "R0": numbers.eps if numbers.R0 is None else numbers.R0,
        "m": numbers.m, "eps_o": numbers.eps_o,
    }  # fmt: skip


def l1_taps(T: int = 8, numbers: PremiseNumbers = SETTING) -> sls.Taps:
    """A robust L1 solve at horizon ``T`` on :func:`quadrotor_model` under ``numbers``."""
    sol = sls.solve(
        quadrotor_model(), sls.Structure(T, "l1", "qr", True, False), sls.Values(numbers=numbers)
    )
    assert sol.status == "optimal" and sol.taps is not None, sol.solver_status
    return sol.taps


def written(
    folder: Path,
    taps: sls.Taps,
    numbers: PremiseNumbers = SETTING,
    *,
    calibrated: bool = True,
    status: str | None = None,
    **setting: object,
) -> Path:
    """``taps`` (on :func:`quadrotor_model`) written to ``folder`` with the certificate
    ``certify()`` gives under ``numbers``: every number is what a reader recomputes. With
    ``calibrated`` (its robustness check passed) rewritten by :func:`as_calibrated` (status
    ``certified``); else the status ``certify()`` gives, or ``status`` in its place (``failed``:
    one the taps never claim, which readers accept). ``setting`` adds certificate keys
    (``error_model_sha256``, ...)."""
    model = quadrotor_model()
    body = certify(taps, model, numbers)
    if status is not None:
        body = body.model_copy(update={"status": status, "status_reason": None})
    ctrl = Controller(taps, model)
    cert = Certificate.of(
        body, controller=Path(folder).name, robust=True, norm="l1", cost="qr",
        strictly_proper=False, T=taps.T, dt=model.dt, mass=model.mass,
        controller_sha256=ctrl.sha256(), **record_of(numbers), **setting,
    )  # fmt: skip
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ctrl.save(folder)
    cert.save(folder)
    return as_calibrated(folder) if calibrated else folder


def written_pd(
    folder: Path, numbers: PremiseNumbers = SETTING, T: int = 10, **setting: object
) -> Path:
    """The PD reference (:class:`PDGains`' defaults) written to ``folder`` as synth writes it:
    its ``T`` taps stored, the true closed loop's norms and guarantee numbers stated
    (:func:`qsls.pipeline.control.design.pd_controller`), status ``reference``."""
    from qsls.pipeline.control.certify import guarantee_fields
    from qsls.pipeline.control.guarantee import Norms
    from qsls.pipeline.control.nominal import pd_responses, static_gain_norms
    from qsls.pipeline.control.pdgain import PDGains

    model = quadrotor_model()
    K, taps = pd_responses(model, PDGains(), T)
    norms = static_gain_norms(model, K, T)
    true = Norms(N=norms["phi_xy"].value, N_w=norms["phi_xx_h"].value, G_m=0.0)
    body = certify(taps, model, numbers, reference=True)
    body = body.model_copy(
        update={f"norm_{k}": n.value for k, n in norms.items()} | guarantee_fields(numbers, true)
    )
    ctrl = Controller(taps, model, "static_gain", K)
    cert = Certificate.of(
        body, controller=Path(folder).name, robust=False, strictly_proper=False, T=T,
        dt=model.dt, mass=model.mass, controller_sha256=ctrl.sha256(), closed_loop_norms=norms,
        **record_of(numbers), **setting,
    )  # fmt: skip
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    ctrl.save(folder)
    cert.save(folder)
    return folder


def constant_break(
    n: int, f: float, k0: int, eps_w: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(w, e)`` for :func:`gated`'s shape: disturbances uniform within ``eps_w``, on vz
    ``(1 + f) eps_w`` from tick ``k0``; errors at their bound (0.1 on positions, ``beta`` 0.2
    on velocities) with random signs, vz's jumping from ``+beta`` to ``-beta`` at the break
    (the errors take ``2 beta`` off every window across it: the worst for a window test)."""
    rng = np.random.default_rng(seed)
    w = rng.uniform(-eps_w, eps_w, (n, 6))
    w[k0:, 5] = (1 + f) * eps_w
    e = np.zeros((n, 6))
    e[:, :3] = rng.choice([-1.0, 1.0], (n, 3)) * 0.1
    e[:, 3:] = rng.choice([-1.0, 1.0], (n, 3)) * 0.2
    e[k0:, 5], e[:k0, 5] = -0.2, 0.2
    return w, e


def at_limits(
    n: int, k0: int, sign: float, outliers: bool, rng: np.random.Generator, eps_w: float,
    gate: float = 1.5,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``(w, e)`` for :func:`gated`'s shape at the premise's limits: ``w = sign eps_w`` on every
    channel (each ``|H|`` row sums to its diagonal), velocity errors at ``-sign beta`` before
    ``k0`` and ``+sign beta`` from it (the jump every window across ``k0`` sees as
    ``+2 beta``), and with ``outliers`` up to ``m`` = 3 per ``T`` = 20 ticks of size ``eps_o``
    on the same side at random ticks; position errors random at their bound."""
    w = np.full((n, 6), sign * eps_w)
    e = np.zeros((n, 6))
    e[:, :3] = rng.choice([-1.0, 1.0], (n, 3)) * 0.1
    e[:, 3:] = np.where(np.arange(n)[:, None] < k0, -sign, sign) * 0.2
    if outliers:  # m = 3 in the first T of every 2 T ticks: at most m in any T consecutive
        for start in range(0, n - 20, 40):
            for k in rng.choice(np.arange(start, start + 20), 3, replace=False):
                e[k, 3:] += sign * (2 * gate - 0.2)
    return w, e

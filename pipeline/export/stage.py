"""``qsls export CONTROLLER_DIR --target c|python --out DIR``.

Reads the controller folder through :func:`~qsls.pipeline.control.artifacts.load_controller_dir`
(integrity: the sha256 its certificate records, gains that match the taps), refuses anything
but ``certified`` unless ``allow_uncertified``, writes the generated files with
:class:`~qsls.pipeline.core.artifacts.StageWriter` (stage ``export``), and checks what it
wrote against the Python realization (:func:`~qsls.pipeline.control.artifacts.load_runtime`):

- ``python``: the generated module, executed, over ``verify_ticks`` random bounded ``y``
  (velocities beyond a gate on about half the entries), against the realization fed the
  same deviations through the certificate's gate (the Python controller as it flies);
- ``c`` (when a C compiler is on PATH): the generated double-precision C, compiled with the
  strict flags and loaded with ctypes, over the same ticks.
- both: the refusal of a measurement that is not finite or beyond ``Y_MAX``
  (:func:`refusal_check`: ``u = 0``, the latched bit, the filter's memory unchanged), recorded
  as ``verify.refuses_nonfinite``. With ``precision: float`` the
  float build is also compared with the double build: over the random ticks (``u``) and in
  closed loop with the controller's own linear plant ``x[k+1] = A x + B u + H w``,
  ``y = C x + e`` driven by random ``||w|| <= eps_w``, ``||e|| <= eps_e`` (state, metres).

The manifest's ``results`` hold the sizes (state bytes, constant bytes, flops per tick) and
these checks; the files themselves are byte-identical for the same controller and options.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import (
    CERTIFICATE_FILE,
    CONTROLLER_FILE,
    load_controller_dir,
    load_runtime,
)
from qsls.pipeline.control.gate import gated_deviation
from qsls.pipeline.control.monitor import innovation_of
from qsls.pipeline.core.artifacts import StageWriter, check_output
from qsls.pipeline.core.plant import NX
from qsls.pipeline.export.bank import (
    INPUT_REFUSED,
    Y_MAX,
    ExportBank,
    check_exportable,
    export_bank,
    facts,
    sizes,
)
from qsls.pipeline.export.bank import facts as facts_of
from qsls.pipeline.export.c import c_files
from qsls.pipeline.export.cbuild import CController, compile_shared, find_compiler
from qsls.pipeline.export.options import ExportOptions
from qsls.pipeline.export.python import load_module, module

STAGE = "export"
Y_BOUND = 1.0
"""Random test inputs: ``y`` uniform in ``[-Y_BOUND, Y_BOUND]`` (m, m/s); with a velocity gate
``V`` the velocities uniform in ``[-2V, 2V]``, so the check exercises the clip."""


@dataclass(frozen=True)
class ExportResult:
    out: Path
    controller: str
    status: str
    files: list[str]
    results: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        r = self.results
        out: dict[str, Any] = {
            "output": str(self.out),
            "controller": f"{self.controller} ({self.status})",
            "files": ", ".join(self.files),
            "state (bytes)": r["state_bytes"],
            "constants (bytes)": r["const_bytes"],
            "flops per tick": r["flops_per_tick"],
        }
        v = r.get("verify", {})
        if "max_abs_diff" in v:
            gated = (
                f"; gate {v['gate']:g} m/s: {100 * v['clipped_ticks']:.0f} % of ticks had a "
                f"velocity deviation clipped to it, on purpose (the check draws velocity "
                f"deviations within +-{2 * v['gate']:g} so the written code's clipping is "
                "compared too)"
                if v.get("gate") is not None
                else ""
            )
            out["max |u - realization|"] = f"{v['max_abs_diff']:.3g} over {v['ticks']} ticks{gated}"
        elif "skipped" in v:
            out["check against realization"] = f"skipped: {v['skipped']}"
        f = r.get("float_vs_double")
        if f:
            if "skipped" in f:
                out["float vs double"] = f"skipped: {f['skipped']}"
            else:
                out["float vs double, max |du|"] = f["max_abs_du_random"]
                out["float vs double, closed loop max |dx| (m)"] = f["max_abs_dx_closed_loop"]
        return out


def _random_y(ticks: int, seed: int, gate: float | None = None) -> np.ndarray:
    """Random deviations: positions in ``[-Y_BOUND, Y_BOUND]``, velocities in ``[-2V, 2V]``
    with a gate ``V`` (about half the velocity entries are clipped), else ``[-Y_BOUND, Y_BOUND]``."""
    rng = np.random.default_rng(seed)
    ys = rng.uniform(-Y_BOUND, Y_BOUND, (ticks, 6))
    if gate is not None:
        ys[:, 3:] = rng.uniform(-2 * gate, 2 * gate, (ticks, 3))
    return ys


def reference_u(cdir: Any, ys: np.ndarray) -> np.ndarray:
    """``u`` of the Python controller as it flies (:class:`~qsls.pipeline.sim.controllers.
    LinearController`'s input): the realization fed the deviations through the certificate's
    gate (:func:`~qsls.pipeline.control.gate.gated_deviation`)."""
    return run_ticks(load_runtime(cdir.folder), gated_deviation(ys, cdir.certificate.gate))


def run_ticks(runtime: Any, ys: np.ndarray) -> np.ndarray:
    """``u`` (n, 3) of a runtime (``reset``, ``step``) fed ``ys`` (n, 6) from rest."""
    runtime.reset()
    return np.array([np.asarray(runtime.step(y), dtype=float) for y in ys]).reshape(-1, 3)


REFUSED_ENTRIES = (float("nan"), float("inf"), float("-inf"), 2 * Y_MAX)
"""What :func:`refusal_check` inserts, one per inserted tick."""


def refusal_check(runtime: Any, ys: np.ndarray) -> bool:
    """The step refuses a measurement holding an entry of :data:`REFUSED_ENTRIES`: ``u = 0``
    on it, :data:`INPUT_REFUSED` from it on (latched), and the other ticks' ``u`` exactly those
    of the same ticks without the refused ones (the filter's memory unchanged)."""
    ys = ys[:40]
    want = run_ticks(runtime, ys)
    at = {len(ys) // 4 + 3 * i: v for i, v in enumerate(REFUSED_ENTRIES)}
    runtime.reset()
    ok, got = True, []
    for k, y in enumerate(ys):
        if k in at:
            bad = np.array(y, dtype=float)
            bad[k % 6] = at[k]
            u = np.asarray(runtime.step(bad), dtype=float)
            ok = ok and bool(np.all(u == 0.0)) and runtime.flags == INPUT_REFUSED
        got.append(np.asarray(runtime.step(y), dtype=float))
        latched = bool(runtime.flags & INPUT_REFUSED)
        ok = ok and latched == (k >= min(at))
    return ok and bool(np.array_equal(np.array(got).reshape(-1, 3), want))


def closed_loop(runtime: Any, model: Any, w: np.ndarray, e: np.ndarray) -> np.ndarray:
    """States (n+1, 6) of ``x[k+1] = A x + B u + H w``, ``u = K(C x + e)`` from ``x = 0``."""
    runtime.reset()
    x = np.zeros(model.A.shape[0])
    xs = [x]
    for wk, ek in zip(w, e, strict=True):
        # the measured channels (an attitude-plant model's extra channels carry no error and
        # the exported step does not take them: docs/model.md)
        u = np.asarray(runtime.step((model.C @ x)[:NX] + ek[:NX]), dtype=float)
        x = model.A @ x + model.B @ u + model.H @ wk
        xs.append(x)
    return np.array(xs)


def _verify_c(
    files: dict[str, str], cdir: Any, options: ExportOptions, ys: np.ndarray, ref_u: np.ndarray
) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Compile the double (and float) build and compare (module docstring)."""
    cc = find_compiler(options.compiler)
    if cc is None:
        why = "no C compiler on PATH"
        return {"skipped": why}, ({"skipped": why} if options.precision == "float" else None)
    c = cdir.controller
    kw = dict(dt=c.dt, strictly_proper=c.strictly_proper, name=cdir.name)
    bank, fx = export_bank(cdir), facts_of(cdir)
    builds: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="qsls-export-") as tmp:
        for prec in dict.fromkeys(["double", options.precision]):
            src = (
                files if prec == options.precision else c_files(bank, fx, options.prefix, "double")
            )
            d = Path(tmp) / prec
            d.mkdir()
            for name, text in src.items():
                (d / name).write_text(text)
            lib = compile_shared(d / f"{options.prefix}.c", d / "lib.so", compiler=cc)
            builds[prec] = CController(lib, options.prefix, precision=prec, **kw)
        u_d = run_ticks(builds["double"], ys)
        verify = {
            "ticks": len(ys),
            **_clipped(ys, cdir.certificate.gate),
            "compiler": Path(cc).name,
            "max_abs_diff": float(np.abs(u_d - ref_u).max(initial=0.0)),
            "max_abs_u": float(np.abs(ref_u).max(initial=0.0)),
            "refuses_nonfinite": all(refusal_check(b, ys) for b in builds.values()),
        }
        if options.precision != "float":
            return verify, None
        u_f = run_ticks(builds["float"], ys)
        cert = cdir.certificate
        rng = np.random.default_rng(options.seed + 1)
        n = options.closed_loop_ticks
        w = rng.uniform(-cert.eps_w, cert.eps_w, (n, c.model.H.shape[1]))
        e = rng.uniform(-cert.eps_e, cert.eps_e, (n, c.model.C.shape[0]))
        x_d = closed_loop(builds["double"], c.model, w, e)
        x_f = closed_loop(builds["float"], c.model, w, e)
        fvd = {
            "ticks_random": len(ys),
            "max_abs_du_random": float(np.abs(u_f - u_d).max(initial=0.0)),
            "ticks_closed_loop": n,
            "max_abs_dx_closed_loop": float(np.abs(x_f - x_d)[:, :3].max(initial=0.0)),
            "max_abs_x_closed_loop": float(np.abs(x_d)[:, :3].max(initial=0.0)),
        }
        return verify, fvd


def _clipped(ys: np.ndarray, gate: float | None) -> dict[str, Any]:
    """The gate the check exercised: the share of ticks with a velocity entry clipped."""
    if gate is None:
        return {"gate": None}
    return {"gate": gate, "clipped_ticks": float((np.abs(ys[:, 3:]) > gate).any(axis=1).mean())}


def _verify_python(
    text: str, ys: np.ndarray, ref_u: np.ndarray, gate: float | None
) -> dict[str, Any]:
    mod: Any = load_module(text)
    u = run_ticks(mod.Controller(), ys)
    return {
        "ticks": len(ys),
        **_clipped(ys, gate),
        "max_abs_diff": float(np.abs(u - ref_u).max(initial=0.0)),
        "max_abs_u": float(np.abs(ref_u).max(initial=0.0)),
        "refuses_nonfinite": refusal_check(mod.Controller(), ys),
    }


def generate(bank: ExportBank, cdir: Any, options: ExportOptions) -> dict[str, str]:
    """The files of the export, by name."""
    fx = facts(cdir, options.limits)
    if options.target == "c":
        return c_files(bank, fx, options.prefix, options.precision)

    return {f"{options.prefix}.py": module(bank, fx)}


def export(folder: Path, options: ExportOptions, out: Path, *, force: bool = False) -> ExportResult:
    """Export one controller folder (module docstring)."""
    check_output(Path(out), force)
    cdir = load_controller_dir(folder)
    check_exportable(cdir, options.allow_uncertified)
    bank = export_bank(cdir)
    files = generate(bank, cdir, options)
    results: dict[str, Any] = {
        "controller": cdir.name,
        "status": cdir.certificate.status,
        "controller_sha256": cdir.certificate.controller_sha256,
        "target": options.target,
        "T": bank.T,
        "strictly_proper": cdir.controller.strictly_proper,
        **sizes(bank, options.precision, innovation_of(cdir)).as_dict(),
    }
    ys = _random_y(options.verify_ticks, options.seed, cdir.certificate.gate)
    ref_u = reference_u(cdir, ys)
    if options.target == "python":
        results["verify"] = _verify_python(
            next(iter(files.values())), ys, ref_u, cdir.certificate.gate
        )
    else:
        verify, fvd = _verify_c(files, cdir, options, ys, ref_u)
        results["verify"] = verify
        if fvd is not None:
            results["float_vs_double"] = fvd
    inputs = [cdir.folder / CONTROLLER_FILE, cdir.folder / CERTIFICATE_FILE]
    with StageWriter(Path(out), STAGE, options=options, inputs=inputs, force=force) as w:
        for name, text in files.items():
            w.write_text(name, text)
        w.results.update(results)
    return ExportResult(Path(out), cdir.name, cdir.certificate.status, sorted(files), results)

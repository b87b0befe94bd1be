"""``controller.npz`` (:class:`Controller`): the FIR responses ``Phi_xx, Phi_ux, Phi_xy,
Phi_uy`` (taps ``0..T``), the plant ``A, B, C, H``, ``dt``, ``mass``, ``kind``; for a filter bank
the realization gains ``K_bb, K_by, K_ub, K_uy`` (docs/synthesis.md#realization-the-filter-bank),
for a static gain (the PD reference) its ``K``. The gains are redundant with the taps: on load
they are recomputed from the taps and a file whose stored gains differ is refused. Also the
controller's name, which reaches generated code (:data:`CONTROLLER_NAME`)."""

from __future__ import annotations

import hashlib
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from qsls.pipeline.control.nominal import ClosedLoopNorm, static_gain_norms, static_gain_responses
from qsls.pipeline.control.realize import FilterBank, filter_bank
from qsls.pipeline.control.sls import RESPONSES, Taps, l1_norm
from qsls.pipeline.core.artifacts import atomic_write_bytes, npz_bytes
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.plant import LinearModel

CONTROLLER_FILE = "controller.npz"

Kind = Literal["filter_bank", "static_gain"]

GAIN_TOL = 1e-12
"""Largest relative difference between stored and recomputed realization gains."""

CONTROLLER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}")
"""A controller's name (its certificate's ``controller``, and the folder name an export reads):
a letter or ``_``, then letters, digits, ``_``, ``.`` or ``-``, at most 64 characters. The
name reaches generated code (docs/export.md), so nothing else is accepted."""
NAME_RULE = "a letter or '_', then letters, digits, '_', '.' or '-', at most 64 characters"


def name_problem(name: object) -> str | None:
    """Why ``name`` is not a controller name (:data:`CONTROLLER_NAME`), None when it is."""
    if isinstance(name, str) and CONTROLLER_NAME.fullmatch(name):
        return None
    shown = ascii(name)  # one line, every control or non-ASCII character escaped
    if len(shown) > 72:
        shown = shown[:69] + "..."
    return f"{shown} is not a controller name ({NAME_RULE})"


def check_controller_name(name: object, where: str) -> str:
    """``name`` when it is a controller name; otherwise a one-line :class:`InputError`."""
    why = name_problem(name)
    if why is not None:
        raise InputError(f"{where}: {why}; refusing it")
    assert isinstance(name, str)
    return name


def _plant_arrays(m: LinearModel) -> dict[str, np.ndarray]:
    return {"A": m.A, "B": m.B, "C": m.C, "H": m.H, "dt": np.array(m.dt), "mass": np.array(m.mass)}


@dataclass(frozen=True)
class Controller:
    """``controller.npz``: a controller's responses and plant (the gains follow from them)."""

    taps: Taps
    model: LinearModel
    kind: Kind = "filter_bank"
    K: np.ndarray | None = None
    """The static gain ``u = K y`` of a ``static_gain`` controller (the PD reference)."""

    @property
    def T(self) -> int:
        return self.taps.T

    @property
    def dt(self) -> float:
        return float(self.model.dt)

    @property
    def mass(self) -> float:
        return float(self.model.mass)

    @property
    def strictly_proper(self) -> bool:
        """``Phi_uy(0) = 0``: ``u[k]`` uses ``y`` up to ``k-1`` only."""
        return self.kind == "filter_bank" and not np.any(self.taps.Phi_uy[0])

    @property
    def bank(self) -> FilterBank:
        """The realization gains, derived from the taps (:func:`realize.filter_bank`)."""
        return filter_bank(self.taps)

    def norms(self) -> dict[str, ClosedLoopNorm]:
        """``phi_xy`` and ``phi_xx_h`` (``||Phi_xy||``, ``||Phi_xx H||``) of the closed loop this
        controller makes: of its taps for a filter bank (FIR: exact, no tail), of the whole
        closed loop for a static gain (:func:`nominal.static_gain_norms`; its taps are
        truncated)."""
        if self.kind == "static_gain":
            assert self.K is not None
            true = static_gain_norms(self.model, self.K, self.T)
            return {k: true[k] for k in ("phi_xy", "phi_xx_h")}
        fir = {
            "phi_xy": l1_norm(self.taps.Phi_xy),
            "phi_xx_h": l1_norm(self.taps.Phi_xx, self.model.H),
        }
        return {
            k: ClosedLoopNorm(value=v, lower=v, tail_bound=0.0, horizon=self.T, truncated=v)
            for k, v in fir.items()
        }

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array stored in ``controller.npz``."""
        out = {**self.taps.arrays(), **_plant_arrays(self.model), "kind": np.array(self.kind)}
        if self.kind == "static_gain":
            if self.K is None:
                raise ValueError("a static_gain controller needs K")
            out["K"] = np.asarray(self.K, dtype=float)
        else:
            out.update(self.bank.arrays())
        return out

    def to_bytes(self) -> bytes:
        """The deterministic bytes of ``controller.npz``."""
        return npz_bytes(self.arrays())

    def sha256(self) -> str:
        return hashlib.sha256(self.to_bytes()).hexdigest()

    def save(self, path: Path) -> Path:
        """Write ``path`` (a folder: ``path/controller.npz``) atomically."""
        f = in_folder(Path(path), CONTROLLER_FILE)
        atomic_write_bytes(f, self.to_bytes())
        return f

    @classmethod
    def load(cls, path: Path) -> Controller:
        """Read ``controller.npz`` (or a folder holding it); refuse gains that do not match the taps."""
        f = in_folder(Path(path), CONTROLLER_FILE)
        if not f.is_file():
            raise InputError(
                f"{f.parent}: no {CONTROLLER_FILE}; pass a controller folder written by 'qsls synth'"
            )
        try:
            with np.load(f, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise InputError(
                f"{f}: not a readable controller file ({exc}); regenerate it with 'qsls synth'"
            ) from None
        missing = [k for k in (*RESPONSES, "A", "B", "C", "H", "dt", "mass") if k not in arrays]
        if missing:
            raise InputError(
                f"{f}: missing {', '.join(missing)}; regenerate the controller with 'qsls synth'"
            )
        taps = Taps(**{n: np.asarray(arrays[n], dtype=float) for n in RESPONSES})
        model = LinearModel(
            A=arrays["A"], B=arrays["B"], C=arrays["C"], H=arrays["H"],
            dt=float(arrays["dt"]), mass=float(arrays["mass"]),
        )  # fmt: skip
        kind = str(arrays.get("kind", np.array("filter_bank")))
        if kind == "static_gain":
            if "K" not in arrays:
                raise InputError(f"{f}: a static_gain controller without K")
            K = np.asarray(arrays["K"], dtype=float)
            _check_static_gain(f, model, K, taps)
            return cls(taps, model, "static_gain", K)
        if kind != "filter_bank":
            raise InputError(f"{f}: unknown controller kind '{kind}'")
        ctrl = cls(taps, model, "filter_bank")
        _check_gains(f, arrays, ctrl.bank)
        return ctrl


def _check_static_gain(f: Path, model: LinearModel, K: np.ndarray, taps: Taps) -> None:
    """A static gain's stored taps are its closed loop's responses (``Phi_uy(0) = K``,
    ``Phi_xy(k) = A_cl^(k-1) B K``, ...): refuse a ``K`` that does not produce them."""
    ok = K.shape == (model.nu, model.ny)
    if ok:
        derived = static_gain_responses(model, K, taps.T)
        for name in RESPONSES:
            want, got = getattr(derived, name), getattr(taps, name)
            scale = max(1.0, float(np.abs(want).max(initial=0.0)))
            ok = ok and want.shape == got.shape and np.abs(want - got).max() <= GAIN_TOL * scale
    if not ok:
        raise InputError(
            f"{f}: gain K does not match the controller's taps (file altered?); "
            "refusing to use it: regenerate it with 'qsls synth'"
        )


def _check_gains(f: Path, arrays: dict[str, np.ndarray], bank: FilterBank) -> None:
    for name, derived in bank.arrays().items():
        stored = arrays.get(name)
        if stored is None:
            raise InputError(f"{f}: missing {name}; regenerate the controller with 'qsls synth'")
        scale = max(1.0, float(np.abs(derived).max(initial=0.0)))
        if stored.shape != derived.shape or np.abs(stored - derived).max() > GAIN_TOL * scale:
            raise InputError(
                f"{f}: gain {name} does not match the controller's taps (file altered?); "
                "refusing to use it: regenerate it with 'qsls synth'"
            )


def in_folder(path: Path, name: str) -> Path:
    """``path`` when it names the file ``name`` (or any ``.npz`` / ``.yaml``), else the file
    ``name`` in the folder ``path``."""
    return path if path.name == name or path.suffix in (".npz", ".yaml") else path / name

"""Compile the exported C with the system compiler and run it through ctypes.

:func:`compile_shared` builds a shared library from an export's ``.c`` file (strict flags:
``-std=c99 -Wall -Wextra -Werror -pedantic``); :class:`CController` is its runtime with the
interface of :class:`qsls.pipeline.control.realize.RealizedController` (``dt``, ``reset()``,
``step(y) -> u``), so the simulator can fly it. :func:`c_runtime` exports a controller folder
to a cache folder (keyed by the generated source's sha256) and loads it.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from qsls.pipeline.control.artifacts import load_controller_dir
from qsls.pipeline.core.errors import InputError
from qsls.pipeline.core.locks import make_temporary
from qsls.pipeline.export.bank import INPUT_REFUSED, export_bank, facts
from qsls.pipeline.export.c import c_files

STRICT = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic")
COMPILERS = ("cc", "gcc", "clang")


def find_compiler(preferred: str | None = None) -> str | None:
    """``$CC``, ``cc``, ``gcc`` or ``clang`` (the first on PATH); None when there is none."""
    names = [preferred] if preferred else [os.environ.get("CC", ""), *COMPILERS]
    for n in names:
        if n and (path := shutil.which(n)):
            return path
    return None


def compile_shared(
    c_file: Path, out: Path, *, compiler: str | None = None, opt: str = "-O2"
) -> Path:
    """Compile ``c_file`` (its header beside it) into the shared library ``out``."""
    cc = find_compiler(compiler)
    if cc is None:
        raise InputError("no C compiler found (tried $CC, cc, gcc, clang); install gcc or clang")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    folder = make_temporary(out)
    tmp = folder / out.name
    try:
        cmd = [cc, *STRICT, opt, "-fPIC", "-shared", "-o", str(tmp), str(c_file), "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0:
            first = (res.stderr.strip().splitlines() or ["(no message)"])[0]
            raise InputError(f"{Path(cc).name} failed on {c_file}: {first}")
        os.replace(tmp, out)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


class CController:
    """The exported C controller through ctypes: ``reset()``, ``step(y) -> u``."""

    def __init__(
        self,
        library: Path,
        prefix: str = "qsls_ctrl",
        *,
        precision: str = "double",
        dt: float,
        strictly_proper: bool = False,
        name: str = "",
        certificate: dict[str, Any] | None = None,
    ) -> None:
        self.library = Path(library)
        self._lib = ctypes.CDLL(str(self.library))
        real = ctypes.c_float if precision == "float" else ctypes.c_double
        self.real = real
        self.dt = float(dt)
        self.strictly_proper = bool(strictly_proper)
        self.name = name
        self.certificate = dict(certificate or {})
        size = getattr(self._lib, f"{prefix}_size")
        size.restype, size.argtypes = ctypes.c_size_t, []
        self.size = int(size())
        self._state = ctypes.create_string_buffer(self.size)
        self._reset = getattr(self._lib, f"{prefix}_reset")
        self._reset.restype, self._reset.argtypes = None, [ctypes.c_void_p]
        self._step = getattr(self._lib, f"{prefix}_step")
        self._step.restype = ctypes.c_int
        self._step.argtypes = [ctypes.c_void_p, ctypes.POINTER(real), ctypes.POINTER(real)]
        self._trips = getattr(self._lib, f"{prefix}_trips")
        self._trips.restype, self._trips.argtypes = ctypes.c_uint, [ctypes.c_void_p]
        self._first = getattr(self._lib, f"{prefix}_first_trip")
        self._first.restype, self._first.argtypes = ctypes.c_long, [ctypes.c_void_p]
        self._flown = getattr(self._lib, f"{prefix}_flown")
        self._flown.restype = None
        self._flown.argtypes = [ctypes.c_void_p, ctypes.POINTER(real)]
        self._refused = getattr(self._lib, f"{prefix}_refused")
        self._refused.restype, self._refused.argtypes = ctypes.c_uint, [ctypes.c_void_p]
        self.flags = 0
        """The step's bits of the last tick: the monitor's (docs/monitor.md) and
        :data:`INPUT_REFUSED` (latched from a refused measurement until :meth:`reset`)."""
        self._att = getattr(self._lib, f"{prefix}_attitude")
        self._att.restype = None
        ptr = ctypes.POINTER(real)
        self._att.argtypes = [ptr, ptr, real, ptr, ptr]
        self._y = (real * 6)()
        self._u = (real * 3)()
        self.reset()

    def reset(self) -> None:
        self._reset(self._state)
        self.flags = 0

    def step(self, y: np.ndarray) -> np.ndarray:
        """``u[k]`` (3,) from ``y[k]`` (6,); the step's bits go to :attr:`flags`. A None entry
        reaches the C step as NaN (refused: ``u = 0``, :data:`INPUT_REFUSED`); in the float
        build an entry beyond float range reaches it as inf (refused too)."""
        self._y[:] = [float(v) for v in np.asarray(y, dtype=float).reshape(6)]
        self.flags = int(self._step(self._state, self._y, self._u))
        return np.array(self._u[:], dtype=float)

    def flown(self, u: np.ndarray) -> None:
        """The command actually flown this tick (deviation) when it is not the step's ``u``
        (a fallback flies): the innovation monitor models the next measurement from it."""
        uu = (self.real * 3)(*[float(v) for v in np.asarray(u, dtype=float).reshape(3)])
        self._flown(self._state, uu)

    @property
    def trips(self) -> int:
        """Ticks on which the monitor tripped since reset."""
        return int(self._trips(self._state))

    @property
    def refused(self) -> int:
        """Measurements the step refused since reset (:data:`INPUT_REFUSED` set while > 0)."""
        return int(self._refused(self._state))

    @property
    def input_refused(self) -> bool:
        """The latched bit: a measurement was refused since reset; fly the fallback."""
        return bool(self.flags & INPUT_REFUSED)

    @property
    def first_trip(self) -> int | None:
        """The first tick (0 = the first after reset) on which the monitor tripped."""
        t = int(self._first(self._state))
        return None if t < 0 else t

    def attitude(
        self, u: np.ndarray, acc_ref: np.ndarray, yaw: float = 0.0
    ) -> tuple[float, np.ndarray]:
        """``(thrust, q [x, y, z, w])`` from the exported ``_attitude`` helper."""
        uu = (self.real * 3)(*[float(v) for v in u])
        aa = (self.real * 3)(*[float(v) for v in acc_ref])
        thrust = self.real(0.0)
        q = (self.real * 4)()
        self._att(uu, aa, self.real(float(yaw)), ctypes.byref(thrust), q)
        return float(thrust.value), np.array(q[:], dtype=float)


def cache_root() -> Path:
    return Path(tempfile.gettempdir()) / f"qsls-c-{os.getuid() if hasattr(os, 'getuid') else 0}"


def c_runtime(folder: Path, *, precision: str = "double", prefix: str = "qsls_ctrl") -> CController:
    """The controller folder exported to C, compiled (``-O2``, cached by source hash), loaded.

    Exports whatever the folder's status (the caller decides what may fly); the folder's
    integrity is checked by :func:`qsls.pipeline.control.artifacts.load_controller_dir`.
    """
    cdir = load_controller_dir(folder)
    files = c_files(export_bank(cdir), facts(cdir), prefix, precision)  # type: ignore[arg-type]
    key = hashlib.sha256("\0".join(files[k] for k in sorted(files)).encode()).hexdigest()[:24]
    lib = cache_root() / f"{prefix}-{key}.so"
    if not lib.is_file():
        with tempfile.TemporaryDirectory(prefix="qsls-c-") as tmp:
            for name, text in files.items():
                (Path(tmp) / name).write_text(text)
            compile_shared(Path(tmp) / f"{prefix}.c", lib)
    c = cdir.controller
    return CController(
        lib,
        prefix,
        precision=precision,
        dt=c.dt,
        strictly_proper=c.strictly_proper,
        name=cdir.name,
        certificate=cdir.certificate.model_dump(),
    )

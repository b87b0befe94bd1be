"""``pipeline/export/c.py`` called directly: its text compiled by gcc (strict flags) and run
through this test's own ctypes binding, against the Python realization, an independent filter
bank, and the closed-loop responses ``Phi`` themselves; its literals and tables read back."""

from __future__ import annotations

import ctypes
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from qsls.pipeline.control.artifacts import ControllerDir
from qsls.pipeline.control.realize import RealizedController
from qsls.pipeline.export.bank import export_bank, facts, sizes
from qsls.pipeline.export.c import c_files, header, literal, source
from qsls.pipeline.export.innovation import state_bytes as innovation_state_bytes
from tests.controllerfixtures import independent_bank, synthesized

T = 8
FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]


@pytest.fixture(scope="module")
def ctrls(tmp_path_factory: pytest.TempPathFactory) -> dict[str, ControllerDir]:
    root = tmp_path_factory.mktemp("ctrls")
    return {
        "proper": synthesized(T, strictly_proper=False, calibrated=root),
        "strict": synthesized(T, strictly_proper=True, name="l1_strict", calibrated=root),
    }


def _compile(
    gcc: str, folder: Path, files: dict[str, str], *extra: str, shared: bool = True
) -> Path:
    for name, text in files.items():
        (folder / name).write_text(text)
    out = folder / ("lib.so" if shared else "prog")
    cs = [str(folder / n) for n in files if n.endswith(".c")]
    cmd = [
        gcc,
        *FLAGS,
        *(["-fPIC", "-shared"] if shared else []),
        *extra,
        "-o",
        str(out),
        *cs,
        "-lm",
    ]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0 and res.stderr == "", res.stderr
    return out


class Bound:
    """This test's own ctypes view of ``PREFIX_size/_reset/_step``."""

    def __init__(self, lib: Path, prefix: str, precision: str = "double") -> None:
        self.lib = ctypes.CDLL(str(lib))
        self.real = ctypes.c_float if precision == "float" else ctypes.c_double
        size = getattr(self.lib, f"{prefix}_size")
        size.restype = ctypes.c_size_t
        self.size = int(size())
        self.state = ctypes.create_string_buffer(self.size)
        self._reset = getattr(self.lib, f"{prefix}_reset")
        self._step = getattr(self.lib, f"{prefix}_step")
        self.reset()

    def reset(self) -> None:
        self._reset(self.state)

    def step(self, y: np.ndarray) -> np.ndarray:
        yy = (self.real * 6)(*[float(v) for v in y])
        uu = (self.real * 3)()
        self._step(self.state, yy, uu)
        return np.array(uu[:], dtype=float)


def test_literals_read_back_bit_for_bit_in_c(tmp_path, gcc):
    rng = np.random.default_rng(5)
    xs = [0.0, -0.0, 1.0, -3.0, 0.1, 1e22, 1e-300, 5e-324, 123456789.0, 2.0**-40]
    xs += list(rng.normal(size=20) * 10.0 ** rng.integers(-12, 12, 20))
    assert literal(3.0, "double") == "3.0" and literal(3.0, "float") == "3.0f"
    assert literal(1e22, "double") == "1e+22" and literal(0.1, "float") == "0.100000001f"
    dbl = ", ".join(literal(x, "double") for x in xs)
    flt = ", ".join(literal(x, "float") for x in xs)
    prog = f"""#include <stdio.h>
static const double D[] = {{ {dbl} }};
static const float F[] = {{ {flt} }};
int main(void) {{
    unsigned i;
    for (i = 0u; i < sizeof D / sizeof D[0]; ++i) printf("%a %a\\n", D[i], (double)F[i]);
    return 0;
}}
"""
    exe = _compile(gcc, tmp_path, {"lit.c": prog}, shared=False)
    lines = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split(
        "\n"
    )
    for x, line in zip(xs, lines, strict=False):
        d, f = line.split()
        assert float.fromhex(d) == x and np.copysign(1, float.fromhex(d)) == np.copysign(1, x)
        assert float.fromhex(f) == float(np.float32(x))


def _tables(src: str) -> dict[str, np.ndarray]:
    """The four ``static const`` tables read back from the C text (flat, file order)."""
    out = {}
    for name in ("UY", "UX", "BB", "BY"):
        m = re.search(rf"static const \w+ {name}(?:\[[^\]]+\])+ = \{{(.*?)\n\}};", src, re.S)
        assert m, name
        nums = re.findall(r"-?\d[\d.]*(?:e[-+]?\d+)?f?", m.group(1))
        out[name] = np.array([float(s.rstrip("f")) for s in nums])
    return out


@pytest.mark.parametrize("which", ["proper", "strict"])
def test_tables_are_the_bank_and_header_states_the_facts(ctrls, which):
    cdir = ctrls[which]
    bank, fx = export_bank(cdir), facts(cdir)
    src = source(bank, fx, "qc", "double")
    tabs = _tables(src)
    for name, arr in (("UY", bank.uy), ("UX", bank.ux), ("BB", bank.bb), ("BY", bank.by)):
        np.testing.assert_array_equal(tabs[name], arr.ravel())  # bit for bit, C order
    assert sum(t.size for t in tabs.values()) == bank.constants()
    first = 1 if which == "strict" else 0
    assert f"static const qc_real_t UY[{T + 1 - first}][QC_NU][QC_NY]" in src
    assert "static const qc_real_t BB[QC_T - 1][QC_NX][QC_NX]" in src
    hdr = header(bank, fx, "qc", "double")
    defines = dict(re.findall(r"#define (QC_\w+) (\S+)", hdr))
    assert defines["QC_T"] == str(T) and defines["QC_NX"] == "6" and defines["QC_NU"] == "3"
    assert defines["QC_STRICTLY_PROPER"] == str(first)
    assert defines["QC_DT"] == "0.1" and defines["QC_MASS"] == "0.256"
    assert defines["QC_GRAVITY"] == "9.81" and defines["QC_STATUS"] == '"certified"'
    assert defines["QC_SHA256"] == f'"{cdir.controller.sha256()}"'
    assert hdr.startswith(f"/* CERTIFIED controller {cdir.certificate.controller}: the guarantee")
    assert " * GUARANTEE (docs/guarantee.md; every number is the certificate's):\n" in hdr
    assert f"rho* = {cdir.certificate.rho_star:.6g} <= r" in hdr
    assert "#define QC_GATED 0" in hdr and "no QC_GATE" in hdr
    assert "typedef double qc_real_t;" in hdr
    assert "typedef float qc_real_t;" in header(bank, fx, "qc", "float")


@pytest.mark.parametrize("which", ["proper", "strict"])
def test_compiled_step_is_the_realization(tmp_path, gcc, ctrls, which):
    cdir = ctrls[which]
    bank = export_bank(cdir)
    lib = _compile(gcc, tmp_path, c_files(bank, facts(cdir), "qc", "double"))
    c = Bound(lib, "qc")
    # two unsigned heads, the monitor's T + 5 counters and the refusal count (no padding), then
    # the innovation monitor's fields
    inn = innovation_state_bytes(facts(cdir).innovation, 8)
    base = (T * 6 + (T + 1) * 6) * 8 + (2 + T + 5 + 1) * 4
    assert inn > 0 and c.size == sizes(bank, "double", facts(cdir).innovation).state_bytes
    assert base + inn <= c.size < base + inn + 16  # padding only
    ys = np.random.default_rng(11).uniform(-1, 1, (400, 6))
    rt = RealizedController(cdir.controller.bank, cdir.controller.dt)
    want = np.array([rt.step(y) for y in ys])
    got = np.array([c.step(y) for y in ys])
    assert np.abs(want).max() > 1.0
    assert np.abs(got - want).max() <= 1e-12
    assert np.abs(got[:60] - independent_bank(cdir.controller.taps, ys[:60])).max() <= 1e-12
    c.reset()  # the ring heads and memory really return to zero
    np.testing.assert_array_equal(np.array([c.step(y) for y in ys[:30]]), got[:30])
    if which == "strict":  # u[k] never sees y[k]
        c.reset()
        assert np.all(c.step(np.full(6, 1e3)) == 0.0)


@pytest.mark.parametrize("which", ["proper", "strict"])
def test_compiled_closed_loop_reproduces_phi(tmp_path, gcc, ctrls, which):
    """Plant ``x+ = A x + B u + d`` with the compiled controller on ``y = x + e``: an impulse
    in each ``w`` and ``e`` channel gives back the columns of ``Phi`` (zero after tap T)."""
    cdir = ctrls[which]
    taps, model = cdir.controller.taps, cdir.controller.model
    c = Bound(
        _compile(gcc, tmp_path, c_files(export_bank(cdir), facts(cdir), "qc", "double")), "qc"
    )
    steps = 2 * T + 2
    worst = 0.0
    for j in range(12):
        c.reset()
        x = np.zeros(6)
        for k in range(steps):
            e = np.eye(6)[j - 6] if (j >= 6 and k == 0) else np.zeros(6)
            u = c.step(x + e)
            want_x = np.zeros(6)
            want_u = np.zeros(3)
            if k <= T:
                want_x = taps.Phi_xx[k][:, j] if j < 6 else taps.Phi_xy[k][:, j - 6]
                want_u = taps.Phi_ux[k][:, j] if j < 6 else taps.Phi_uy[k][:, j - 6]
            worst = max(worst, np.abs(x - want_x).max(), np.abs(u - want_u).max())
            x = model.A @ x + model.B @ u + (np.eye(6)[j] if (j < 6 and k == 0) else 0.0)
    assert worst <= 1e-9


def test_float_build_is_close_but_not_double(tmp_path, gcc, ctrls):
    cdir = ctrls["proper"]
    bank = export_bank(cdir)
    lib = _compile(gcc, tmp_path, c_files(bank, facts(cdir), "qf", "float"))
    c = Bound(lib, "qf", "float")
    inn = innovation_state_bytes(facts(cdir).innovation, 4)
    base = (T * 6 + (T + 1) * 6) * 4 + (2 + T + 5 + 1) * 4
    assert c.size == sizes(bank, "float", facts(cdir).innovation).state_bytes
    assert base + inn <= c.size < base + inn + 16  # padding only
    ys = np.random.default_rng(2).uniform(-1, 1, (400, 6))
    rt = RealizedController(cdir.controller.bank, 0.1)
    want = np.array([rt.step(y) for y in ys])
    got = np.array([c.step(y) for y in ys])
    dev = np.abs(got - want).max() / np.abs(want).max()
    assert 0.0 < dev <= 1e-5


def test_two_prefixes_link_into_one_program(tmp_path, gcc, ctrls):
    """The tables are file-local: two exports with two prefixes live in one binary."""
    files: dict[str, str] = {}
    for prefix, key in (("ca", "proper"), ("cb", "strict")):
        files.update(c_files(export_bank(ctrls[key]), facts(ctrls[key]), prefix, "double"))
    files["main.c"] = """#include <stdio.h>
#include "ca.h"
#include "cb.h"
int main(void) {
    ca_t a; cb_t b; double y[6] = {0.5, -0.25, 0.125, 1.0, -1.0, 0.75}, ua[3], ub[3];
    int k;
    ca_reset(&a); cb_reset(&b);
    for (k = 0; k < 5; ++k) {
        ca_step(&a, y, ua); cb_step(&b, y, ub);
        printf("%a %a %a %a %a %a\\n", ua[0], ua[1], ua[2], ub[0], ub[1], ub[2]);
    }
    return 0;
}
"""
    exe = _compile(gcc, tmp_path, files, shared=False)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split()
    got = np.array([float.fromhex(s) for s in out]).reshape(5, 6)
    y = np.array([0.5, -0.25, 0.125, 1.0, -1.0, 0.75])
    for cols, key in ((slice(0, 3), "proper"), (slice(3, 6), "strict")):
        rt = RealizedController(ctrls[key].controller.bank, 0.1)
        want = np.array([rt.step(y) for _ in range(5)])
        assert np.abs(got[:, cols] - want).max() <= 1e-12
    assert np.all(got[0, 3:] == 0.0) and np.any(got[0, :3] != 0.0)

"""Benchmark of the export (issue 12): ``python benchmarks/bench_export.py [--smoke]``.

For L1 robust controllers synthesized at T = 20 and T = 50 (the export tests' error model:
eps_e, S and eps_w their maxima, so the design premise holds on all of it; not calibrated, so
'relaxed', exported with allow_uncertified: the speed is the same code's):

1. Ticks per second of one controller step, against the budget of a 500 Hz flight-controller
   loop (2 ms per tick):
   - the exported C compiled ``-O2`` (double and float), timed in C by a small harness
     (``clock_gettime`` around a million steps, inputs varying every tick);
   - the exported C through ctypes (what ``--backend c`` pays per call from Python);
   - the exported stdlib Python module (no numpy);
   - the naive ways: qsls' numpy realization (``RealizedController.step``) and a
     straightforward pure-Python filter bank (nested loops over taps, shifting lists);
   - the cost of the onboard premise monitor (docs/monitor.md): the exported C step against
     the same source with the innovation monitor's call removed (the envelope monitor only)
     and with both removed (the step alone), timed by the same harness and counted in
     instructions by valgrind (the target: the monitors add at most 10 % to the step).
2. State and constant sizes (double and float) against a 192 KB RAM / 1 MB flash
   microcontroller; flops per tick.
3. Float vs double: largest ``|u|`` deviation over 10 000 random ticks and largest position
   deviation in closed loop with the linear plant (``qsls export --precision float``).

``--smoke`` (``smokemode.py``): T = 8 only, 2 000 C ticks, 200 Python ticks, one run each.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from smokemode import add_flag, require

from qsls.pipeline.control.artifacts import load_controller_dir, load_runtime
from qsls.pipeline.control.monitor import innovation_of
from qsls.pipeline.control.synth import SynthOptions, synth
from qsls.pipeline.core.artifacts import dump_yaml
from qsls.pipeline.errormodel.model import DisturbanceStats, ErrorModel, SlopeStats
from qsls.pipeline.export.bank import LOOP_HZ, MCU_FLASH_BYTES, MCU_RAM_BYTES, export_bank
from qsls.pipeline.export.cbuild import STRICT, CController, find_compiler
from qsls.pipeline.export.python import load_module
from qsls.pipeline.export.stage import ExportOptions, export

HARNESS = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "qsls_ctrl.h"

int main(void)
{
    static qsls_ctrl_real_t ys[1024][6];
    qsls_ctrl_t c;
    qsls_ctrl_real_t u[3];
    volatile qsls_ctrl_real_t sink = 0;
    struct timespec a, b;
    unsigned long i, n = %(N)dUL;
    unsigned int s = 12345u;
    for (i = 0; i < 1024; ++i) {
        int k;
        for (k = 0; k < 6; ++k) {
            s = s * 1103515245u + 12345u;
            ys[i][k] = (qsls_ctrl_real_t)((double)(s >> 8) / 8388608.0 - 1.0);
        }
    }
    qsls_ctrl_reset(&c);
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (i = 0; i < n; ++i) {
        qsls_ctrl_step(&c, ys[i & 1023u], u);
        sink += u[0];
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%%.3f\n", ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / (double)n);
    return sink == 12345.0;
}
"""


def controller(root: Path, T: int) -> Path:
    em = ErrorModel(
        disturbance=DisturbanceStats(max=0.01, source="inputs", n_steps=100),
        eps_e=0.05, eps_e_percentiles={"p95": 0.04}, radius=1.0,
        s_slope=SlopeStats(max=0.13, percentiles={"p50": 0.1, "p95": 0.12}),
        R0=0.05, delta=0.05, n_samples=100, n_pairs=1000,
    )  # fmt: skip
    (root / "fit").mkdir(exist_ok=True)
    (root / "fit" / "error_model.yaml").write_text(dump_yaml(em))
    opts = SynthOptions(T=T, S="max", controllers="single")
    synth(root / "fit", opts, root / f"synth{T}")
    return root / f"synth{T}" / "l1_robust"


MONITOR_CALLS = (
    "flags = qsls_ctrl_monitor_tick(c, yg, inn);",
    "flags = qsls_ctrl_monitor_tick(c, yg, 0);",
)
INNOVATION_CALL = "inn = qsls_ctrl_innovation_tick(c, yg);"


def step_alone(export_dir: Path, innovation_only: bool = False) -> Path:
    """A copy of the export whose step skips the monitor (its calls replaced by ``flags = 0``):
    the filter bank and the gate alone, for the monitor's cost; with ``innovation_only`` only
    the innovation monitor's call is removed (``inn = 0``: the envelope monitor stays), for
    the innovation monitor's own cost."""
    d = (
        export_dir.parent
        / f"{export_dir.name}-{'noinnovation' if innovation_only else 'nomonitor'}"
    )
    d.mkdir(exist_ok=True)
    (d / "qsls_ctrl.h").write_text((export_dir / "qsls_ctrl.h").read_text())
    src = (export_dir / "qsls_ctrl.c").read_text()
    if src.count(INNOVATION_CALL) == 1:
        src = src.replace(INNOVATION_CALL, "inn = 0; (void)qsls_ctrl_innovation_tick;")
    if not innovation_only:
        call = next(c for c in MONITOR_CALLS if src.count(c) == 1)
        src = src.replace(call, "flags = 0; (void)qsls_ctrl_monitor_tick;")
    (d / "qsls_ctrl.c").write_text(src)
    return d


def c_harness(cc: str, export_dir: Path, n: int, name: str = "bench") -> Path:
    (export_dir / f"{name}.c").write_text(HARNESS % {"N": n})
    exe = export_dir / name
    cmd = [cc, "-std=c99", "-O2", "-o", str(exe), str(export_dir / f"{name}.c")]
    subprocess.run([*cmd, str(export_dir / "qsls_ctrl.c"), "-lm"], check=True)
    return exe


def instructions_per_tick(cc: str, export_dir: Path, n: int = 20_000) -> float | None:
    """Instructions one step executes, counted by valgrind (deterministic, unlike the wall
    clock of a shared machine): the harness at ``n`` and ``2 n`` ticks, the difference over
    ``n``. None without valgrind."""
    import re
    import shutil

    if shutil.which("valgrind") is None:
        return None
    counts = []
    for k in (n, 2 * n):
        exe = c_harness(cc, export_dir, k, f"count{k}")
        res = subprocess.run(
            ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", str(exe)],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        counts.append(int(re.search(r"Collected : (\d+)", res.stderr).group(1)))  # type: ignore[union-attr]
    return (counts[1] - counts[0]) / n


def c_ns_per_tick(*exes: Path, repeat: int = 3) -> list[float]:
    """The best of ``repeat`` runs of each harness, the harnesses run in turn (so a busy
    moment of a shared machine hits them alike)."""
    best = [np.inf] * len(exes)
    for _ in range(repeat):
        for i, exe in enumerate(exes):
            out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
            best[i] = min(best[i], float(out))
    return best


def py_ns_per_tick(step, ys: list, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for y in ys:
            step(y)
        best = min(best, (time.perf_counter() - t0) / len(ys) * 1e9)
    return best


class NaiveBank:
    """The filter bank as one would first write it: nested loops over taps, shifted lists."""

    def __init__(self, bank) -> None:
        self.uy, self.ux = bank.uy.tolist(), bank.ux.tolist()
        self.bb, self.by, self.first, self.T = (
            bank.bb.tolist(),
            bank.by.tolist(),
            bank.uy_first,
            bank.T,
        )
        self.beta = [[0.0] * 6 for _ in range(self.T)]
        self.ys = [[0.0] * 6 for _ in range(self.T + 1)]

    def step(self, y):
        self.ys = [list(y), *self.ys[:-1]]
        u = [0.0, 0.0, 0.0]
        nb = [0.0] * 6
        for j, g in enumerate(self.uy):
            yy = self.ys[j + self.first]
            for i in range(3):
                for k in range(6):
                    u[i] += g[i][k] * yy[k]
        for j, g in enumerate(self.ux):
            for i in range(3):
                for k in range(6):
                    u[i] += g[i][k] * self.beta[j][k]
        for j, g in enumerate(self.by):
            for i in range(6):
                for k in range(6):
                    nb[i] += g[i][k] * self.ys[j][k]
        for j, g in enumerate(self.bb):
            for i in range(6):
                for k in range(6):
                    nb[i] += g[i][k] * self.beta[j][k]
        self.beta = [nb, *self.beta[:-1]]
        return u


def run(T: int, root: Path, cc: str | None, c_ticks: int, py_ticks: int, repeat: int = 9) -> dict:
    folder = controller(root, T)
    cdir = load_controller_dir(folder)
    bank = export_bank(cdir)
    out: dict = {"T": T}
    for prec in ("double", "float"):
        d = root / f"c{T}{prec}"
        res = export(folder, ExportOptions(target="c", precision=prec, allow_uncertified=True), d)
        out[prec] = res.results
        if cc:
            variants = d, step_alone(d, innovation_only=True), step_alone(d)
            exes = [c_harness(cc, v, c_ticks) for v in variants]
            ns = c_ns_per_tick(*exes, repeat=repeat)
            out[prec]["c_ns"], out[prec]["c_ns_no_innovation"], out[prec]["c_ns_no_monitor"] = ns
            n = min(20_000, c_ticks)
            out[prec]["c_instr"] = instructions_per_tick(cc, d, n)
            out[prec]["c_instr_no_innovation"] = instructions_per_tick(cc, variants[1], n)
            out[prec]["c_instr_no_monitor"] = instructions_per_tick(cc, variants[2], n)
            out[prec]["innovation_windows"] = list(innovation_of(cdir).windows)
        verify = res.results["verify"]
        require(
            verify["max_abs_diff"] <= 1e-9 * max(1.0, verify["max_abs_u"]),
            f"T = {T}, {prec}: the exported C step equals the realization",
        )
    ys = np.random.default_rng(0).uniform(-1, 1, (py_ticks, 6))
    ylists = ys.tolist()
    py = root / f"py{T}"
    export(folder, ExportOptions(target="python", verify_ticks=0, allow_uncertified=True), py)
    mod = load_module((py / "qsls_ctrl.py").read_text())
    py_repeat = min(3, repeat)
    out["stdlib_ns"] = py_ns_per_tick(mod.Controller().step, ylists, py_repeat)
    out["numpy_ns"] = py_ns_per_tick(load_runtime(folder).step, list(ys), py_repeat)
    out["naive_ns"] = py_ns_per_tick(NaiveBank(bank).step, ylists[: max(200, py_ticks // 10)], 1)
    if cc:
        lib = root / f"c{T}double" / "lib.so"
        cmd = [cc, *STRICT, "-O2", "-fPIC", "-shared", "-o", str(lib)]
        subprocess.run([*cmd, str(root / f"c{T}double" / "qsls_ctrl.c"), "-lm"], check=True)
        out["ctypes_ns"] = py_ns_per_tick(CController(lib, dt=0.1).step, list(ys), py_repeat)
    return out


def table(results: list[dict], repeat: int = 9) -> None:
    budget_ns = 1e9 / LOOP_HZ
    print(
        f"\nController step, ticks/s and share of a {LOOP_HZ:.0f} Hz loop ({budget_ns / 1e6:g} ms)"
    )
    hdr = f"{'implementation':34s}" + "".join(
        f"{'T=' + str(r['T']) + ' ticks/s':>16s}{'% budget':>10s}" for r in results
    )
    print(hdr)
    print("-" * len(hdr))
    rows = [
        ("C -O2, double (exported)", lambda r: r["double"].get("c_ns")),
        ("C -O2, float (exported)", lambda r: r["float"].get("c_ns")),
        ("C through ctypes (--backend c)", lambda r: r.get("ctypes_ns")),
        ("stdlib Python module (exported)", lambda r: r["stdlib_ns"]),
        ("naive: numpy realization", lambda r: r["numpy_ns"]),
        ("naive: pure-Python nested loops", lambda r: r["naive_ns"]),
    ]
    for name, get in rows:
        cells = ""
        for r in results:
            ns = get(r)
            cells += (
                f"{'n/a':>16s}{'':>10s}"
                if ns is None
                else f"{1e9 / ns:16,.0f}{100 * ns / budget_ns:9.3f}%"
            )
        print(f"{name:34s}{cells}")
    print(
        f"\nMemory against a {MCU_RAM_BYTES // 1024} KB RAM / {MCU_FLASH_BYTES // 1024} KB flash MCU"
    )
    print(
        f"{'T':>4s} {'precision':>9s} {'state B':>9s} {'% RAM':>7s} {'const B':>9s} {'% flash':>8s} {'flops/tick':>11s}"
    )
    for r in results:
        for prec in ("double", "float"):
            s = r[prec]
            print(
                f"{r['T']:4d} {prec:>9s} {s['state_bytes']:9d} {100 * s['state_bytes'] / MCU_RAM_BYTES:6.2f}% "
                f"{s['const_bytes']:9d} {100 * s['const_bytes'] / MCU_FLASH_BYTES:7.2f}% {s['flops_per_tick']:11d}"
            )
    print("\nThe premise monitor's cost per tick (exported C -O2, docs/monitor.md): instructions")
    print("counted by valgrind (deterministic), the step with both monitors, without the")
    print("innovation monitor, without any; the monitors' share of the step alone; wall clock,")
    print(f"best of {repeat} runs taken in turn")
    print(
        f"{'T':>4s} {'precision':>9s} {'step instr':>11s} {'no innov.':>10s} {'alone':>8s} "
        f"{'innov. +%':>9s} {'all +%':>7s} {'step ns':>8s} {'no inn ns':>9s} {'alone ns':>9s}"
    )
    for r in results:
        for prec in ("double", "float"):
            s = r[prec]
            if s.get("c_ns") is None:
                continue
            ins, noi, alone = (
                s.get(k) for k in ("c_instr", "c_instr_no_innovation", "c_instr_no_monitor")
            )
            cnt = (
                f"{ins:11.0f} {noi:10.0f} {alone:8.0f} {100 * (ins - noi) / alone:8.1f}% "
                f"{100 * (ins - alone) / alone:6.1f}%"
                if ins is not None and noi is not None and alone is not None
                else f"{'n/a (no valgrind)':>49s}"
            )
            print(
                f"{r['T']:4d} {prec:>9s} {cnt} {s['c_ns']:8.1f} {s['c_ns_no_innovation']:9.1f} "
                f"{s['c_ns_no_monitor']:9.1f}"
            )
        print(f"     windows {r['double'].get('innovation_windows')}")
    print("\nFloat vs double (qsls export --precision float)")
    print(
        f"{'T':>4s} {'max|du| random':>15s} {'max|u|':>8s} {'max|dx| closed loop (m)':>24s} {'double vs realization':>22s}"
    )
    for r in results:
        f = r["float"].get("float_vs_double", {})
        if "max_abs_du_random" not in f:
            print(f"{r['T']:4d} {'n/a (no C compiler)':>15s}")
            continue
        print(
            f"{r['T']:4d} {f['max_abs_du_random']:15.3g} {r['double']['verify']['max_abs_u']:8.3g} "
            f"{f['max_abs_dx_closed_loop']:24.3g} {r['double']['verify']['max_abs_diff']:22.3g}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--T", type=int, nargs="+", default=[20, 50])
    ap.add_argument("--c-ticks", type=int, default=1_000_000)
    ap.add_argument("--py-ticks", type=int, default=20_000)
    ap.add_argument("--json", type=Path, help="also write the numbers as JSON")
    add_flag(ap)
    args = ap.parse_args()
    repeat = 9
    if args.smoke:
        args.T, args.c_ticks, args.py_ticks, repeat = [8], 2_000, 200, 1
    cc = find_compiler()
    with tempfile.TemporaryDirectory(prefix="qsls-bench-export-") as tmp:
        results = [run(T, Path(tmp), cc, args.c_ticks, args.py_ticks, repeat) for T in args.T]
    table(results, repeat)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))


if __name__ == "__main__":
    main()

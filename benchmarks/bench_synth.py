"""Benchmark of the synthesis stage (issue 5): ``python benchmarks/bench_synth.py``.

1. T = 50 L1 robust output-feedback synthesis (c_QR, robustness constraint), three ways:
   - eliminated (issue 27, :mod:`qsls.pipeline.control.sls`): the free taps of Phi_xx as the
     only variable, the other responses affine maps of them, shared epigraphs, the axes'
     block pattern, cvxpy Parameters (DPP);
   - vectorized (the formulation before issue 27, tests/sls_reference.py): one variable per
     response (taps side by side), every achievability equation a constraint, Parameters;
   - naive: one variable per tap and per response, constraints and norms written tap by
     tap in Python loops, numbers as constants (Dean et al.'s and SLSpy's style);
   each measured on the first solve (expression tree + compile + solve) and the two
   Parameter ones on a re-solve with new values (what a sweep does): build and solve wall
   times, Clarabel's own time and iterations, and the CPU seconds of build + solve (this
   process; the machine is shared, so CPU time is the load-independent figure).
2. A 48-point sweep on 2 processes against the same points one after another.
2b. The quickstart's own honest setting (configs/quickstart.yaml's ``problem:`` and
   ``synth:`` sections: the attitude plant, W_e, beta, m outliers per window through ``G_m``'s
   ``sum_largest``, the velocity gate) at T = 50 (issue 37), on one thread: the formulation
   before issue 37 (every axis its own responses), the mirrored one of its first round (the x
   and y axes, a signed permutation of each other, solved once), both at ``sls.TIGHT``, and
   what ``sls.solve`` runs since its second round (mirrored, the light cost rows left out and
   checked, ``sls.FAST`` first), in the same run; objective, the largest tap difference and
   the certificate's guarantee numbers and realization error of each.
3. The premise's share of training pairs above S (:mod:`qsls.pipeline.premise.record`):
   the cell grid against the chunked all-pairs count, same answer required.
Targets: build + solve <= 0.15 s on one core at T = 50 (issue 27; issue 37 in the honest
setting); sweep >= 1.8x faster.

``--smoke`` (``smokemode.py``): T = 20 (the honest setting at T = 38: infeasible below 38 since
the quickstart's Delta covers its reference family),
one repeat, a 4-point sweep, 400 premise samples.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from smokemode import add_flag, requested, require

from qsls.pipeline.control import sls
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.premise.numbers import PremiseNumbers

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.sls_reference

SETTING = {"eps_w": 0.01, "eps_e": 0.05, "S": 0.2, "radius": 1.0, "delta": 0.05}
Q = np.diag([10.0, 10, 10, 1, 1, 1])
R = np.diag([1.0, 1, 0.1])


def naive_problem(model, T: int, S: float, eps_e: float, radius: float, eps_w: float, delta: float):
    """The same problem, tap by tap (no Parameters)."""
    import cvxpy as cp

    a, b, c, h = model.A, model.B, model.C, model.H
    nx, nu, ny = model.nx, model.nu, model.ny
    xx = [cp.Variable((nx, nx)) for _ in range(T + 1)]
    ux = [cp.Variable((nu, nx)) for _ in range(T + 1)]
    xy = [cp.Variable((nx, ny)) for _ in range(T + 1)]
    uy = [cp.Variable((nu, ny)) for _ in range(T + 1)]
    cons = [xx[0] == 0, ux[0] == 0, xy[0] == 0, xx[1] == np.eye(nx)]
    cons += [xy[1] == b @ uy[0], ux[1] == uy[0] @ c]
    for k in range(1, T):
        cons += [
            xx[k + 1] == a @ xx[k] + b @ ux[k],
            xx[k + 1] == xx[k] @ a + xy[k] @ c,
            xy[k + 1] == a @ xy[k] + b @ uy[k],
            ux[k + 1] == ux[k] @ a + uy[k] @ c,
        ]
    cons += [
        a @ xx[T] + b @ ux[T] == 0,
        a @ xy[T] + b @ uy[T] == 0,
        xx[T] @ a + xy[T] @ c == 0,
        ux[T] @ a + uy[T] @ c == 0,
    ]
    qh, rh = np.sqrt(Q), np.sqrt(R)

    def l1(blocks):  # largest absolute row sum over the taps side by side
        rows = []
        for i in range(blocks[0].shape[0]):
            rows.append(sum(cp.sum(cp.abs(blk[i, :])) for blk in blocks))
        return cp.max(cp.hstack(rows))

    n_xy = l1(xy[1:])
    n_xx = l1([p @ h for p in xx[1:]])
    cons.append(
        (S + eps_e / radius) * n_xy + (eps_w * n_xx + delta) / radius <= 1 - sls.ROBUST_BACKOFF
    )
    rows = []
    for i in range(nx):
        rows.append(
            sum(cp.sum(cp.abs((qh @ p @ h)[i, :])) * eps_w for p in xx)
            + sum(cp.sum(cp.abs((qh @ p)[i, :])) * eps_e for p in xy)
        )
    for i in range(nu):
        rows.append(
            sum(cp.sum(cp.abs((rh @ p @ h)[i, :])) * eps_w for p in ux)
            + sum(cp.sum(cp.abs((rh @ p)[i, :])) * eps_e for p in uy)
        )
    return cp.Problem(cp.Minimize(cp.max(cp.hstack(rows))), cons)


def timed_solve(problem):
    t0 = time.perf_counter()
    problem.solve(solver="CLARABEL", warm_start=False)
    wall = time.perf_counter() - t0
    comp = problem.compilation_time or 0.0
    st = problem.solver_stats
    return comp, wall - comp, float(st.solve_time), int(st.num_iters), float(problem.value)


def bench_build(T: int, repeats: int) -> list[tuple]:
    """Rows ``(formulation, rep, tree, compile, solve, clarabel, iterations, cpu, objective)``."""
    import cvxpy  # noqa: F401  (import time is not part of any measurement)

    from tests.sls_reference import VectorizedProblem

    model = quadrotor_model()
    rows = []
    s = SETTING
    numbers = PremiseNumbers(s["eps_e"], s["S"], s["radius"], s["eps_w"], s["delta"])
    values = sls.Values(Q=Q, R=R, numbers=numbers)
    other = sls.Values(Q=Q, R=R, numbers=replace(numbers, S=0.19))
    for rep in range(repeats):
        for name, cls in (("eliminated", sls.SLSProblem), ("vectorized", VectorizedProblem)):
            sls._CACHE.clear()
            c0, t0 = time.process_time(), time.perf_counter()
            prob = cls(model, sls.Structure(T, "l1", "qr", True))
            tree = time.perf_counter() - t0
            prob.set_values(values)
            comp, solve, own, its, obj = timed_solve(prob.problem)
            cpu = time.process_time() - c0
            rows.append((f"{name}, first solve", rep, tree, comp, solve, own, its, cpu, obj))
            prob.set_values(other)
            prob.set_values(values)
            c0 = time.process_time()
            comp, solve, own, its, obj = timed_solve(prob.problem)
            cpu = time.process_time() - c0
            rows.append((f"{name}, re-solve", rep, 0.0, comp, solve, own, its, cpu, obj))
        c0, t0 = time.process_time(), time.perf_counter()
        naive = naive_problem(model, T, **SETTING)
        tree = time.perf_counter() - t0
        comp, solve, own, its, obj = timed_solve(naive)
        cpu = time.process_time() - c0
        rows.append(("naive tap-by-tap loops", rep, tree, comp, solve, own, its, cpu, obj))
    return rows


def honest_setting(T: int):
    """The quickstart's synthesis problem (``problem:`` under ``synth:``), resolved without an
    error model (its numbers are all given; the fit's state weights are 1), at horizon ``T``."""
    import yaml

    from qsls.pipeline.control.options import ProblemOptions
    from qsls.pipeline.control.problem import resolve

    config = Path(__file__).resolve().parents[1] / "configs/quickstart.yaml"
    cfg = yaml.safe_load(config.read_text())
    keys = set(ProblemOptions.model_fields)
    opts = {k: v for k, v in {**cfg["problem"], **cfg["synth"]}.items() if k in keys}
    r = resolve(ProblemOptions(**{**opts, "T": T}))
    return r, r.structure(T, "l1", "qr", True, False)


HONEST = (
    ("per axis (before)", False),
    ("x, y mirrored (round 1)", True),
    ("qsls (sls.solve)", None),
)
"""The honest setting's formulations: every axis its own responses and every cost row, at
:data:`sls.TIGHT`; x and y mirrored, the same; what :func:`sls.solve` runs (mirrored, the
light cost rows left out and checked, :data:`sls.FAST` first)."""


def bench_honest(T: int, repeats: int) -> tuple[list[tuple], dict]:
    """Rows ``(formulation, rep, tree, compile, solve, clarabel, iterations, cpu, objective)``
    of the honest setting, first solves on one thread; and each formulation's taps and
    certificate numbers."""
    from dataclasses import replace

    from threadpoolctl import threadpool_limits

    from qsls.pipeline.control.certify import certify

    r, structure = honest_setting(T)
    rows, last = [], {}
    values = r.values()
    with threadpool_limits(limits=1):
        for rep in range(repeats):
            for name, mirrored in HONEST:
                c0 = time.process_time()
                if mirrored is None:  # what a synthesis runs: sls.solve picks the structure
                    sls._CACHE.clear()
                    sol = sls.solve(r.model, structure, values)
                    prob = list(sls._CACHE.values())[-1]
                else:
                    prob = sls.SLSProblem(r.model, replace(structure, mirrored=mirrored))
                    sol = prob.solve(values, solver_options=sls.TIGHT)
                cpu = time.process_time() - c0
                st = prob.problem.solver_stats
                comp = prob.problem.compilation_time or 0.0
                rows.append(
                    (name, rep, prob.construct_time_s, comp, sol.solve_time_s, float(st.solve_time),
                     int(st.num_iters), cpu, sol.objective)
                )  # fmt: skip
                last[name] = sol
    out = {}
    for name, sol in last.items():
        require(sol.taps is not None, f"{name}: the honest setting at T = {T} is feasible")
        assert sol.taps is not None
        body = certify(sol.taps, r.model, r.numbers, r.shape, solver_status=sol.status)
        out[name] = (sol.taps, body)
    return rows, out


def same_optimum(objectives: list[float], rel: float = 1e-5) -> bool:
    """All finite and within ``rel`` of each other (the solvers' tolerances are 1e-8 to 1e-10;
    the formulations' paths differ)."""
    o = np.asarray(objectives, dtype=float)
    return bool(np.isfinite(o).all() and np.abs(o / o[0] - 1).max() <= rel)


def print_rows(rows: list[tuple]) -> None:
    hdr = (
        f"{'formulation':28s} {'rep':>3s} {'tree':>6s} {'compile':>7s} {'solve':>6s} "
        f"{'clarabel':>8s} {'iters':>5s} {'build+solve':>11s} {'cpu':>6s} {'objective':>11s}"
    )
    print(hdr, "-" * len(hdr), sep="\n")
    for name, rep, tree, comp, solve, own, its, cpu, obj in rows:
        print(
            f"{name:28s} {rep:3d} {tree:6.3f} {comp:7.3f} {solve:6.3f} {own:8.3f} {its:5d} "
            f"{tree + comp + solve:11.3f} {cpu:6.3f} {obj:11.8f}"
        )


def report_honest(T: int, repeats: int) -> None:
    rows, out = bench_honest(T, repeats)
    print(f"\nT = {T} quickstart honest setting (attitude plant, W_e, G_m, gate), one thread, s")
    print_rows(rows)
    names = [name for name, _ in HONEST]
    best = [min(r[7] for r in rows if r[0] == n) for n in names]
    print(
        "best CPU: "
        + ", ".join(f"{n} {b:.3f} s" for n, b in zip(names, best, strict=True))
        + " (target <= 0.15 s)"
    )
    ta, _ = out[names[0]]
    for name in names[1:]:
        tb, _ = out[name]
        diff = max(float(np.abs(getattr(ta, n) - getattr(tb, n)).max()) for n in sls.RESPONSES)
        objs = [r[8] for r in rows[-len(names) :]]
        rel = abs(objs[names.index(name)] / objs[0] - 1)
        print(f"{name}: objective relative difference {rel:.1e}; largest tap difference {diff:.3g}")
    require(
        same_optimum([r[8] for r in rows]),
        "the honest setting's formulations reach the same optimum",
    )
    fields = ("status", "robustness_lhs", "norm_N", "norm_N_w", "G_m", "a", "gamma", "rho_star")
    for field in (*fields, "rho_v", "realization_error"):
        print(f"  {field:17s}" + "".join(f" {getattr(out[n][1], field)!s:>22s}" for n in names))


def sweep_options():
    from qsls.pipeline.control.sweep import SweepOptions

    if requested():
        return SweepOptions(
            eps_e=0.05, radius=1.0, delta=0.05, eps_w=0.01, s_max_curve=False,
            grid={"S": [0.02, 0.2], "T": [10], "cost": ["qr", "imitation"]},
        )  # fmt: skip
    return SweepOptions(
        eps_e=0.05, radius=1.0, delta=0.05, eps_w=0.01, s_max_curve=False,
        grid={"S": [0.02, 0.05, 0.08, 0.11, 0.14, 0.17, 0.2, 0.25], "T": [10, 20, 30], "cost": ["qr", "imitation"]},
    )  # fmt: skip


def _cpu() -> float:
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def bench_sweep(jobs: int) -> tuple[float, float, int, int]:
    """Wall and CPU seconds (this process and its finished children) of the sweep."""
    from qsls.pipeline.control.sweep import compute

    sls._CACHE.clear()
    c0, t0 = _cpu(), time.perf_counter()
    table, _, _ = compute(sweep_options(), jobs=jobs)
    return time.perf_counter() - t0, _cpu() - c0, len(table), int(table["feasible"].sum())


def _timed_chunk(chunk):
    import resource

    from qsls.pipeline.control.sweep import run_chunk

    c0 = resource.getrusage(resource.RUSAGE_SELF)
    run_chunk(chunk)
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    return os.getpid(), (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)


def cpu_balance(jobs: int = 2) -> tuple[float, float]:
    """The sweep's chunks on ``jobs`` processes, timed by CPU seconds per worker: the
    speed-up the chunking allows on idle cores is total CPU / the busiest worker's CPU
    (a figure the shared machine's load does not distort)."""
    import multiprocessing as mp
    from collections import defaultdict
    from concurrent.futures import ProcessPoolExecutor

    from qsls.pipeline.control.sweep import grid_points, make_chunks

    opts = sweep_options()
    chunks = make_chunks(grid_points(opts, None), jobs * opts.chunks_per_job)
    sls._CACHE.clear()
    per_worker: dict[int, float] = defaultdict(float)
    with ProcessPoolExecutor(jobs, mp_context=mp.get_context("fork")) as pool:
        for pid, cpu in pool.map(_timed_chunk, chunks):
            per_worker[pid] += cpu
    total = sum(per_worker.values())
    return total, total / max(per_worker.values())


def bench_premise(n: int = 8000, flights: int = 4) -> list[tuple[str, float, float]]:
    """``(way, seconds, tested range)``: the leave-one-flight-out premise's distances to other
    flights (docs/guarantee.md) by KD-tree against all cross-flight pairs."""
    from qsls.pipeline.premise.honest import other_flight_distances

    rng = np.random.default_rng(0)
    x = rng.uniform(-3.0, 3.0, (n, 6))
    flight = np.repeat(np.arange(flights), n // flights)
    scale = (1.0, 1.0, 1.0, 0.5, 0.5, 0.5)
    t0 = time.perf_counter()
    tree = other_flight_distances(x, flight, scale)
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    xs = x * np.asarray(scale)
    naive = np.empty(n)
    for k in range(n):
        other = flight != flight[k]
        naive[k] = np.abs(xs[other] - xs[k]).max(axis=1).min()
    slow = time.perf_counter() - t0
    require(np.array_equal(tree, naive), "the KD-tree's distances equal all pairs'")
    return [
        ("KD-tree (qsls)", fast, float(tree.max())),
        ("all pairs (naive)", slow, float(naive.max())),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--T", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--skip-build", action="store_true", help="only the sweep part")
    ap.add_argument("--skip-sweep", action="store_true", help="only the synthesis part")
    add_flag(ap)
    args = ap.parse_args()
    n_premise, honest_T = 8000, args.T
    if args.smoke:
        args.T, args.repeats, n_premise, honest_T = 20, 1, 400, 38
    rows = [] if args.skip_build else bench_build(args.T, args.repeats)
    print(f"\nT = {args.T} L1 robust output-feedback synthesis (c_QR + robustness), times in s")
    print_rows(rows)
    if rows:
        best = {n: min(r[7] for r in rows if r[0] == n) for n in dict.fromkeys(r[0] for r in rows)}
        first = best["eliminated, first solve"]
        print(
            f"eliminated first solve, CPU: {first:.3f} s (target <= 0.15 s); vectorized "
            f"{best['vectorized, first solve'] / first:.1f}x, naive loops "
            f"{best['naive tap-by-tap loops'] / first:.1f}x that"
        )
        require(same_optimum([r[8] for r in rows]), "the three formulations reach the same optimum")
    if not args.skip_build:
        report_honest(honest_T, args.repeats)
    if args.skip_sweep:
        return
    seq = bench_sweep(1)
    par = bench_sweep(2)
    grid = " x ".join(f"{k} {'/'.join(map(str, v))}" for k, v in sweep_options().grid.items())
    print(f"\n{seq[2]}-point sweep ({grid}), {seq[3]} feasible")
    require(seq[2:] == par[2:], "one process and two find the same points feasible")
    print(f"{'executor':16s} {'wall s':>8s} {'cpu s':>8s}")
    print(f"{'sequential':16s} {seq[0]:8.2f} {seq[1]:8.2f}")
    print(f"{'2 processes':16s} {par[0]:8.2f} {par[1]:8.2f}")
    print(f"speed-up: {seq[0] / par[0]:.2f}x wall (target >= 1.8x)")
    total, bound = cpu_balance(2)
    print(f"CPU-balance: {total:.2f} CPU s over 2 workers -> {bound:.2f}x on 2 idle cores")
    prem = bench_premise(n_premise)
    print(f"\npremise: distance of each of {n_premise} samples to the other 3 flights (lofo S)")
    print(f"{'way':20s} {'s':>7s} {'largest':>8s}")
    for way, sec, largest in prem:
        print(f"{way:20s} {sec:7.3f} {largest:8.4f}")
    print(f"speed-up: {prem[1][1] / prem[0][1]:.1f}x")
    print(f"load average after the run: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()

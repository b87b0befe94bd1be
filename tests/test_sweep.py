"""`qsls sweep`: grid, local pool, a real Dask cluster on loopback, the CI expectation."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.control import largest_s, sls
from qsls.pipeline.control.sweep import (
    ABOVE_S_MAX,
    NECESSARY,
    mark_above_s_max,
    setting_key,
    skip_reason,
)
from qsls.pipeline.core.artifacts import dump_yaml
from qsls.pipeline.core.plant import quadrotor_model
from qsls.pipeline.errormodel.model import DisturbanceStats, ErrorModel, SlopeStats
from qsls.pipeline.premise.choose import ModelInput
from qsls.pipeline.premise.numbers import PremiseNumbers

RUN = CliRunner()
REPO = Path(__file__).resolve().parents[1]
TIMING = ["build_time_s", "solve_time_s"]

SMALL = """
eps_e: 0.05
radius: 1.0
delta: 0.05
eps_w: 0.01
grid:
  S: [0.05, 0.14, 0.24, 1.5]
  T: [6, 10]
  norm: [l1, h2]
"""


def _sweep(*args):
    return RUN.invoke(app, ["sweep", *map(str, args)])


def _table(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "sweep.parquet")


def test_local_sweep_table_and_feasibility(tmp_path):
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL)
    out = tmp_path / "sw"
    res = _sweep("-c", cfg, "-o", out, "--jobs", "2")
    assert res.exit_code == 0, res.output
    t = _table(out)
    assert len(t) == 16 and list(t["index"]) == list(range(16))
    for col in (
        "S",
        "T",
        "norm",
        "status",
        "feasible",
        "cost_value",
        "norm_phi_xy",
        "gamma",
        "margin",
    ):
        assert col in t.columns
    assert not set(TIMING) & set(t.columns)  # timings: the manifest only (byte-identical data)
    pd.testing.assert_frame_equal(
        pd.read_csv(out / "sweep.csv"), t, check_dtype=False, atol=0, rtol=1e-15
    )
    for name in ("feasibility.png", "s_max_vs_T.png", "s_max.csv", "manifest.json"):
        assert (out / name).is_file()
    # feasibility against the largest feasible S computed separately for each T (the
    # robustness constraint does not involve the cost, so both norms agree)
    model = quadrotor_model()
    s_max = {T: largest_s.max_feasible_s(model, T, _premise(0.05, 1.0)).s_max for T in (6, 10)}
    for _, row in t.iterrows():
        assert row["feasible"] == (row["S"] <= s_max[row["T"]]), row.to_dict()
        if row["feasible"]:
            assert row["status"] == "relaxed" and row["margin"] > 0
            assert row["norm_phi_xy"] >= 1 and row["gamma"] > 0
    assert set(t.loc[t["S"] == 1.5, "status"]) == {"infeasible"}  # S + eps_e/r >= 1, not solved
    necessary = t["solver_status"] == NECESSARY
    assert list(necessary) == list(t["S"] == 1.5)  # and marked so
    # every other infeasible point lies above its T's largest feasible S: answered by the
    # Dinkelbach run, not by a solve, and marked so; the solver ran on feasible points only
    above = t["solver_status"] == ABOVE_S_MAX
    assert list(above) == [r.S != 1.5 and s_max[r.T] < r.S for r in t.itertuples()]
    assert above.sum() == 6 and list(t["skipped"]) == list(necessary | above)
    assert set(t.loc[t["skipped"], "status"]) == {"infeasible"}
    assert t.loc[~t["skipped"], "feasible"].all()
    timings = json.loads((out / "manifest.json").read_text())["results"]["timings"]
    assert len(timings["points"]) == 16
    assert all(timings["points"][str(i)] == [0.0, 0.0] for i in t.loc[t["skipped"], "index"])
    assert timings["solve_time_s"] > 0
    smax = pd.read_csv(out / "s_max.csv")
    assert dict(zip(smax["T"], smax["s_max"], strict=True)) == pytest.approx(s_max, rel=1e-6)


GRID = """
delta: 0.05
eps_w: 0.01
grid:
  S: [0.05, 0.3, 0.99]
  T: [6, 10]
  eps_e: [0.02, 0.05]
  radius: [0.5, 1.0]
"""


def test_one_and_two_processes_write_identical_tables(tmp_path):
    """The sweep and largest-S tables are byte-identical on 1 and 2 processes, and one
    Dinkelbach run per T and radius gives every eps_e the S_max of its own run."""
    cfg = tmp_path / "grid.yaml"
    cfg.write_text(GRID)
    for jobs in (1, 2):
        res = _sweep("-c", cfg, "-o", tmp_path / f"j{jobs}", "--jobs", jobs)
        assert res.exit_code == 0, res.output
    for name in ("sweep.parquet", "sweep.csv", "s_max.parquet", "s_max.csv"):
        assert (tmp_path / "j1" / name).read_bytes() == (tmp_path / "j2" / name).read_bytes()
    t = _table(tmp_path / "j1")
    assert len(t) == 24
    necessary = t["solver_status"] == NECESSARY
    assert list(necessary) == list(t["S"] + t["eps_e"] / t["radius"] >= 1)
    assert necessary.sum() == 8 and not t.loc[t["skipped"], "feasible"].any()
    assert list(t["skipped"]) == list(necessary | (t["solver_status"] == ABOVE_S_MAX))
    smax = pd.read_parquet(tmp_path / "j1" / "s_max.parquet")
    assert len(smax) == 8
    model = quadrotor_model()
    for _, row in smax.iterrows():
        own = largest_s.max_feasible_s(model, int(row["T"]), _premise(row["eps_e"], row["radius"]))
        assert row["s_max"] == own.s_max  # the same solves: exactly the same number
    s_of = {(r.T, r.eps_e, r.radius): r.s_max for r in smax.itertuples()}
    for r in t[~necessary].itertuples():
        assert r.feasible == (s_of[(r.T, r.eps_e, r.radius)] >= r.S)
        assert r.skipped == (not r.feasible)  # every infeasible point answered without a solve


def test_points_above_the_largest_feasible_s_are_exactly_the_infeasible_ones():
    """The Dinkelbach bound answers a point without the solver only where the solver would
    say infeasible: just above the bound (by 1e-5) is marked and solves infeasible, the
    largest feasible S itself is not marked and solves feasible, for two horizons."""
    model = quadrotor_model()
    setting = {"radius": 1.0, "eps_w": 0.01, "delta": 0.05}
    for T in (6, 10):
        ratio = largest_s.max_ratio(model, T, _premise(0.0, 1.0))
        upper = ratio.upper(largest_s.min_phi_xy(model, T))
        assert ratio.ratio <= upper <= ratio.ratio * (1 + 1e-8)  # Dinkelbach's gap closed
        s_max = largest_s.max_feasible_s(model, T, _premise(0.05, 1.0), ratio=ratio).s_max
        point = {"robust": True, "T": T, "eps_e": 0.05, **setting, "strictly_proper": False,
                 "dt": 0.1, "mass": 1.0, "eps_o_value": 0.0, "m_value": 0, "measure": "full",
                 "gate_value": None, "H": None, "state_scale": [1.0] * 6,
                 "error_scale": [1.0] * 6}  # fmt: skip
        above = {**point, "S": upper - 0.05 + 1e-5, "necessary": 0.5}
        at = {**point, "S": s_max, "necessary": 0.5}
        assert mark_above_s_max([above, at], {setting_key(point): upper}) == 1
        assert skip_reason(above) == ABOVE_S_MAX and skip_reason(at) == ""
        for p, want in ((above, "infeasible"), (at, "optimal")):
            v = sls.Values(numbers=PremiseNumbers(eps=0.05, S=p["S"], **setting))
            assert sls.solve(model, sls.Structure(T, "l1", "qr", True), v).status == want


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port}")


def _wait_for_workers(address: str, n: int, timeout: float = 60.0) -> None:
    from distributed import Client

    with Client(address, timeout="20s", set_as_default=False) as client:
        client.wait_for_workers(n, timeout=timeout)


@pytest.mark.slow
def test_dask_cluster_gives_the_local_table(tmp_path):
    """A real `dask scheduler` and two `dask worker` processes on loopback."""
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL)
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask", "scheduler"]  # `dask scheduler` of this Python
    worker = [sys.executable, "-m", "dask", "worker"]
    procs: list[subprocess.Popen] = []
    log = open(tmp_path / "dask.log", "w")  # noqa: SIM115 - closed in the finally below
    try:
        sched = [*dask, "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]
        procs.append(subprocess.Popen(sched, stdout=log, stderr=log, cwd=tmp_path))
        _wait_for_port(port)
        for _ in range(2):
            ports = ["--worker-port", str(_free_port()), "--nanny-port", str(_free_port())]
            cmd = [
                *worker,
                address,
                "--nthreads",
                "1",
                "--no-dashboard",
                "--host",
                "127.0.0.1",
                *ports,
            ]
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=log, cwd=tmp_path))
        _wait_for_workers(address, 2)
        res = _sweep("-c", cfg, "-o", tmp_path / "dask", "--scheduler", address)
        assert res.exit_code == 0, res.output
        assert "dask" in res.output
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        log.close()
    for jobs in (1, 2):
        res = _sweep("-c", cfg, "-o", tmp_path / f"local{jobs}", "--jobs", jobs)
        assert res.exit_code == 0, res.output
        for name in ("sweep.parquet", "sweep.csv", "s_max.parquet"):
            got = (tmp_path / "dask" / name).read_bytes()
            assert got == (tmp_path / f"local{jobs}" / name).read_bytes()
    sa = pd.read_parquet(tmp_path / "dask" / "s_max.parquet")
    sb = pd.read_parquet(tmp_path / "local1" / "s_max.parquet")
    pd.testing.assert_frame_equal(sa, sb, check_exact=True)


def test_ci_sweep_matches_committed_expectation(tmp_path):
    out = tmp_path / "ci"
    res = _sweep("-c", REPO / "configs" / "ci_sweep.yaml", "-o", out, "--jobs", "2")
    assert res.exit_code == 0, res.output
    got = pd.read_csv(out / "sweep.csv")
    want = pd.read_csv(REPO / "configs" / "ci_sweep_expected.csv")
    assert 24 <= len(want) <= 48
    keys = [c for c in want.columns if c != "feasible"]
    merged = want.merge(
        got[[*keys, "feasible"]], on=keys, suffixes=("_want", "_got"), validate="1:1"
    )
    assert len(merged) == len(want)
    assert (merged["feasible_want"] == merged["feasible_got"]).all(), merged


def test_error_model_names_resolve(tmp_path):
    em = ErrorModel(
        disturbance=DisturbanceStats(max=0.01, source="inputs", n_steps=100),
        eps_e=0.05, radius=1.0, s_slope=SlopeStats(max=11.7, percentiles={"p50": 0.1}), R0=0.05,
        delta=0.05, n_samples=10, n_pairs=10,
    )  # fmt: skip
    f = tmp_path / "error_model.yaml"
    f.write_text(dump_yaml(em))
    cfg = tmp_path / "s.yaml"
    cfg.write_text("eps_e: max\neps_w: 0.01\ngrid:\n  S: [p50, max]\n  T: [6]\n")
    out = tmp_path / "o"
    res = _sweep("-c", cfg, "-m", f, "-o", out, "--jobs", "1")
    assert res.exit_code == 0, res.output
    t = _table(out)
    assert list(t["S"]) == ["p50", "max"] and list(t["S_value"]) == [0.1, 11.7]
    # T = 6, the model's eps_e, r and Delta: the largest feasible S is 0.103
    assert list(t["feasible"]) == [True, False]
    assert t["radius_value"].tolist() == [1.0, 1.0] and t["delta_value"].tolist() == [0.05, 0.05]
    # numbers and names on one axis: the column holds text
    cfg.write_text("eps_e: max\neps_w: 0.01\ngrid:\n  S: [0.02, p50]\n  T: [6]\n")
    res = _sweep("-c", cfg, "-m", f, "-o", tmp_path / "o2", "--jobs", "1")
    assert res.exit_code == 0, res.output
    assert list(_table(tmp_path / "o2")["S"]) == ["0.02", "p50"]


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("grid:\n  SS: [0.1]\n", r"unknown grid axis 'SS'; did you mean 'S'"),
        ("grid:\n  T: [1]\n", r"'T'.*greater than or equal to 2"),
        ("radius: 1\neps_e: 0.05\ngrid:\n  S: [p95]\n", r"none was given"),
        ("grid:\n  S: []\n", r"non-empty list"),
    ],
)
def test_bad_sweep_config_is_one_clear_error(tmp_path, text, pattern):
    import re

    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    out = tmp_path / "o"
    res = _sweep("-c", cfg, "-o", out, "--jobs", "1")
    assert res.exit_code == 2, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and re.search(pattern, lines[0]), (
        res.output
    )
    assert not out.exists()


def test_grid_and_base_from_the_command_line(tmp_path):
    cfg = tmp_path / "s.yaml"
    cfg.write_text("eps_e: 0.05\nradius: 1.0\ngrid:\n  S: [0.5]\n  T: [6]\n")
    out = tmp_path / "o"
    # --grid replaces the config's S axis and keeps its T; --delta sets the base
    res = _sweep("-c", cfg, "-g", "S=0.05,0.3", "--delta", "0.0", "-o", out, "-j", "1")
    assert res.exit_code == 0, res.output
    t = _table(out)
    assert list(t["S"]) == [0.05, 0.3] and list(t["T"]) == [6, 6]
    assert list(t["delta_value"]) == [0.0, 0.0] and list(t["feasible"]) == [True, False]
    bad = _sweep("-c", cfg, "-g", "S0.05", "-o", tmp_path / "b", "-j", "1")
    assert bad.exit_code == 2 and "expected AXIS=V1,V2" in bad.output


# --------------------------------------------------------------------------- Dask failures
def _qsls_sweep(*args: object) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "qsls.cli.main", "sweep", *map(str, args)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _one_error_line(stderr: str) -> str:
    assert "Traceback" not in stderr, stderr
    errors = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, stderr
    return errors[0]


def test_a_scheduler_address_without_port_is_refused_up_front(tmp_path):
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL)
    t0 = time.monotonic()
    proc = _qsls_sweep("-c", cfg, "-o", tmp_path / "o", "--scheduler", "tcp://127.0.0.1")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "missing port number" in _one_error_line(err) and "tcp://127.0.0.1:8786" in err
    assert time.monotonic() - t0 < 15  # not the 10 s connection timeout first
    assert not (tmp_path / "o").exists()


class _Cluster:
    """A real `dask scheduler` (and `dask worker --no-nanny` processes) on loopback."""

    def __init__(self, tmp_path: Path) -> None:
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.log = open(tmp_path / "dask.log", "w")  # noqa: SIM115 - closed in stop()
        self.procs: list[subprocess.Popen] = []
        sched = [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1"]
        self._start([*sched, "--port", str(self.port), "--no-dashboard"])
        _wait_for_port(self.port)

    def _start(self, cmd: list[str]) -> subprocess.Popen:
        proc = subprocess.Popen(cmd, stdout=self.log, stderr=self.log)
        self.procs.append(proc)
        return proc

    def worker(self) -> subprocess.Popen:
        cmd = [sys.executable, "-m", "dask", "worker", self.address, "--no-nanny"]
        return self._start([*cmd, "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"])

    def stop(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=20)
        self.log.close()


@pytest.mark.slow
def test_a_scheduler_without_workers_fails_with_one_line_after_waiting(tmp_path):
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL)
    cluster = _Cluster(tmp_path)
    try:
        t0 = time.monotonic()
        proc = _qsls_sweep(
            "-c", cfg, "-o", tmp_path / "o", "--scheduler", cluster.address, "--wait-workers", 3
        )
        _, err = proc.communicate(timeout=120)
        elapsed = time.monotonic() - t0
    finally:
        cluster.stop()
    assert proc.returncode == 2, err
    assert f"waiting for workers at {cluster.address}" in err
    assert "no Dask worker joined the scheduler" in _one_error_line(err)
    assert 3 <= elapsed < 60
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_the_only_worker_dying_fails_with_one_line(tmp_path):
    from distributed import Client

    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL.replace("T: [6, 10]", "T: [20, 30, 40]"))
    cluster = _Cluster(tmp_path)
    try:
        worker = cluster.worker()
        _wait_for_workers(cluster.address, 1)
        proc = _qsls_sweep(
            "-c", cfg, "-o", tmp_path / "o", "--scheduler", cluster.address, "--wait-workers", 3
        )
        with Client(cluster.address, timeout="20s", set_as_default=False) as client:
            deadline = time.monotonic() + 60
            while not client.processing() or not any(client.processing().values()):
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.05)
        worker.kill()  # the only worker dies while it solves
        _, err = proc.communicate(timeout=120)
    finally:
        cluster.stop()
    assert proc.returncode == 2, err
    assert f"every Dask worker at {cluster.address} left" in _one_error_line(err)
    assert not (tmp_path / "o").exists()


def test_a_large_horizon_is_announced_before_the_solves(tmp_path):
    cfg = tmp_path / "big.yaml"  # S = 1.5 fails the necessary condition: nothing is solved
    cfg.write_text("eps_e: 0.05\nradius: 1.0\ndelta: 0.05\ns_max_curve: false\n"
                   "grid:\n  S: [1.5]\n  T: [200]\n")  # fmt: skip
    proc = _qsls_sweep("-c", cfg, "-o", tmp_path / "o", "--jobs", "1")
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    # (T + 1) taps of Phi_xx (6x6), Phi_ux (3x6), Phi_xy (6x6), Phi_uy (3x6)
    assert f"T = 200: about {201 * (36 + 18 + 36 + 18):,} variables per problem" in err
    small = _qsls_sweep("-c", cfg, "-o", tmp_path / "s", "--jobs", "1", "-g", "T=20")
    _, err = small.communicate(timeout=120)
    assert small.returncode == 0 and "variables per problem" not in err


def test_none_feasible_is_said_not_a_negative_s(tmp_path):
    """A setting where no S >= 0 is feasible: the summary says 'none feasible' (it printed a
    negative largest S before), the s_max table keeps the number."""
    cfg = tmp_path / "s.yaml"
    cfg.write_text(
        "eps_e: 0.05\nradius: 1.0\ndelta: 0.99\neps_w: 0.01\ngrid:\n  S: [0.0]\n  T: [6]\n"
    )
    res = _sweep("-c", cfg, "-o", tmp_path / "o", "--jobs", "1")
    assert res.exit_code == 0, res.output
    assert "none feasible" in res.output
    s_max = pd.read_parquet(tmp_path / "o" / "s_max.parquet")
    assert (s_max["s_max"] < 0).all()


def test_a_sweep_row_is_the_certificate_synth_writes_for_the_same_options():
    """One path from options to a certified solution: the sweep's row of a point is the
    projection of the certificate ``synthesize`` makes for the same options (every number
    equal, not close), the imitation of ``l1_nominal`` included."""
    from qsls.pipeline.control.options import SweepOptions, SynthOptions
    from qsls.pipeline.control.sweep import ROW_FIELDS, compute
    from qsls.pipeline.control.synth import synthesize

    base = {"T": 6, "S": 0.05, "eps_e": 0.05, "radius": 1.0, "delta": 0.05, "eps_w": 0.01,
            "imitate": "l1_nominal"}  # fmt: skip
    made = synthesize(ModelInput(), SynthOptions(**base)).certificates()
    opts = SweepOptions(**base, grid={"cost": ["qr", "imitation"]}, s_max_curve=False)
    table, _, _ = compute(opts, jobs=1)
    for row, name in zip(table.itertuples(), ("l1_robust", "l1_robust_imitation"), strict=True):
        cert = made[name]
        assert row.status == cert.status == "relaxed"
        assert row.cost_value == cert.cost_value
        for col, field in ROW_FIELDS.items():
            assert getattr(row, col) == getattr(cert, field), (name, col)
    assert made["l1_robust_imitation"].imitate == "l1_nominal"
    assert table["cost_value"][1] != made["l1_robust"].cost_value  # a different problem


@pytest.mark.slow
def test_the_scheduler_lost_mid_sweep_fails_with_one_line(tmp_path):
    """The Dask scheduler killed while a worker solves (issue 35: FuturesCancelledError)."""
    from distributed import Client

    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL.replace("T: [6, 10]", "T: [20, 30, 40]"))
    cluster = _Cluster(tmp_path)
    try:
        cluster.worker()
        _wait_for_workers(cluster.address, 1)
        proc = _qsls_sweep(
            "-c", cfg, "-o", tmp_path / "o", "--scheduler", cluster.address, "--wait-workers", 3
        )
        with Client(cluster.address, timeout="20s", set_as_default=False) as client:
            deadline = time.monotonic() + 60
            while not client.processing() or not any(client.processing().values()):
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.05)
        cluster.procs[0].kill()  # the scheduler dies while its worker solves
        _, err = proc.communicate(timeout=120)
    finally:
        cluster.stop()
    assert proc.returncode == 2, err
    line = _one_error_line(err)
    assert f"the Dask scheduler at {cluster.address}" in line and "rerun the sweep" in line
    assert not (tmp_path / "o").exists()


def test_jobs_zero_means_every_core_and_no_more_processes_than_cores(tmp_path):
    """Issue 35: --jobs 0 (which evaluate accepts) was refused, --jobs 64 started 64
    processes on 2 cores. 0 now means every core; no pool has more processes than cores."""
    from qsls.pipeline.control.options import SweepSection
    from qsls.pipeline.core.pools import available_cores, pool_size

    cores = available_cores()
    assert SweepSection(jobs=0).jobs == 0 and pool_size(0) == cores == pool_size(None)
    assert pool_size(64) == cores and pool_size(1) == 1
    cfg = tmp_path / "sweep.yaml"
    cfg.write_text(SMALL)
    res = _sweep("-c", cfg, "-o", tmp_path / "j64", "--jobs", 64)
    assert res.exit_code == 0, res.output
    assert f"local, {cores} process" in res.output, res.output


def _premise(eps_e: float, radius: float) -> PremiseNumbers:
    """The premise these sweeps state (``eps_w`` 0.01, ``Delta`` 0.05; ``S`` aside)."""
    return PremiseNumbers(eps=float(eps_e), S=0.0, radius=float(radius), eps_w=0.01, delta=0.05)

"""The foundation: atomic stage folders, manifests, config validation, the CLI's surface."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qsls.cli.main import app
from qsls.pipeline.core import artifacts
from qsls.pipeline.core.config import Options, load_options
from qsls.pipeline.core.errors import ConfigError, OutputExistsError
from qsls.pipeline.core.plant import quadrotor_model


class _Inner(Options):
    gain: float = 1.0


class _Opts(Options):
    dt: float = 0.1
    align: str = "4dof"
    inner: _Inner = _Inner()


def test_unknown_key_suggests_nearest(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("dtt: 0.2\n")
    with pytest.raises(ConfigError, match="unknown option 'dtt'; did you mean 'dt'"):
        load_options(_Opts, cfg)
    cfg.write_text("inner:\n  gian: 2\n")
    with pytest.raises(ConfigError, match="did you mean 'gain'"):
        load_options(_Opts, cfg)


def test_command_line_wins_over_file(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("dt: 0.2\nalign: se3\n")
    opts = load_options(_Opts, cfg, {"dt": 0.05, "align": None})
    assert opts.dt == 0.05 and opts.align == "se3"


def test_malformed_yaml_is_one_clear_error(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("dt: [0.1\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_options(_Opts, cfg)


def test_stage_writer_is_atomic_and_refuses_overwrite(tmp_path):
    out = tmp_path / "stage"
    src = tmp_path / "input.txt"
    src.write_text("hello")
    df = pd.DataFrame({"a": np.arange(5), "b": np.linspace(0, 1, 5)})
    with artifacts.StageWriter(out, "demo", options={"k": 1}, inputs=[src]) as w:
        w.write_parquet("t.parquet", df)
        w.results["n"] = 5
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["inputs"][0]["sha256"] == artifacts.sha256_file(src)
    assert manifest["results"]["n"] == 5
    assert manifest["files"]["t.parquet"] == artifacts.sha256_file(out / "t.parquet")
    # the manifest lists exactly the published files (not the temporary's PID-signed marker)
    published = {p.name for p in out.iterdir() if p.is_file()} - {"manifest.json"}
    assert set(manifest["files"]) == published == {"t.parquet"}
    first = (out / "t.parquet").read_bytes()

    with pytest.raises(OutputExistsError):
        artifacts.StageWriter(out, "demo").__enter__()

    # A stage that fails mid-way leaves the old output untouched and no temp folder.
    with pytest.raises(RuntimeError), artifacts.StageWriter(out, "demo", force=True) as w:
        w.write_text("partial.txt", "x")
        raise RuntimeError("killed")
    assert not (out / "partial.txt").exists()
    assert (out / "t.parquet").read_bytes() == first
    assert not list(tmp_path.glob(".stage.tmp-*"))

    # Same data, same bytes.
    with artifacts.StageWriter(out, "demo", force=True) as w:
        w.write_parquet("t.parquet", df)
    assert (out / "t.parquet").read_bytes() == first


def test_npz_is_deterministic():
    a = {"x": np.arange(6.0).reshape(2, 3), "y": np.eye(2)}
    assert artifacts.npz_bytes(a) == artifacts.npz_bytes(dict(reversed(list(a.items()))))


def test_zoh_model_matches_closed_form():
    m = quadrotor_model(dt=0.1, mass=0.256)
    dt, g = 0.1, 9.81
    assert np.allclose(m.A[:3, 3:], dt * np.eye(3))
    assert m.B[3, 0] == pytest.approx(-g * dt)
    assert m.B[0, 0] == pytest.approx(-g * dt**2 / 2)
    assert m.B[5, 2] == pytest.approx(dt / 0.256)


def test_cli_version_and_help():
    runner = CliRunner()
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.stdout.startswith("qsls ")
    proc = subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", "--help"], capture_output=True, text=True
    )
    assert proc.returncode == 0 and "Usage" in proc.stdout


@pytest.mark.parametrize("size", [0, 1, (1 << 18) - 1, 1 << 18, (1 << 18) + 3, 5 << 20])
def test_file_hash_equals_hashlib(tmp_path, size):
    """Read in pieces (256 KiB: ``hashlib.file_digest``'s), a file hashes to hashlib's sha256
    of its bytes, whole and across piece boundaries (primed in a thread or not)."""
    import hashlib

    data = np.random.default_rng(size).integers(0, 256, size, dtype=np.uint8).tobytes()
    f = tmp_path / "f.bin"
    f.write_bytes(data)
    want = hashlib.sha256(data).hexdigest()
    assert artifacts.sha256_file(f) == want
    artifacts.prime_hashes([f])
    assert artifacts.sha256_file(f) == want


@pytest.mark.parametrize("n", [0, 1, 257])
def test_flight_table_reads_back_as_the_pandas_frame(tmp_path, n):
    """What ingest writes (a pyarrow table built without pandas) reads back as exactly the
    DataFrame ``make_flight_frame`` builds from the same arrays, dtypes and index included;
    and its parquet bytes are the same on every write."""
    from qsls.pipeline.ingest.flight import flight_table, make_flight_frame, read_flight

    rng = np.random.default_rng(n)
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    x = rng.normal(size=(n, 6))
    y = x + rng.normal(scale=0.01, size=(n, 6))
    data = artifacts.parquet_bytes(flight_table(stamps, x, y))
    # strided columns (C order) and contiguous ones (Fortran order) give the same bytes
    assert data == artifacts.parquet_bytes(
        flight_table(stamps, np.asfortranarray(x), np.asfortranarray(y))
    )
    (tmp_path / "flight.parquet").write_bytes(data)
    pd.testing.assert_frame_equal(
        read_flight(tmp_path), make_flight_frame(stamps, x, y), check_exact=True
    )

"""Nothing lost, nothing trusted blindly (issue 16): outputs never overwrite inputs, output
folders are locked, degenerate input is refused, through the public commands."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from qsls.pipeline.core.artifacts import sha256_path
from tests.test_fit import vio_flights

REPO = Path(__file__).resolve().parents[1]


def qsls(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
    )


def one_line_error(proc: subprocess.CompletedProcess, code: int = 2) -> str:
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


# --------------------------------------------------------------------------- item 1
def test_force_never_destroys_an_input_folder(tmp_path):
    flights, _ = vio_flights(tmp_path / "flights", n=2)
    before = [sha256_path(f) for f in flights]
    parent = tmp_path / "flights"
    # the output contains the inputs
    msg = one_line_error(qsls("fit", *flights, "--out", parent, "--force", "--no-figures"))
    assert "contains the input" in msg
    # the output is an input
    msg = one_line_error(qsls("fit", *flights, "--out", flights[0], "--force", "--no-figures"))
    assert "is the input" in msg
    # the output lies inside an input, reached through a symlink
    link = tmp_path / "link"
    link.symlink_to(flights[1], target_is_directory=True)
    msg = one_line_error(qsls("fit", *flights, "--out", link / "fit", "--force"))
    assert "lies inside the input" in msg
    assert [sha256_path(f) for f in flights] == before
    assert sorted(p.name for p in parent.iterdir()) == ["flight0", "flight1"]

    fitted = tmp_path / "fit"
    ok = qsls("fit", *flights, "--out", fitted, "--no-figures", "--radius", "1.0")
    assert ok.returncode == 0, ok.stderr
    model_hash = sha256_path(fitted)
    msg = one_line_error(qsls("synth", "--model", fitted, "--out", fitted, "--force", "-T", "5"))
    assert "is the input" in msg
    assert sha256_path(fitted) == model_hash and (fitted / "error_model.yaml").is_file()

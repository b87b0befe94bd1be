"""Nothing of the user's touched (issue 35): qsls removes only the temporaries it created and
signed, only at the levels it writes; a run folder that overlaps an input, a filesystem root
or a folder of other files is refused before anything is written."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from qsls.pipeline.core.artifacts import StageWriter, atomic_write_bytes, publish
from qsls.pipeline.core.locks import (
    clean_dead_temporaries,
    clean_stale,
    is_temporary,
    make_temporary,
    mark_temporary,
)

TINY = {
    "name": "tiny",
    "seed": 0,
    "stages": ["simulate"],
    "simulate": {"duration": 5.0},
    "flights": [{"name": "f1", "role": "train", "simulate": {"seed": 1}}],
    "report": False,
}


def _qsls(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "qsls.cli.main", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
    )


def _one_line_refusal(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _tree(root: Path) -> dict[str, bytes | None]:
    return {
        p.relative_to(root).as_posix(): (p.read_bytes() if p.is_file() else None)
        for p in sorted(root.rglob("*"))
    }


def _plant_user_files(root: Path, dead: int) -> list[Path]:
    """Files and folders a user may well have, named like qsls's temporaries."""
    files = [
        root / ".env.old-prod",
        root / "sub" / ".draft.tmp-notes",
        root / "sub" / "deeper" / ".thesis.old-v2" / "chapter1.tex",
        root / f".notes.tmp-{dead}",  # a dead process's number, but a user's file
        root / f".backup.old-{dead}" / "keep.txt",  # a folder without qsls's signature
        root / "simulate" / f".f1.tmp-{dead}" / "mine.txt",  # beside a stage folder, unsigned
    ]
    for f in files:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text("the user's\n")
    return files


def test_clean_stale_keeps_what_qsls_did_not_sign(tmp_path):
    dead = _dead_pid()
    out = tmp_path / "fit"
    user = [
        tmp_path / ".fit.old-v2",
        tmp_path / f".fit.tmp-{dead}",
        tmp_path / f".fit.old-{dead}" / "thesis.tex",
    ]
    for f in user:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text("x")
    forged = tmp_path / f".fit.tmp-{dead}x"  # signed, but its name holds no pid
    forged.mkdir()
    mark_temporary(forged)
    other = tmp_path / f".fit.old-{dead}"
    assert not is_temporary(other)  # the user's folder: no signature
    live = make_temporary(out)  # this live process's work in progress
    # forge a dead process's temporary the way qsls signs one
    dead_tmp = tmp_path / f".fit.tmp-{_dead_pid()}"
    dead_tmp.mkdir()
    (dead_tmp / ".qsls-temporary").write_text(f"qsls temporary {dead_tmp.name.rsplit('-', 1)[1]}\n")
    (dead_tmp / "part.parquet").write_bytes(b"half")
    clean_stale(out)
    assert all(f.exists() for f in user) and forged.exists() and live.exists()
    assert not dead_tmp.exists()


def test_run_keeps_user_files_named_like_temporaries(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    root = tmp_path / "runs" / "tiny"
    first = _qsls("run", cfg, "--out", root, cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    dead = _dead_pid()
    user = _plant_user_files(root, dead)
    # a real leftover of a killed qsls process: signed, at a level a run writes
    killed = root / "simulate" / f".f1.tmp-{_dead_pid()}"
    killed.mkdir()
    (killed / ".qsls-temporary").write_text(f"qsls temporary {killed.name.rsplit('-', 1)[1]}\n")
    before = {f: f.read_bytes() for f in user}
    again = _qsls("run", cfg, "--out", root, cwd=tmp_path)  # cleans up, then up to date
    assert again.returncode == 0, again.stderr[-2000:]
    assert {f: f.read_bytes() for f in user if f.exists()} == before
    assert not killed.exists()


def test_atomic_writes_and_publish_leave_no_temporary(tmp_path):
    atomic_write_bytes(tmp_path / "run.json", b"{}\n")
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]
    out = tmp_path / "stage"
    for _ in range(2):
        with StageWriter(out, "test", force=True) as w:
            w.write_text("a.txt", "a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.json", "stage"]


def test_force_onto_a_symlinked_out_leaves_no_old_link(tmp_path):
    target = tmp_path / "elsewhere"
    with StageWriter(target, "test") as w:
        w.write_text("a.txt", "a")
    link = tmp_path / "out"
    link.symlink_to(target)
    with StageWriter(link, "test", force=True) as w:
        w.write_text("a.txt", "b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "out"]
    assert (link / "a.txt").read_text() == "b" and not link.is_symlink()
    assert (target / "a.txt").read_text() == "a"  # the link's target is left alone


def test_publish_refuses_an_unsigned_folder_in_the_way(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / f".out.old-{os.getpid()}").mkdir()  # the user's, named like ours
    tmp = make_temporary(out)
    from qsls.pipeline.core.errors import OutputExistsError

    with pytest.raises(OutputExistsError, match="not written by qsls"):
        publish(tmp, out)
    assert (tmp_path / f".out.old-{os.getpid()}").is_dir()


def test_dead_temporaries_only_at_the_given_levels(tmp_path):
    deep = tmp_path / "a" / "b"
    deep.mkdir(parents=True)
    dead = _dead_pid()
    here = tmp_path / f".x.tmp-{dead}"
    there = deep / f".x.tmp-{dead}"
    for d in (here, there):
        d.mkdir()
        (d / ".qsls-temporary").write_text(f"qsls temporary {dead}\n")
    assert clean_dead_temporaries([tmp_path]) == [here]
    assert there.exists()


# ------------------------------------------------------------ refused before anything is written
@pytest.fixture(scope="module")
def bag_config(tmp_path_factory):
    from tests.bagfixtures import write_flight

    work = tmp_path_factory.mktemp("bagrun")
    bag = write_flight(work / "flight_ros2", "ros2-sqlite", duration=4.0)
    cfg = work / "real.yaml"
    flight = {"name": "f1", "role": "train", "sources": [str(bag)]}
    cfg.write_text(yaml.safe_dump({"name": "real", "flights": [flight], "report": False}))
    return work, cfg, bag


@pytest.mark.parametrize("via_link", [False, True], ids=["folder", "symlink"])
def test_run_out_an_input_is_refused_before_writing(bag_config, via_link):
    work, cfg, bag = bag_config
    out = bag
    if via_link:
        out = work / "link_to_bag"
        if not out.is_symlink():
            out.symlink_to(bag)
    before, beside = _tree(bag), sorted(p.name for p in bag.parent.iterdir())
    line = _one_line_refusal(_qsls("run", cfg, "--out", out, cwd=work))
    assert "input" in line and "choose" in line
    assert _tree(bag) == before
    assert sorted(p.name for p in bag.parent.iterdir()) == beside


@pytest.mark.parametrize("out", ["/", ".", ".."])
def test_run_out_root_or_a_folder_of_other_files_is_one_line(tmp_path, out):
    cwd = tmp_path / "project" / "work"
    cwd.mkdir(parents=True)
    (cwd / "notes.txt").write_text("mine")
    (tmp_path / "project" / "fit").mkdir()
    (tmp_path / "project" / "fit" / "mine.txt").write_text("mine")
    cfg = cwd / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    before = _tree(tmp_path)
    line = _one_line_refusal(_qsls("run", cfg, "--out", out, "--force", cwd=cwd))
    assert "--out" in line
    assert _tree(tmp_path) == before


def test_a_published_folder_holds_only_what_the_stage_wrote(tmp_path):
    out = tmp_path / "stage"
    for force in (False, True):
        with StageWriter(out, "test", force=force) as w:
            w.write_text("a.txt", "a")
        assert sorted(p.name for p in out.iterdir()) == ["a.txt", "manifest.json"]

"""What a new user met (issue 26): bad numbers, unwritable folders, misnamed formats and
other inputs answered with one line and nothing left behind, through the public commands."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from qsls.cli.main import app

RUN = CliRunner()
REPO = Path(__file__).resolve().parents[1]


def invoke(*args):
    return RUN.invoke(app, [str(a) for a in args])


def one_line(res, code: int = 2) -> str:
    """The single ``error:`` line of a refused command (no traceback)."""
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    return lines[0]


# --------------------------------------------------------------------------- item 6
@pytest.mark.parametrize(
    "args, field, value",
    [
        (["ingest", "--vio", "v.txt", "--truth", "t.txt", "--time-offset", "nan"], "time_offset", "nan"),
        (["ingest", "--vio", "v.txt", "--truth", "t.txt", "--time-offset", "inf"], "time_offset", "inf"),
        (["synth", "--S", "nan"], "S", "nan"),
        (["synth", "--eps-e", "nan"], "eps_e", "nan"),
        (["synth", "--delta", "nan"], "delta", "nan"),
        (["synth", "--dt", "inf"], "dt", "inf"),
        (["synth", "--S", "-inf"], "S", "-inf"),
    ],
)  # fmt: skip
def test_non_finite_numbers_are_refused_by_the_options_model(tmp_path, args, field, value):
    res = invoke(*args, "--out", tmp_path / "out")
    assert one_line(res) == f"error: command line: '{field}': must be a finite number (got {value})"
    assert not (tmp_path / "out").exists()


def test_non_finite_numbers_in_a_config_file_or_a_list_are_refused(tmp_path):
    from qsls.pipeline.core.config import load_options
    from qsls.pipeline.core.errors import ConfigError
    from qsls.pipeline.export.replay import ReplayOptions

    cfg = tmp_path / "replay.yaml"
    cfg.write_text("replay:\n  thrust_band: [0.5, .inf]\n")
    with pytest.raises(ConfigError, match=r"'thrust_band': must be a finite number"):
        load_options(ReplayOptions, cfg, section="replay")
    cfg.write_text("replay:\n  max_gap: .nan\n")
    with pytest.raises(ConfigError, match=r"'max_gap': must be a finite number \(got nan\)"):
        load_options(ReplayOptions, cfg, section="replay")


# --------------------------------------------------------------------------- item 1
def test_an_output_containing_the_config_file_is_refused_even_with_force(tmp_path):
    from tests.test_fit import vio_flights

    flights, _ = vio_flights(tmp_path / "flights", n=1)
    folder = tmp_path / "d"
    folder.mkdir()
    cfg = folder / "fit.yaml"
    cfg.write_text("fit:\n  radius: 1.0\n  figures: false\n")
    before = cfg.read_bytes()
    res = invoke("fit", *flights, "--config", cfg, "--out", folder, "--force")
    assert one_line(res) == (
        f"error: output folder {folder} contains the input {cfg}; writing it would destroy the "
        "input (even with --force): choose an output folder apart from the inputs"
    )
    assert cfg.read_bytes() == before and sorted(p.name for p in folder.iterdir()) == ["fit.yaml"]
    # the same file, kept apart from the output, is read as usual
    assert invoke("fit", *flights, "--config", cfg, "--out", tmp_path / "fit").exit_code == 0


# --------------------------------------------------------------------------- item 5
def _unwritable(tmp_path):
    """(output, the folder the message names, why): a file used as a folder, and /proc."""
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    places = [(blocker / "out", blocker, "not a folder")]
    if Path("/proc/self").is_dir():
        places.append((Path("/proc/qsls-no/out"), Path("/proc"), "No such file or directory"))
    return places


def _refused_unwritable(res, out, folder, why, what="output folder"):
    line = one_line(res)
    assert line.startswith(f"error: cannot write the {what} {out.absolute()}: "), line
    assert f"folder {folder} is not writable ({why})" in line, line


def test_an_unwritable_output_is_one_line_for_fit_ingest_and_run(tmp_path):
    from tests.bagfixtures import write_flight as write_bag
    from tests.test_fit import vio_flights

    flights, _ = vio_flights(tmp_path / "flights", n=1)
    bag = write_bag(tmp_path / "f.bag", "ros1", duration=15.0)
    for out, folder, why in _unwritable(tmp_path):
        _refused_unwritable(invoke("fit", *flights, "--out", out), out, folder, why)
        _refused_unwritable(invoke("ingest", bag, "--out", out), out, folder, why)
        res = invoke("run", REPO / "configs" / "quickstart.yaml", "--out", out)
        _refused_unwritable(res, out, folder, why, "run folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "f.bag", "flights"]


def test_a_read_only_mount_is_one_line(tmp_path):
    """A read-only file system, mounted in a user namespace of its own (skipped where the
    kernel does not allow one)."""
    import shutil
    import subprocess
    import sys

    from tests.test_fit import vio_flights

    flights, _ = vio_flights(tmp_path / "flights", n=1)
    ro = tmp_path / "ro"
    ro.mkdir()
    if shutil.which("unshare") is None:
        pytest.skip("no unshare")
    probe = subprocess.run(["unshare", "-rm", "mount", "-t", "tmpfs", "-o", "ro", "none", ro],
                           capture_output=True)  # fmt: skip
    if probe.returncode != 0:
        pytest.skip("no user namespaces with mounts here")
    script = (
        f"mount -t tmpfs -o ro none {ro} && "
        f"{sys.executable} -m qsls.cli.main fit {flights[0]} --out {ro}/fit --radius 1"
    )
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip() == (
        f"error: cannot write the output folder {ro}/fit: folder {ro} is not writable "
        "(Read-only file system); choose another --out"
    )


# --------------------------------------------------------------------------- item 8
@pytest.mark.parametrize(
    "prefix, why",
    [
        ("int", "'int' is a C keyword; choose another name, e.g. 'int_ctrl'"),
        ("restrict", "'restrict' is a C keyword; choose another name, e.g. 'restrict_ctrl'"),
        ("class", "'class' is a Python keyword; choose another name, e.g. 'class_ctrl'"),
        ("__x", "'__x' is reserved in C (a leading '__' or '_' and a capital)"),
    ],
)
def test_export_prefix_must_be_a_usable_identifier(tmp_path, prefix, why):
    res = invoke(
        "export", tmp_path / "ctrl", "-t", "c", "--prefix", prefix, "--out", tmp_path / "x"
    )
    assert one_line(res).startswith(f"error: command line: 'prefix': {why}")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- item 7
def _tum_lines(t_text, p, sep=" "):
    return "".join(
        sep.join([a, *(f"{v:.6f}" for v in (*b, 0.0, 0.0, 0.0, 1.0))]) + "\n"
        for a, b in zip(t_text, p, strict=True)
    )


def test_tum_stamps_in_nanoseconds_read_as_the_same_flight(tmp_path):
    import numpy as np

    from qsls.pipeline.core.artifacts import sha256_file

    t_ns = 1_403_636_579_000_000_000 + np.arange(0, 20_000_000_000, 20_000_000, dtype=np.int64)
    t = (t_ns - t_ns[0]) * 1e-9
    truth = np.c_[np.cos(t), np.sin(t), 1 + 0.1 * np.sin(3 * t)]
    vio = truth + np.random.default_rng(0).normal(scale=0.01, size=truth.shape)
    secs = [f"{v // 10**9}.{v % 10**9:09d}" for v in t_ns.tolist()]
    nanos = [str(v) for v in t_ns.tolist()]
    for name, stamps in (("s", secs), ("ns", nanos)):
        (tmp_path / f"vio_{name}.tum").write_text(_tum_lines(stamps, vio))
        (tmp_path / f"truth_{name}.tum").write_text(_tum_lines(stamps, truth))
        res = invoke("ingest", "--vio", tmp_path / f"vio_{name}.tum",
                     "--truth", tmp_path / f"truth_{name}.tum", "--out", tmp_path / name)  # fmt: skip
        assert res.exit_code == 0, res.output
    assert sha256_file(tmp_path / "s" / "flight.parquet") == sha256_file(
        tmp_path / "ns" / "flight.parquet"
    )


def test_a_comma_separated_tum_file_and_a_stamp_beyond_any_clock_are_named(tmp_path):
    p = [(1.0, 2.0, 3.0)] * 2
    commas = tmp_path / "commas.tum"
    commas.write_text(
        "# t x y z qx qy qz qw\n" + _tum_lines(["1403636579.758", "1403636579.808"], p, ",")
    )
    good = tmp_path / "good.tum"
    good.write_text(_tum_lines(["1403636579.758", "1403636579.808"], p))
    res = invoke("ingest", "--vio", commas, "--truth", good, "--out", tmp_path / "o")
    assert one_line(res) == (
        f"error: {commas}: read as EuRoC csv (comma-separated, 't_ns, px, py, pz, qw, qx, qy, "
        "qz, ...' with t in integer nanoseconds), but line 2 has '1403636579.758', 8 "
        "comma-separated fields with a stamp in seconds: a TUM file with commas? TUM separates "
        "'t x y z qx qy qz qw' (t in seconds) by spaces; replace the commas by spaces"
    )
    huge = tmp_path / "huge.tum"
    huge.write_text(_tum_lines(["1e30", "2e30"], p))
    res = invoke("ingest", "--vio", huge, "--truth", good, "--out", tmp_path / "o")
    assert one_line(res) == (
        f"error: {huge}: line 1: stamp 1e30 read as seconds is beyond any clock; TUM stamps "
        "are seconds ('1403636579.758555'), or integer nanoseconds (>= 1e+15)"
    )
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- item 12
def test_from_fly_reruns_fly_only_and_an_unknown_stage_names_the_choices(tmp_path):
    from qsls.pipeline.core.artifacts import StageWriter
    from qsls.pipeline.run.graph import Stage, StageGraph

    def writer(kind):
        def execute(out, deps):
            with StageWriter(out, kind, options={}, force=True) as w:
                w.write_text("x.txt", kind)

        return execute

    def graph():
        g = StageGraph(tmp_path / "run")
        g.add(Stage("fit", "fit", {}, writer("fit")))
        g.add(Stage("synth", "synth", {}, writer("synth"), deps=("fit",)))
        g.add(Stage("evaluate", "evaluate", {}, writer("evaluate"), deps=("synth",)))
        g.add(Stage("fly", "fly", {}, writer("fly"), deps=("synth",)))
        return g

    assert [o.status for o in graph().run()] == ["ran"] * 4
    ran = {o.id for o in graph().run(from_kind="fly") if o.status == "ran"}
    assert ran == {"fly"}
    ran = {o.id for o in graph().run(from_kind="evaluate") if o.status == "ran"}
    assert ran == {"evaluate", "fly"}
    res = invoke(
        "run", REPO / "configs" / "quickstart.yaml", "--from", "flying", "--out", tmp_path / "r"
    )
    assert one_line(res) == (
        "error: --from flying: not a stage (choose from simulate, ingest, fit, sweep, synth, "
        "calibrate, evaluate, report, fly)"
    )
    assert not (tmp_path / "r").exists()


def test_report_on_a_folder_that_is_not_a_run_is_one_line(tmp_path):
    from qsls.pipeline.core.artifacts import StageWriter

    stage = tmp_path / "model"
    with StageWriter(stage, "fit", options={}) as w:
        w.write_text("error_model.yaml", "eps_e: 0.1\n")
    res = invoke("report", stage, "--out", tmp_path / "r")
    assert one_line(res) == (
        f"error: {stage}: a 'fit' stage folder, not a run; pass the run folder that holds it "
        "(written by 'qsls run', e.g. runs/quickstart)"
    )
    # a folder holding stage folders, but not where a run puts them
    other = tmp_path / "work"
    with StageWriter(other / "mine" / "model", "fit", options={}) as w:
        w.write_text("error_model.yaml", "eps_e: 0.1\n")
    res = invoke("report", other, "--out", tmp_path / "r")
    assert one_line(res) == (
        f"error: {other}: not a run folder (no run.json and no stage folders such as fit/ or "
        "ingest/NAME/); pass the folder a 'qsls run' wrote, e.g. runs/quickstart"
    )
    assert not (tmp_path / "r").exists()


# --------------------------------------------------------------------------- item 3
@pytest.mark.slow
def test_two_runs_of_one_config_keep_their_own_reports_and_write_nowhere_else(tmp_path):
    import subprocess
    import sys

    from tests.test_run_cache import _config

    cfg = _config(tmp_path, report=True)
    for out in ("a", "b"):
        proc = subprocess.run(
            [sys.executable, "-m", "qsls.cli.main", "run", cfg, "--out", out],
            cwd=tmp_path, capture_output=True, text=True,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert f"{out}/report/index.html" in proc.stdout
    # the working folder holds the config and the two runs, nothing else (no reports/)
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == [
        "a", "b", cfg.name,
    ]  # fmt: skip
    a, b = (tmp_path / n / "report" / "index.html" for n in "ab")
    assert a.is_file() and b.is_file()
    # same config and seed: the same page, each in its own run (neither overwrote the other)
    assert a.read_bytes() == b.read_bytes() and a.stat().st_ino != b.stat().st_ino


# --------------------------------------------------------------------------- item 2
def _run_config(tmp_path, **changes):
    import yaml

    from tests.test_run_cache import SMALL

    data = {**SMALL, **changes}
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    return cfg


def test_a_heldout_flight_without_an_evaluate_section_is_evaluated_with_defaults(tmp_path):
    from qsls.pipeline.evaluate.options import EvaluateOptions
    from qsls.pipeline.run.runner import load_run_config, plan
    from tests.test_run_cache import SMALL

    flights = [*SMALL["flights"], {"name": "held", "role": "heldout", "simulate": {"seed": 3}}]
    for stages in (None, ["simulate", "ingest", "fit", "synth", "evaluate"]):
        cfg = _run_config(tmp_path, flights=flights, stages=stages)
        graph = plan(load_run_config(cfg), cfg, tmp_path / "run")
        (evaluate,) = [s for s in graph.stages if s.id == "evaluate"]
        assert evaluate.options == EvaluateOptions()
        assert set(evaluate.deps) == {"fit", "synth", "ingest/held"}
    assert not (tmp_path / "run").exists()


def test_evaluate_listed_with_nothing_to_evaluate_is_refused_before_any_stage(tmp_path):
    stages = ["simulate", "ingest", "fit", "synth", "evaluate"]
    res = invoke("run", _run_config(tmp_path, stages=stages), "--out", tmp_path / "run")
    assert one_line(res) == (
        f"error: {tmp_path}: stages: evaluate is asked for but there is nothing to evaluate: "
        "no flight has role 'heldout'; add a held-out flight, or leave evaluate out (the "
        "controllers fly in a fly: section)"
    )
    res = invoke("run", _run_config(tmp_path, stages=stages, synth=None), "--out", tmp_path / "run")
    assert one_line(res) == (
        f"error: {tmp_path}: stages: evaluate is listed but there are no controllers to "
        "evaluate: add a synth: section (and synth to the stages)"
    )
    # fly, a stage of its own, is refused alike: without synth, and without its section
    fly = {"seeds": [0], "duration": 5, "conditions": ["regular"]}
    flying = ["simulate", "ingest", "fit", "fly"]
    res = invoke("run", _run_config(tmp_path, stages=flying, fly=fly), "--out", tmp_path / "run")
    assert one_line(res) == (
        f"error: {tmp_path}: stages: fly is listed but there are no controllers to "
        "fly: add a synth: section (and synth to the stages)"
    )
    res = invoke("run", _run_config(tmp_path, stages=[*stages, "fly"]), "--out", tmp_path / "run")
    assert one_line(res) == (
        f"error: {tmp_path}: stages: fly is listed but the config has no fly: section (the "
        "seeds, conditions and duration to fly): add one, or leave fly out"
    )
    assert not (tmp_path / "run").exists()


# --------------------------------------------------------------------------- item 13
@pytest.mark.slow
def test_ctrl_c_during_a_parallel_sweep_ends_it_at_once(tmp_path):
    """Ctrl-C (SIGINT to the process group) ended a --jobs 2 sweep only after the points
    being solved finished (11-20 s); now as quickly as SIGTERM."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import yaml

    from tests.test_run_cache import _alive, _workers, interruptible

    cfg = yaml.safe_load((REPO / "configs" / "ci_sweep.yaml").read_text())
    cfg["grid"]["T"] = [150, 200, 250]  # points of a second or more each (the solver got faster)
    (tmp_path / "big.yaml").write_text(yaml.safe_dump(cfg))
    proc = interruptible(
        [sys.executable, "-m", "qsls.cli.main", "sweep", "--config", tmp_path / "big.yaml",
         "--out", tmp_path / "sw", "--jobs", "2"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        workers = _workers(proc.pid, 2)
        time.sleep(2.0)  # inside the solves
        assert proc.poll() is None, "the sweep ended before Ctrl-C"
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "interrupted; no partial output was kept" in err, err
    assert "Traceback" not in err
    assert took < 3, f"Ctrl-C took {took:.1f} s"
    assert not any(_alive(w) for w in workers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.yaml"]


# --------------------------------------------------------------------------- smaller: console
def test_a_first_run_says_done_and_a_rerun_says_why():
    """Each line shows the stage's own time, then the run's so far (issue 50: the run's
    cumulative time was shown as if it were the stage's)."""
    from qsls.cli.run import stage_line

    assert stage_line("fit", "ran", 2, 6, "not run yet", 3.25, 9.5) == "[3/6] fit" + " " * 22 + (
        "done        (   3.2 s, 9.5 s in all)"
    )
    line = stage_line("fit", "ran", 2, 6, "output fit/error_model.yaml is missing", 3.0, 4.0)
    assert line is not None and line.endswith("  ran: output fit/error_model.yaml is missing")
    assert stage_line("synth", "skipped", 3, 6, "", 0.0, 1.0).endswith(
        "up to date  (   0.0 s, 1.0 s in all)"
    )
    assert stage_line("synth", "running", 3, 6, "", 1.0, 1.0) is None


def test_long_stages_print_lines_when_not_on_a_terminal(capsys):
    """With stderr not a terminal no bar is drawn: a line at most every ``every`` seconds
    while a task advances (every 0 s here: one per step; every hour: none)."""
    from qsls.cli.common import RichProgress

    with RichProgress(every=0.0) as p:
        p.start("flying", total=3)
        for _ in range(3):
            p.advance()
        p.finish()
    err = capsys.readouterr().err.splitlines()
    assert [ln.split(" (")[0] for ln in err] == [f"flying: {k}/3" for k in (1, 2, 3)]
    with RichProgress(every=3600.0) as p:
        p.start("sweep", total=36)
        for _ in range(36):
            p.advance()
    assert capsys.readouterr().err == ""


def test_box_table_draws_every_cell_whole():
    """The summary tables: columns as wide as their widest cell (no wrapping at 80 columns),
    a multi-line cell on lines of its own, rich's box characters."""
    from qsls.cli.common import box_table

    long = "/a/" + "x" * 120 + "/flight"
    got = box_table("qsls t", None, [["output", long], ["gaps", "0\n1 s at 3.2 s"]]).split("\n")
    assert got == [
        "qsls t",
        "┌────────┬" + "─" * (len(long) + 2) + "┐",
        f"│ output │ {long} │",
        "│ gaps   │ 0" + " " * (len(long) - 1) + " │",
        "│        │ 1 s at 3.2 s" + " " * (len(long) - 12) + " │",
        "└────────┴" + "─" * (len(long) + 2) + "┘",
    ]
    head = box_table("f", ["a", "bb"], [["1", "2"]]).split("\n")
    assert head == ["f", "┏━━━┳━━━━┓", "┃ a ┃ bb ┃", "┡━━━╇━━━━┩", "│ 1 │ 2  │", "└───┴────┘"]
    wide = box_table("f", None, [["名前", "\u00e9"], ["ab", "e\u0301"]]).split("\n")
    # a wide character takes two columns, a combining accent none
    assert wide[2:4] == ["│ 名前 │ \u00e9 │", "│ ab   │ e\u0301 │"]


def test_summary_tables_in_ascii_where_stdout_cannot_encode_boxes(tmp_path):
    """On a Latin-1 stdout the summary is drawn with + - | (rich did the same), not a
    UnicodeEncodeError."""
    import os
    import subprocess
    import sys

    code = "from qsls.cli.common import print_summary; print_summary('t', {'key': 'é 1'})"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, cwd=tmp_path, timeout=60,
        env={**os.environ, "PYTHONIOENCODING": "latin-1"},
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.decode("latin-1").splitlines() == [
        "t", "+-----+-----+", "| key | é 1 |", "+-----+-----+"
    ]  # fmt: skip


# --------------------------------------------------------------------------- smaller: palette
# Machado, Oliveira & Fernandes (2009), severity 1, on linear RGB
_CVD = {
    "normal": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    "protanopia": [[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216],
                   [-0.003882, -0.048116, 1.051998]],
    "deuteranopia": [[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413],
                     [-0.011820, 0.042940, 0.968881]],
    "tritanopia": [[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602],
                   [0.004733, 0.691367, 0.303900]],
}  # fmt: skip


def _lab(hex_colour, cvd="normal"):
    """CIELAB (D65) of an sRGB colour as seen with ``cvd``."""
    import numpy as np

    c = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)]) / 255
    rgb = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    rgb = np.clip(np.array(_CVD[cvd]) @ rgb, 0, 1)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                    [0.0193, 0.1192, 0.9505]]) @ rgb / [0.95047, 1.0, 1.08883]  # fmt: skip
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def test_every_controller_has_a_distinct_colour_blind_safe_colour():
    import itertools

    import numpy as np

    from qsls.pipeline.core.style import CONTROLLER_COLOURS, controller_colour

    names = ["pd", "l1_nominal", "l1_robust", "l1_robust_imitation", "se3"]
    assert len({controller_colour(n) for n in names}) == len(names)
    for cvd in _CVD:
        for a, b in itertools.combinations(names, 2):
            d = np.linalg.norm(_lab(CONTROLLER_COLOURS[a], cvd) - _lab(CONTROLLER_COLOURS[b], cvd))
            assert d >= 15, f"{a} and {b}: {d:.1f} CIELAB units apart under {cvd}"
    # the three l1_* controllers in different hue families (sky blue and blue were one)
    hue = {n: np.degrees(np.arctan2(*_lab(CONTROLLER_COLOURS[n])[[2, 1]])) % 360 for n in names}
    for a, b in itertools.combinations(["l1_nominal", "l1_robust", "l1_robust_imitation"], 2):
        gap = abs(hue[a] - hue[b]) % 360
        assert min(gap, 360 - gap) >= 45, f"{a} and {b}: hues {hue[a]:.0f} and {hue[b]:.0f} deg"


# --------------------------------------------------------------------------- smaller: figure
def test_the_perception_error_figure_draws_what_the_verdict_compares():
    """Per-sample ||e_k|| (not a 1 s average), its peak, and gamma_nominal of the flight the
    controller flew (not gamma_strict), with the axis holding the peak (it ended at 0.3 while
    the peak was 1.03)."""
    from types import SimpleNamespace

    import numpy as np
    import pandas as pd

    from qsls.pipeline.fly.figures import error_per_controller_figure, own_gamma

    t = np.arange(0.0, 20.0, 0.1)
    e = 0.05 + 0.02 * np.sin(t)
    e[137] = 1.03  # one outlier: a 1 s average would show ~0.14
    outcomes = [
        SimpleNamespace(name="regular/l1_robust/s0", condition="regular", controller="l1_robust"),
        SimpleNamespace(name="regular/pd/s0", condition="regular", controller="pd"),
    ]
    checks = pd.DataFrame(
        {
            "flight": ["regular/l1_robust/s0", "regular/l1_robust/s0", "regular/pd/s0"],
            "controller": ["l1_robust", "pd", "pd"],
            "flown_by": ["l1_robust", "l1_robust", "pd"],
            "gamma_nominal": [0.25, 0.9, np.nan],
        }
    )
    bounds = own_gamma(outcomes, checks)  # the own flight's row, not the reference bound's
    assert bounds["regular/l1_robust"] == 0.25 and np.isnan(bounds["regular/pd"])
    traces = {"regular/l1_robust": (t, e), "regular/pd": (t, 0.5 * e)}
    fig = error_per_controller_figure(traces, bounds, ["regular"])
    (ax,) = fig.axes
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    np.testing.assert_array_equal(lines["l1_robust"].get_ydata(), e)  # every sample, as is
    np.testing.assert_array_equal(lines["pd"].get_ydata(), 0.5 * e)
    peaks = sorted(float(ln.get_ydata()[0]) for ln in ax.get_lines() if ln.get_marker() == "v")
    assert peaks == [0.515, 1.03]
    level = [ln.get_ydata()[0] for ln in ax.get_lines() if ln.get_linestyle() == "--"]
    assert level == [0.25]  # l1_robust's gamma_nominal; pd has no bound
    assert ax.get_ylim()[1] >= 1.03 and "gamma_nominal" in ax.get_title(loc="left")
    assert [tx.get_text() for tx in ax.texts] == ["1.03", "0.515"]


# --------------------------------------------------------------------------- smaller: one seed
def test_one_seed_says_no_interval_instead_of_dashes(tmp_path):
    import math

    from qsls.pipeline.fly.items import interval_text as fly_interval_text
    from qsls.pipeline.fly.stats import Interval
    from qsls.pipeline.report.facts import Facts, interval_text
    from qsls.pipeline.report.summary import findings_lines

    one = {"id": 1, "claim": "PD tracks best", "verdict": "inconclusive", "effect": 1.31,
           "ci": [None, None]}  # fmt: skip
    f = Facts(run_dir=tmp_path, info={"name": "x"}, stages={},
              findings={"n_seeds": 1, "findings": [one]})  # fmt: skip
    assert findings_lines(f) == [
        "Finding 1, PD tracks best: **inconclusive** (effect 1.31, one seed: no interval)"
    ]
    ten = {**one, "ci": [1.1, 1.52]}
    f = Facts(run_dir=tmp_path, info={"name": "x"}, stages={},
              findings={"n_seeds": 10, "findings": [ten]})  # fmt: skip
    assert findings_lines(f) == [
        "Finding 1, PD tracks best: **inconclusive** (effect 1.31, 95% CI 1.1 to 1.52)"
    ]
    assert interval_text([None, None], 3) == "no interval"
    assert (
        fly_interval_text(Interval(1.31, math.nan, math.nan, 1)) == "1.31 (one seed: no interval)"
    )

"""``pipeline/run/runner.py`` called directly on a tiny config (three TUM text flights, T = 6):
the stage graph :func:`plan` builds (order, dependencies, external files), which cache keys a
change moves, and :func:`run`'s caching, invalidation, ``--from``/``--force`` and refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from qsls.pipeline.core.artifacts import sha256_file
from qsls.pipeline.core.errors import ConfigError
from qsls.pipeline.run.runner import load_run_config, plan, run

BASE = {
    "name": "tiny",
    "flights": [
        {"name": "a", "role": "train", "vio": "a_vio.txt", "truth": "a_truth.txt"},
        {"name": "b", "role": "train", "vio": "b_vio.txt", "truth": "b_truth.txt"},
        {"name": "c", "role": "heldout", "vio": "c_vio.txt", "truth": "c_truth.txt"},
    ],
    "ingest": {"dt": 0.1, "align": "none", "time_offset": 0.0},
    "fit": {"radius": 1.0, "figures": False},
    "synth": {"T": 6, "controllers": "single", "S": 0.01, "eps_e": 0.05},
    "evaluate": {},
    "report": False,
}
ALL = ["ingest/a", "ingest/b", "ingest/c", "fit", "synth", "evaluate"]


def _tum(path: Path, t: np.ndarray, p: np.ndarray) -> None:
    path.write_text(
        "".join(
            f"{a:.2f} {x:.6f} {y:.6f} {z:.6f} 0 0 0 1\n" for a, (x, y, z) in zip(t, p, strict=True)
        )
    )


def _flights(folder: Path) -> None:
    """Three 12 s circles (truth) and a biased, noisy copy of each (VIO), TUM text files."""
    t = np.arange(0, 1200) * 0.01
    w = 2 * np.pi / 5
    for i, name in enumerate("abc"):
        p = np.column_stack([np.cos(w * t) * (1 + 0.1 * i), np.sin(w * t), 1 + 0.05 * np.sin(t)])
        noise = np.random.default_rng(i).normal(0, 0.003, p.shape)
        _tum(folder / f"{name}_truth.txt", t, p)
        _tum(folder / f"{name}_vio.txt", t, p + 0.02 * np.sin(3 * t)[:, None] + noise)


def _config(folder: Path, **changes) -> Path:
    cfg = {**BASE, **changes}
    path = folder / "run.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


@pytest.fixture
def work(tmp_path: Path) -> Path:
    (tmp_path / "cfg").mkdir()
    _flights(tmp_path / "cfg")
    return tmp_path


def _plan(work: Path, **changes):
    path = _config(work / "cfg", **changes)
    return plan(load_run_config(path), path, work / "out")


def test_plan_orders_stages_and_wires_inputs(work, monkeypatch):
    monkeypatch.chdir(work)  # relative paths are the config folder's, not the cwd's
    g = _plan(work)
    assert g.ids == ALL
    by = {s.id: s for s in g.stages}
    assert [by[i].kind for i in ALL] == ["ingest", "ingest", "ingest", "fit", "synth", "evaluate"]
    assert by["fit"].deps == ("ingest/a", "ingest/b")  # training flights only
    assert by["synth"].deps == ("fit",)
    assert by["evaluate"].deps == ("fit", "synth", "ingest/c")
    assert by["ingest/a"].external == (
        (work / "cfg" / "a_vio.txt").resolve(),
        (work / "cfg" / "a_truth.txt").resolve(),
    )
    assert by["synth"].options.T == 6 and by["fit"].options.radius == 1.0
    assert g.downstream(["ingest/c"]) == {"ingest/c", "evaluate"}
    assert g.downstream(["ingest/a"]) == {"ingest/a", "fit", "synth", "evaluate"}

    # sweep sits between fit and synth; `fly` without held-out flights: no bound check
    sweep = {"grid": {"S": [0.0, 0.01]}, "T": 6, "eps_e": 0.05, "jobs": 1}
    flights = BASE["flights"][:2]
    g2 = _plan(work, sweep=sweep, flights=flights, evaluate=None, fly={"seeds": [0]})
    assert g2.ids == ["ingest/a", "ingest/b", "fit", "sweep", "synth", "fly"]
    fly = g2.stages[-1]
    assert (fly.kind, fly.deps) == ("fly", ("fit", "synth"))
    assert _plan(work, stages=["ingest", "fit"]).ids == ALL[:4]
    assert _plan(work, stages=["ingest"]).ids == ALL[:3]


def test_cache_keys_move_exactly_downstream_of_a_change(work):
    k0 = _plan(work).keys()
    assert len(set(k0.values())) == len(ALL)
    k1 = _plan(work, synth={**BASE["synth"], "T": 7}).keys()
    assert [s for s in ALL if k1[s] != k0[s]] == ["synth", "evaluate"]
    k2 = _plan(work, fit={**BASE["fit"], "radius": 0.8}).keys()
    assert [s for s in ALL if k2[s] != k0[s]] == ["fit", "synth", "evaluate"]
    k3 = _plan(work, ingest={**BASE["ingest"], "dt": 0.05}).keys()
    assert [s for s in ALL if k3[s] != k0[s]] == ALL
    # the content of an input file: a held-out flight's moves only its ingest and evaluate
    f = work / "cfg" / "c_vio.txt"
    f.write_text(f.read_text().replace("0.00 ", "0.000 ", 1))
    k4 = _plan(work).keys()
    assert [s for s in ALL if k4[s] != k0[s]] == ["ingest/c", "evaluate"]
    f = work / "cfg" / "b_truth.txt"
    f.write_text(f.read_text() + "12.00 1.0 0.0 1.0 0 0 0 1\n")
    k5 = _plan(work).keys()
    assert [s for s in ALL if k5[s] != k4[s]] == ["ingest/b", "fit", "synth", "evaluate"]


def _ran(result) -> list[str]:
    return [o.id for o in result.outcomes if o.status == "ran"]


def test_run_caches_and_reruns_what_changed(work):
    out = work / "out"
    path = _config(work / "cfg")
    events: list[tuple] = []
    r1 = run(path, out=out, on_stage=lambda *a: events.append(a))
    assert _ran(r1) == ALL
    assert [e[:2] for e in events if e[1] == "ran"] == [(s, "ran") for s in ALL]
    assert all(e[4] == "not run yet" for e in events if e[1] == "ran")
    assert r1.summary() == {
        "run folder": str(out),
        "stages run": 6,
        "stages up to date (skipped)": 0,
    }
    info = json.loads((out / "run.json").read_text())
    assert info["config_sha256"] == sha256_file(path) and info["stages"] == ALL
    state = json.loads((out / "run_state.json").read_text())["stages"]
    assert state["fit"]["key"] == r1.outcomes[3].key
    assert state["fit"]["files"]["error_model.yaml"]["sha256"] == sha256_file(
        out / "fit" / "error_model.yaml"
    )
    em = (out / "fit" / "error_model.yaml").read_bytes()
    cert = (out / "synth" / "l1_robust" / "certificate.yaml").read_bytes()

    assert _ran(run(path, out=out)) == []
    (out / "fit" / "error_model.yaml").unlink()
    r = run(path, out=out)
    assert _ran(r) == ["fit", "synth", "evaluate"]
    why = {o.id: o.reason for o in r.outcomes if o.status == "ran"}
    assert why == {
        "fit": "output error_model.yaml is missing",
        "synth": "fit ran",
        "evaluate": "fit ran",
    }
    # determinism: the same inputs give the same bytes
    assert (out / "fit" / "error_model.yaml").read_bytes() == em
    assert (out / "synth" / "l1_robust" / "certificate.yaml").read_bytes() == cert

    path = _config(work / "cfg", synth={**BASE["synth"], "T": 7})
    r = run(path, out=out)
    assert _ran(r) == ["synth", "evaluate"]
    assert r.outcomes[4].reason == "its options or inputs changed"
    assert "T: 7" in (out / "synth" / "l1_robust" / "certificate.yaml").read_text()
    assert _ran(run(path, out=out, from_stage="synth")) == ["synth", "evaluate"]
    assert _ran(run(path, out=out, from_stage="ingest")) == ALL
    assert _ran(run(path, out=out, force=True)) == ALL
    with pytest.raises(ConfigError, match="--from bogus: not a stage"):
        run(path, out=out, from_stage="bogus")
    with pytest.raises(ConfigError, match="--from sweep: this run has no such stage"):
        run(path, out=out, from_stage="sweep")
    assert _ran(run(path, out=out)) == []


@pytest.mark.parametrize(
    ("changes", "words"),
    [
        (
            {"flights": [{"name": "../x", "vio": "a_vio.txt", "truth": "a_truth.txt"}]},
            "plain folder name",
        ),
        (
            {"flights": [{"name": "a", "vio": "nope.txt", "truth": "a_truth.txt"}]},
            "nope.txt does not exist",
        ),
        ({"flights": [{"name": "a"}]}, "give 'simulate', 'sources' or 'vio' and 'truth'"),
        (
            {"flights": [{**BASE["flights"][2]}]},
            "the fit needs at least one flight with role 'train'",
        ),
        ({"flights": []}, "a run needs at least one flight"),
        ({"synth": {"T": 6, "S_": 0.1}}, "unknown option 'S_'"),
        ({"fit": {"radius": -1}}, "fit: 'radius'"),
        (
            {"flights": [{"name": "s", "simulate": {"duration": 5}}], "stages": ["ingest", "fit"]},
            "leave out simulate",
        ),
    ],
)
def test_bad_config_is_refused_before_anything_is_written(work, changes, words):
    path = _config(work / "cfg", **changes)
    with pytest.raises(ConfigError, match=None) as exc:
        run(path, out=work / "out")
    assert words in str(exc.value), str(exc.value)
    assert "\n" not in str(exc.value)
    assert not (work / "out").exists()

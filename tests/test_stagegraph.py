"""The cached stage graph: skip what is up to date, rerun exactly what is downstream of a change."""

from __future__ import annotations

import pytest

from qsls.pipeline.core.artifacts import StageWriter
from qsls.pipeline.run.graph import Stage, StageGraph


def _graph(root, calls, opts):
    def make(name):
        def execute(out, deps):
            calls.append(name)
            text = opts[name] + "".join((d / "value.txt").read_text() for d in deps.values())
            if opts.get("fail") == name:
                with StageWriter(out, name, force=True) as w:
                    w.write_text("value.txt", text)
                    raise KeyboardInterrupt  # killed mid-way
            with StageWriter(out, name, options={"v": opts[name]}, force=True) as w:
                w.write_text("value.txt", text)

        return execute

    g = StageGraph(root)
    g.add(Stage("a", "a", {"v": opts["a"]}, make("a")))
    g.add(Stage("b", "b", {"v": opts["b"]}, make("b"), deps=("a",)))
    g.add(Stage("c", "c", {"v": opts["c"]}, make("c")))
    g.add(Stage("d", "d", {"v": opts["d"]}, make("d"), deps=("b", "c")))
    return g


def test_rerun_skips_and_change_reruns_downstream_only(tmp_path):
    opts = {"a": "1", "b": "2", "c": "3", "d": "4"}
    calls: list[str] = []
    _graph(tmp_path, calls, opts).run()
    assert calls == ["a", "b", "c", "d"]
    assert (tmp_path / "d" / "value.txt").read_text() == "4" + "21" + "3"

    calls.clear()
    outcomes = _graph(tmp_path, calls, opts).run()
    assert calls == [] and {o.status for o in outcomes} == {"skipped"}

    calls.clear()
    opts["b"] = "X"
    _graph(tmp_path, calls, opts).run()
    assert calls == ["b", "d"]
    assert (tmp_path / "d" / "value.txt").read_text() == "4X13"

    calls.clear()
    _graph(tmp_path, calls, opts).run(from_kind="c")
    assert calls == ["c", "d"]
    calls.clear()
    _graph(tmp_path, calls, opts).run(force=True)
    assert calls == ["a", "b", "c", "d"]


def test_interrupted_stage_leaves_nothing_and_next_run_resumes(tmp_path):
    opts = {"a": "1", "b": "2", "c": "3", "d": "4", "fail": "c"}
    calls: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        _graph(tmp_path, calls, opts).run()
    assert calls == ["a", "b", "c"]
    assert not (tmp_path / "c").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".c.tmp")]
    calls.clear()
    del opts["fail"]
    _graph(tmp_path, calls, opts).run()
    assert calls == ["c", "d"]

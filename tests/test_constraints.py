"""constraints.txt (issue 50): every requirement of qsls and its [test] extra is pinned, each
pin within pyproject.toml's bounds, one pin a package; CI keeps testing the newest releases
(.ci/run never reads it)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[1]


def pins() -> dict[str, str]:
    out: dict[str, str] = {}
    for line in (REPO / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        name, _, version = line.partition("==")
        assert version, f"not a pin: {line!r}"
        key = canonicalize_name(name)
        assert key not in out, f"{name} pinned twice"
        out[key] = version
    return out


def test_every_requirement_is_pinned_within_its_bounds():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    pinned = pins()
    for text in [*project["dependencies"], *project["optional-dependencies"]["test"]]:
        req = Requirement(text)
        key = canonicalize_name(req.name)
        assert key in pinned, f"{req.name} is not in constraints.txt"
        assert req.specifier.contains(pinned[key], prereleases=True), (text, pinned[key])


def test_ci_tests_the_newest_releases():
    assert "constraints" not in (REPO / ".ci" / "run").read_text()

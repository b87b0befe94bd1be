"""The README's pure-API example runs as printed: objects in memory, nothing read or written,
and it prints what the README says it prints."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
SECTION = "## The library, without files"


def _example() -> tuple[str, str]:
    """The section's python block and the output its prose promises."""
    text = README.read_text()
    section = text[text.index(SECTION) :]
    section = section[: section.index("\n## ", len(SECTION))]
    code = re.search(r"```python\n(.*?)```", section, re.S)
    said = re.search(r"it prints\s+`([^`]+)`", section)
    assert code is not None and said is not None
    return code.group(1), said.group(1)


def test_readme_pure_api_example_runs_and_prints_what_it_says(tmp_path):
    code, said = _example()
    assert len([ln for ln in code.splitlines() if ln.strip()]) <= 16  # a short example
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout.strip()
    assert out == said
    status, eps, _s, gamma = re.fullmatch(
        r"(\w+) eps=([0-9.]+) S=([0-9.]+) gamma=([0-9.]+)", out
    ).groups()  # type: ignore[union-attr]
    assert status == "relaxed" and 0 < float(eps) < float(gamma)  # not calibrated
    assert list(tmp_path.iterdir()) == []  # no file written

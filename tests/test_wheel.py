"""The wheel ships every package: packages are found, not listed (setup.py), so a new subpackage
cannot silently stay out of it. Built with pip as a user would, imported without the editable
install (``python -S``: no site hooks, dependencies from site-packages only)."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _source_packages() -> list[str]:
    return sorted(
        "qsls." + ".".join(init.parent.relative_to(ROOT).parts)
        for top in ("cli", "pipeline")
        for init in (ROOT / top).rglob("__init__.py")
        if "__pycache__" not in init.parts
    )


@pytest.mark.slow
def test_wheel_holds_and_imports_every_subpackage(tmp_path):
    import shutil

    # built from a copy: setuptools writes build/ beside the sources, never in the checkout
    src = tmp_path / "src"
    skip = (".venv", ".git", "build", "*.egg-info", "__pycache__", "runs", "reports", "benchmarks")
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(*skip))
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(src)],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = tmp_path.glob("qsls-*.whl")
    unpacked = tmp_path / "unpacked"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(unpacked)
        names = set(z.namelist())
    packages = _source_packages()
    assert {"qsls.pipeline.core", "qsls.pipeline.control", "qsls.pipeline.ingest.sources"} <= set(
        packages
    )
    missing = [p for p in packages if p.replace(".", "/") + "/__init__.py" not in names]
    assert not missing, f"packages missing from the wheel: {missing}"
    # every module of the wheel imports from the wheel itself
    modules = sorted(
        n[:-3].replace("/", ".").removesuffix(".__init__")
        for n in names
        if n.startswith("qsls/") and n.endswith(".py")
    )
    code = (
        "import importlib, sys\n"
        f"sys.path[:0] = [{str(unpacked)!r}, {sysconfig.get_paths()['purelib']!r}]\n"
        f"for m in {modules!r}:\n"
        "    mod = importlib.import_module(m)\n"
        f"    assert mod.__file__.startswith({str(unpacked)!r}), (m, mod.__file__)\n"
        "print(len(" + repr(modules) + "))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    run = subprocess.run(
        [sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert int(run.stdout.strip()) == len(modules) > 40

"""Packages are found, not listed: every folder with an ``__init__.py`` under ``cli/`` and
``pipeline/`` ships as ``qsls.<dotted path>`` (``package-dir`` in pyproject.toml maps them)."""

from setuptools import find_packages, setup

setup(packages=[f"qsls.{p}" for p in find_packages(include=["cli", "cli.*", "pipeline", "pipeline.*"])])

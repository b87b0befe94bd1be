"""The figures the README and docs/calibration.md state for the quickstart come from the code:
each is compared with the quickstart run's own certificate (tests/conftest.py's session run),
rounded as written, so a change that moves a documented figure fails here until the text is
regenerated from the run (issue 50). The figures of the long configs (paper_sim,
paper_sim_camera) are in their runs' own files: fly/comparison.md, calibrate/calibration.json;
constraints.txt names the versions that reproduce them."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
CERT = "runs/quickstart/calibrate/regular/l1_robust/certificate.yaml"
MACHINE = {"checks", "controller_sha256"}  # solver residuals and hashes: not figures


def as_written(actual: float, doc: float, text: str) -> bool:
    """``actual`` rounded to the significant digits ``text`` shows equals ``doc``."""
    if isinstance(doc, int) and "." not in text and "e" not in text.lower():
        return actual == doc
    digits = len(re.sub(r"[^0-9]", "", text.split("e")[0].lstrip("0.").lstrip("-")))
    if doc == 0:
        return abs(actual) < 0.5 * 10 ** -(len(text.split(".")[-1]) if "." in text else 0)
    scale = 10 ** (math.floor(math.log10(abs(actual))) - digits + 1) if actual else 1
    return math.isclose(round(actual / scale) * scale, doc, rel_tol=1e-9, abs_tol=1e-12)


def numbers(doc: Any, run: Any, path: str = "") -> list[str]:
    """Every documented number that differs from the run's, as ``path: doc != run`` (the
    digits shown are the number's as YAML read it: ``repr`` gives back what was typed)."""
    bad = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            if k in MACHINE or not isinstance(run, dict) or k not in run:
                continue
            bad += numbers(v, run[k], f"{path}.{k}" if path else str(k))
    elif (
        isinstance(doc, int | float)
        and not isinstance(doc, bool)
        and (not isinstance(run, int | float) or not as_written(float(run), doc, repr(doc)))
    ):
        bad.append(f"{path}: documented {doc}, the run's {run}")
    return bad


def readme_certificate() -> tuple[dict[str, Any], str]:
    text = (REPO / "README.md").read_text()
    block = text.split("## Reading a certificate")[1].split("```yaml\n")[1].split("```")[0]
    return yaml.safe_load(block), block


def test_the_readmes_certificate_is_the_quickstarts(quickstart_session):
    work = quickstart_session[0]
    run = yaml.safe_load((work / CERT).read_text())
    doc, _ = readme_certificate()
    bad = numbers(doc, run)
    assert bad == [], "README.md's certificate differs from the quickstart's:\n" + "\n".join(bad)


def test_calibration_docs_quickstart_figures_are_the_runs(quickstart_session):
    work = quickstart_session[0]
    run = yaml.safe_load((work / CERT).read_text())
    cal = run["calibration"]
    text = (REPO / "docs/calibration.md").read_text()
    section = text.split("## Measured on the quickstart")[1].split("\n## ")[0]
    rows = {r.split("|")[1].strip(): [c.strip() for c in r.split("|")[2:-1]]
            for r in section.splitlines() if r.startswith("| `")}  # fmt: skip
    lam = re.search(r"calibrated \(x ([0-9.]+)\)", section).group(1)
    assert as_written(cal["lambda_hat"], float(lam), lam)
    want = {  # row: (design premise, largest ratio, calibrated, tolerance)
        "`eps` (dense)": (cal["nominal"]["eps_e"], cal["parts"]["dense"], run["eps_e"],
                          cal["tolerances"]["eps"]),
        "`eps_w`": (cal["nominal"]["eps_w"], cal["parts"]["disturbance"], run["eps_w"],
                    cal["tolerances"]["eps_w"]),
        "`Delta` (reference)": (cal["nominal"]["delta"], cal["parts"]["reference"], run["delta"],
                                cal["tolerances"]["delta"]),
    }  # fmt: skip
    bad = []
    for name, values in want.items():
        for cell, actual in zip(rows[name], values, strict=True):
            if not as_written(float(actual), float(cell), cell):
                bad.append(f"{name}: documented {cell}, the run's {actual}")
    said = re.search(
        r"`lhs` ([0-9.]+), `rho\*` ([0-9.]+) <= `r`\s+[0-9.]+ and `rho_v` ([0-9.]+) <= the gate "
        r"[0-9.]+; the flights reached ([0-9.]+)",
        section,
    )
    for text_, actual in zip(said.groups(), (run["robustness_lhs"], run["rho_star"],
                                             run["rho_v"], run["tested_range"]), strict=True):  # fmt: skip
        if not as_written(actual, float(text_), text_):
            bad.append(f"sentence: documented {text_}, the run's {actual}")
    family = text.split("The quickstart calibrates over its stated family and is certified")[1][:80]
    lam2, rho2, tested2 = re.search(
        r"`lambda_hat` ([0-9.]+), `rho\*` ([0-9.]+),\s+tested to ([0-9.]+)", family
    ).groups()
    for text_, actual in ((lam2, cal["lambda_hat"]), (rho2, run["rho_star"]),
                          (tested2, run["tested_range"])):  # fmt: skip
        if not as_written(actual, float(text_), text_):
            bad.append(f"family paragraph: documented {text_}, the run's {actual}")
    assert bad == [], "docs/calibration.md differs from the quickstart's run:\n" + "\n".join(bad)

"""The evidence behind the summary, one section per question, each a few narrow tables
(at most about 8 columns, long texts as notes, full data as CSV beside the report) and the
figures that go with it.

Order: the paper's figures, certificates (:mod:`qsls.pipeline.report.certificates`), the
bound check on held-out flights, the flown comparison and the paper's findings; then the error
model, the sweep, the flights.
"""

from __future__ import annotations

import re
from typing import Any

from qsls.pipeline.control.sweep import FEASIBILITY_FIGURE, S_MAX_FIGURE
from qsls.pipeline.errormodel.figures import (
    ERROR_NORM_FIGURE,
    SLOPE_DISTRIBUTION_FIGURE,
    WORST_PAIRS_FIGURE,
)
from qsls.pipeline.evaluate.figures import DISTANCE_FIGURE, PERCEPTION_ERROR_FIGURE
from qsls.pipeline.evaluate.verdict import ASSUMPTIONS_FILE
from qsls.pipeline.fly.figures import INPUT_FIGURES, tracking_file
from qsls.pipeline.report.document import Figure, Section, figure_of, stage_pngs
from qsls.pipeline.report.facts import Facts, findings_list, g4, interval_text


def _csv(sec: Section, name: str, df: Any) -> str:
    return sec.attach(name, df.to_csv(index=False, float_format="%.6g").encode())


def _slug(rel: str) -> str:
    return rel.replace("/", "_")


def _stage_figures(
    f: Facts, folder: str, counter: list[int], captions: dict[str, str], skip: tuple[str, ...] = ()
) -> list[Figure]:
    """Every PNG of a stage folder (those named in ``captions`` first, in that order)."""
    root = f.run_dir / folder
    pngs = [p for p in stage_pngs(root) if p.name not in skip]
    order = {name: i for i, name in enumerate(captions)}
    pngs.sort(key=lambda p: (order.get(p.name, len(order)), p.relative_to(root).as_posix()))
    return [
        figure_of(f.run_dir, p, captions.get(p.name, f"{folder}/{p.name}"), counter) for p in pngs
    ]


# --------------------------------------------------------------------------- paper figures
PAPER_FIGURES = {
    tracking_file("regular"): "Tracking (paper, Fig. pos_tracking): regular perception, top view",
    tracking_file("degraded"): "Tracking: degraded perception, top view",
    PERCEPTION_ERROR_FIGURE: "Perception error ||e|| against each controller's bound "
    "(paper, Fig. est_err), per condition",
}


def _paper_files(root: Any) -> tuple[str, ...]:
    return (*PAPER_FIGURES, *sorted(p.name for p in root.glob(INPUT_FIGURES)))


def section_paper_figures(f: Facts, counter: list[int]) -> Section | None:
    if not f.fly_folder:
        return None
    root = f.run_dir / f.fly_folder
    sec = Section("The paper's figures", id="figures")
    names = [n for n in PAPER_FIGURES if (root / n).is_file()]
    inputs = sorted(p.name for p in root.glob(INPUT_FIGURES))
    caps = dict(PAPER_FIGURES)
    for n in inputs:
        caps[n] = "Input (paper, Fig. u_L1_pd): the robust controller's command against what PD "
        caps[n] += "commands from the same estimate"
    order = names[:2] + inputs + names[2:]
    sec.figures([figure_of(f.run_dir, root / n, caps[n], counter) for n in order])
    sec.text(
        f"Flown by qsls in simulation ({f.fly_folder}); one colour per controller in every "
        "figure. Diagnostic figures follow the sections they belong to."
    )
    return sec


# --------------------------------------------------------------------------- bound check
def _note_index(notes: list[str], text: str) -> int:
    if text not in notes:
        notes.append(text)
    return notes.index(text) + 1


def _theorem_row(r: Any, text: str, n: int) -> list[Any]:
    """A bound-check row with the theorem's columns: the verdict's first word (``holds``,
    ``FAILS``, ``premise only``, ``no bound``) and its note."""
    word = re.split(r"[:;(]", text)[0].strip() or "-"
    if r.get("has_guarantee", True) is False and word in ("holds", "FAILS"):
        word = f"{word} (no guarantee)"
    ratio = r.get("nominal_ratio")
    return [
        f"{r['flight']} ({r.get('flown_by') or 'recorded'})",
        r["controller"],
        r.get("max_error_norm"),
        f"{g4(r.get('a_nominal'))} / {g4(r.get('a_certificate'))}",
        r.get("gamma_nominal"),
        ratio,
        r.get("frac_premise_holds"),
        f"{word} [{n}]" if n else word,
    ]


def _per_sample_row(r: Any, text: str, n: int) -> list[Any]:
    """A bound-check row of a table written before the theorem columns existed."""
    word = text.split(";")[0].strip() or "-"
    if "bound_holds" in r and r.get("has_guarantee", True) is False:
        word = f"{word} (no guarantee)"
    return [
        r["flight"],
        r["controller"],
        r.get("flown_by") or "(recorded)",
        r.get("max_error_norm"),
        r.get("gamma"),
        r.get("max_ratio"),
        r.get("frac_premise_holds"),
        f"{word} [{n}]" if n else word,
    ]


def section_heldout(f: Facts, counter: list[int]) -> Section | None:
    if not f.evaluations:
        return None
    sec = Section("Bound check", id="heldout")
    for ev in f.evaluations:
        t = ev.table
        if not len(t):
            continue
        theorem = "gamma_nominal" in t
        rows: list[list[Any]] = []
        notes: list[str] = []
        for _, r in t.iterrows():
            text = str(r.get("verdict", ""))
            n = _note_index(notes, text) if text else 0
            rows.append(_theorem_row(r, text, n) if theorem else _per_sample_row(r, text, n))
        what = "gamma_nominal (the theorem on the flight)" if theorem else "gamma(d) per sample"
        csv = _csv(sec, f"bound_check_{_slug(ev.folder)}.csv", t)
        scope = (
            "flights flown by the controllers" if ev.kind == "fly" else "recorded held-out flights"
        )
        head = (
            ["flight (flown by)", "controller", "max ||e||", "a_nominal / certificate's a",
             "gamma_nominal", "max ||e|| / gamma_nominal", "premise holds (share)",
             "verdict [note]"]
            if theorem
            else ["flight", "controller", "flown by", "max ||e||", "gamma",
                  "max ||e|| / gamma", "premise holds (share)", "verdict [note]"]
        )  # fmt: skip
        sec.table(
            head,
            rows,
            f"{ev.folder}: {scope}, ||e|| against {what}",
            notes=notes,
            csv=csv,
            text_cols=[1, 3, 7] if theorem else [1, 2, 7],
        )
        if theorem:
            sec.text(
                "On a flight the controller flew itself, x = x_hat + Phi_xy * e: a_nominal is "
                "how far x_hat (the flight without perception error) strayed from the training "
                "data, and gamma_nominal = (eps_e + S a_nominal) / (1 - S ||Phi_xy||) is the "
                "theorem's bound on that flight; the certificate bounds a a priori by "
                "eps_w ||Phi_xx H|| + Delta. Other rows check the premise only."
            )
        else:
            sec.text(
                "The per-sample check compares ||e_k|| with gamma evaluated at the flown state's "
                "distance to the training data; it holds wherever the premise holds, so it tests "
                "the error model rather than the controller. The theorem applies to a flight "
                "flown by the certified controller itself."
            )
        figs = _stage_figures(
            f,
            ev.folder,
            counter,
            {
                PERCEPTION_ERROR_FIGURE: f"{ev.folder}: ||e|| per flight against each bound",
                DISTANCE_FIGURE: f"{ev.folder}: distance of the flown state to the "
                "training data (diagnostic)",
            },
            skip=_paper_files(f.run_dir / ev.folder) if ev.kind == "fly" else (),
        )
        sec.figures(figs)
    return sec


# --------------------------------------------------------------------------- flown
def section_flown(f: Facts, counter: list[int]) -> Section | None:
    pc = f.per_controller
    items = findings_list(f)
    if pc is None and not items:
        return None
    sec = Section("Findings and flown comparison", id="findings")
    if items:
        rows: list[list[Any]] = []
        notes: list[str] = []
        for it in items:
            ci = it.get("ci")
            eff = g4(it["effect"]) if it.get("effect") is not None else "-"
            if it.get("effect") is not None:
                iv = interval_text(ci, it.get("n_seeds"))
                eff += f" [{iv.replace(' to ', ', ')}]" if " to " in iv else f" ({iv})"
            n = _note_index(notes, it["detail"]) if it["detail"] else 0
            rows.append([it["id"], it["claim"], it["verdict"], eff, f"[{n}]" if n else "-"])
        sec.table(
            ["#", "the paper's finding", "verdict", "effect [95% CI]", "qsls"],
            rows,
            "Against the paper's findings (details in the notes)",
            notes=notes,
            wrap_cols=[1],
            text_cols=[2],
        )
    _mechanism_table(f, sec)
    if pc is not None and len(pc):
        cols = [
            ("condition", "condition"),
            ("controller", "controller"),
            ("tracking_rms_m", "tracking RMS (m)"),
            ("tracking_max_m", "tracking max (m)"),
            ("perception_error_rms", "||e|| RMS"),
            ("perception_error_max", "||e|| max"),
            ("reaction_vs_pd", "feedback command vs PD on its estimate (< 1: softer)"),
            ("smoothness_vs_pd", "input roughness vs PD (1 = PD)"),
            ("crashed", "crashed"),
        ]
        cols = [(k, h) for k, h in cols if k in pc]
        if "reaction_vs_pd" in pc:  # softness (finding 4) in its place; roughness in the CSV
            cols = [(k, h) for k, h in cols if k != "smoothness_vs_pd"]
        csv = _csv(sec, f"per_controller_{_slug(f.fly_folder)}.csv", pc)
        sec.table(
            [h for _, h in cols],
            pc[[k for k, _ in cols]].to_numpy().tolist(),
            "How the controllers flew (mean over seeds; ||e|| in the state's units, inf norm)",
            csv=csv,
            text_cols=[0, 1],
        )
    _assumptions_table(f, sec)
    return sec


MECHANISM_COLUMNS = {
    "norm_phi_xe": "gain error to state ||Phi_xe||",
    "norm_phi_ue": "gain error to input ||Phi_ue||",
    "reaction_vs_pd_circle": "feedback command vs PD (circle)",
    "angular_rate_rms": "body rate RMS (rad/s)",
    "blur_px_mean": "blur (px)",
    "features_per_frame": "features / frame",
    "perception_error_rms_circle": "||e|| RMS (circle)",
}


def _mechanism_table(f: Facts, sec: Section) -> None:
    """What drives the findings, measured per controller and condition (``findings.json``'s
    ``mechanism``): the gains from perception error to state and input, the reaction against
    PD's, the body rate, the blur and features of the estimator that flew, the error."""
    rows = f.findings.get("mechanism") or []
    if not rows:
        return
    keys = [k for k in MECHANISM_COLUMNS if any(r.get(k) is not None for r in rows)]
    est = f.findings.get("estimator") or f.findings.get("estimator_flown") or "the estimator"
    sec.table(
        ["controller", "condition", *(MECHANISM_COLUMNS[k] for k in keys)],
        [[r["controller"], r["condition"], *(r.get(k) if r.get(k) is not None else "-"
          for k in keys)] for r in rows],
        f"The mechanism, measured ({est}'s flights; blur and features from the estimator that "
        "flew, means over seeds)",
        text_cols=[0, 1],
    )  # fmt: skip


def _assumptions_table(f: Facts, sec: Section) -> None:
    """Every assumption of the guarantee on each certified controller's own flights (the
    fly stage's ``assumptions.parquet``): the value against its limit, the first to fail."""
    import pandas as pd

    path = f.run_dir / f.fly_folder / ASSUMPTIONS_FILE if f.fly_folder else None
    if path is None or not path.is_file():
        return
    a = pd.read_parquet(path)
    if not len(a):
        return
    names = ("disturbance", "nominal", "invariance", "dense", "outliers")
    rows = [
        [r["flight"], *(f"{r[f'{n}_value']:.3g} / {r[f'{n}_limit']:.3g}" for n in names),
         r["first_failed"] or "none", "held" if r["bound_held"] else "NOT held"]
        for _, r in a.iterrows()
    ]  # fmt: skip
    sec.table(
        ["flight", "||H^-1 w|| / eps_w", "dist(x_hat) / a", "dist(x) / rho*",
         "dense error above eps_e + S dist", "outliers per T steps / m", "first to fail",
         "bound (consequence)"],
        rows,
        "The guarantee's assumptions on each certified controller's own flights, from its own "
        "log (docs/guarantee.md): a flight is inside the guarantee only if none fails",
        text_cols=[0, 6, 7],
    )  # fmt: skip


# --------------------------------------------------------------------------- error model
def section_error_model(f: Facts, counter: list[int]) -> Section | None:
    em = f.error_model
    if not em:
        return None
    sec = Section("Error model", id="error-model")
    slope = em.get("s_slope") or {}
    rows = [["max", em.get("eps_e"), slope.get("max"), "-"]]
    for key in sorted(slope.get("percentiles") or {}, key=lambda k: float(k[1:])):
        rows.append(
            [
                key,
                (em.get("eps_e_percentiles") or {}).get(key),
                slope["percentiles"][key],
                (slope.get("local_max_percentiles") or {}).get(key),
            ]
        )
    sec.table(
        ["statistic", "eps_e = ||e||_inf", "S over pairs", "S, largest per sample"],
        rows,
        f"{f.error_model_folder}: {em.get('n_samples')} samples, {em.get('n_pairs')} pairs within "
        f"radius r = {g4(em.get('radius'))}; R0 {g4(em.get('R0'))}, Delta {g4(em.get('delta'))}",
        text_cols=[0],
    )
    if rule := em.get("min_separation_rule"):
        sec.text(f"Pairs closer than {g4(em.get('min_separation'))} are left out ({rule}).")
    worst = (em.get("worst_pairs") or [])[:10]
    if worst:
        sec.table(
            ["slope", "distance", "flight", "t_i (s)", "t_j (s)", "||e_i||", "||e_j||"],
            [
                [
                    w.get("slope"),
                    w.get("distance"),
                    w.get("flight"),
                    w.get("t_i"),
                    w.get("t_j"),
                    max(abs(v) for v in w.get("e_i") or [0]),
                    max(abs(v) for v in w.get("e_j") or [0]),
                ]
                for w in worst
            ],
            "The pairs that set the largest S-slopes (where the measurements are at fault)",
            text_cols=[2],
        )
    sec.figures(
        _stage_figures(
            f,
            f.error_model_folder,
            counter,
            {
                SLOPE_DISTRIBUTION_FIGURE: "Distribution of the S-slopes over pairs",
                ERROR_NORM_FIGURE: "||e|| over time per training flight, with eps_e",
                WORST_PAIRS_FIGURE: "The worst pairs on the trajectory",
            },
        )
    )
    return sec


# --------------------------------------------------------------------------- sweep
def section_sweep(f: Facts, counter: list[int]) -> Section | None:
    folders = f.stages.get("sweep", [])
    if not folders:
        return None
    sec = Section("Sweep", id="sweep")
    sw, sm = f.sweep, f.s_max
    if sm is not None and len(sm):
        cols = [("T", "T (steps)"), ("eps_e", "eps_e"), ("radius", "r"), ("delta", "Delta"),
                ("eps_w", "eps_w"), ("s_max", "largest feasible S"),
                ("min_norm_phi_xy", "min ||Phi_xy||")]  # fmt: skip
        cols = [(k, h) for k, h in cols if k in sm]
        sec.table(
            [h for _, h in cols],
            sm[[k for k, _ in cols]].to_numpy().tolist(),
            "Largest feasible S against T (bisection); S + eps_e/r <= 1/min ||Phi_xy|| is "
            "necessary",
        )
    if sw is not None and len(sw):
        s_col = "S_value" if "S_value" in sw else "S"
        keys = [k for k in ("S", s_col, "T") if k in sw]
        keys = list(dict.fromkeys(keys))
        grouped = sw.groupby(keys, sort=True)
        rows = [
            [*(k if isinstance(k, tuple) else (k,)), int(g["feasible"].sum()), len(g),
             g["gamma"].min() if "gamma" in g else None]
            for k, g in grouped
        ]  # fmt: skip
        if s_col in keys:
            rows.sort(key=lambda r: (r[keys.index(s_col)], *r[len(keys) - 1 : len(keys)]))
        heads = {"S": "S", "S_value": "S value", "T": "T (steps)"}
        csv = _csv(sec, "sweep.csv", sw)
        sec.table(
            [*(heads[k] for k in keys), "feasible", "points", "smallest gamma"],
            rows,
            f"{len(sw)} grid points, {int(sw['feasible'].sum())} feasible",
            csv=csv,
            text_cols=[0],
        )
    sec.figures(
        _stage_figures(
            f,
            f.rel(folders[0]),
            counter,
            {
                S_MAX_FIGURE: "Largest feasible S against the horizon T",
                FEASIBILITY_FIGURE: "Feasible fraction over the grid",
            },
        )
    )
    return sec

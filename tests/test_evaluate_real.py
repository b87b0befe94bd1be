"""The bound check on real EuRoC flights (../shared/data/real; skipped when absent).

Train on one estimator's V1_02 flight, hold out another estimator's V1_02 flight (same room,
same kind of motion) and a machine-hall flight (MH_04: another place), all through the
real ingest, fit and synth stages.
"""

from __future__ import annotations

import numpy as np
import pytest

from qsls.pipeline.control.synth import SynthOptions, synth
from qsls.pipeline.errormodel.fit import FitOptions, fit
from qsls.pipeline.evaluate.options import EvaluateOptions
from qsls.pipeline.evaluate.stage import evaluate
from qsls.pipeline.ingest.flight import X_COLS, read_flight
from qsls.pipeline.ingest.stage import IngestOptions, ingest


@pytest.mark.real
def test_bound_check_on_euroc(real_data, tmp_path):
    def ing(name, truth):
        d = real_data / name
        opts = IngestOptions(vio=d / "estimate_tum.txt", truth=d / truth)
        ingest([], opts, tmp_path / name)
        return tmp_path / name

    train = ing("euroc_v102_rpg", "groundtruth_tum.txt")
    same_room = ing("euroc_v102", "groundtruth.csv")
    hall = ing("euroc_mh04_rpg", "groundtruth_tum.txt")
    fit([train], FitOptions(radius=1.0, figures=False), tmp_path / "fit")
    synth(tmp_path / "fit", SynthOptions(T=12, S="p50", eps_e="p95", controllers="single"),
          tmp_path / "synth")  # fmt: skip
    res = evaluate([same_room, hall], tmp_path / "fit", [tmp_path / "synth" / "l1_robust"],
                   EvaluateOptions(), tmp_path / "ev")  # fmt: skip
    t = res.table.set_index("flight")
    assert set(t.index) == {"euroc_v102", "euroc_mh04_rpg"}
    # independent check of the distance to the training data (brute force, inf norm)
    tr = read_flight(train)[list(X_COLS)].to_numpy()
    for name, folder in (("euroc_v102", same_room), ("euroc_mh04_rpg", hall)):
        x = read_flight(folder)[list(X_COLS)].to_numpy()
        x = x[np.isfinite(x).all(axis=1)]
        brute = np.abs(x[:, None, :] - tr[None]).max(axis=2).min(axis=1)
        assert t.loc[name, "max_distance_to_training"] == pytest.approx(brute.max(), rel=1e-9)
    # the same room stays closer to the training states than the machine hall
    assert (
        t.loc["euroc_v102", "mean_distance_to_training"]
        < t.loc["euroc_mh04_rpg", "mean_distance_to_training"]
    )
    for col in ("frac_under_gamma", "frac_under_gamma_strict"):
        assert ((t[col] >= 0) & (t[col] <= 1)).all()
    assert (tmp_path / "ev" / "perception_error.png").stat().st_size > 1000

"""IDIM-IV (issue 15, item 2): instruments from the simulated closed loop."""
from __future__ import annotations

import numpy as np

import identification


def test_idim_iv_on_the_paper_log(paper_log, truth):
    """The well-excited f within 3 %, the truth within 3 standard errors."""
    f_true = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    r = identification.identify(paper_log, method="idim-iv")
    well = [0, 1, 3, 5, 6, 8]
    rel = np.abs(r.f - f_true) / np.abs(f_true)
    assert np.all(rel[well] < 0.03), rel
    assert np.all(np.abs(r.f - f_true) <= 3 * r.f_std)
    assert r.method == "idim-iv" and r.settings["idim"]["iv_iterations"] > 0

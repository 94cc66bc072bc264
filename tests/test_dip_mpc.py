"""The dip-mpc experiment at tiny scale: it runs, its table has every cell, and the unconstrained-equivalent
controllers agree where the limit cannot bind."""

import numpy as np

from experiments.dip_mpc import EXPERIMENT, NAMES, DipMpcConfig


def test_dip_mpc_tiny_run():
    cfg = DipMpcConfig(seeds=4, duration=0.3, x0_scales=[0.5, 12.0], tune_steps=1, tune_seeds=2, tune_duration=0.1)
    out = EXPERIMENT.run(cfg, None, progress=False)
    table = out.results["table"]
    assert set(table) == {"x0.5", "x12"} and all(set(row) == set(NAMES) for row in table.values())
    # at half the eki-dip spread |u| stays far below 6 V: MPC is exactly the discrete LQR
    small = table["x0.5"]
    assert small["mpc"]["mean_abs_u"] < 3.0
    np.testing.assert_allclose(small["mpc"]["cost"], small["lqr_sat"]["cost"], rtol=1e-9)
    assert "which controller wins where" in out.report.lower()
    assert small["mpc"]["qp_unsolved_periods"] == 0 and "qp_unsolved_periods" not in small["lqr_sat"]

"""Roll and pitch are analysed: a second-order baseline on the free decays, and amplitude-dependent
(quadratic) roll damping named when the simulator carries it and not when it does not."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.diagnose import diagnose
from diagnose_synthetic import simulated_trial
from pipeline.sim import Effects
from pipeline.sim.manoeuvres import chain, free_decay
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
AAUSHIP = load_vessel(ROOT / "vessel_configs" / "aauship.toml")


def _decays():
    return chain(*(free_decay("roll", np.radians(a), 3.0) for a in (20, -15, 25, 10)),
                 *(free_decay("pitch", np.radians(a), 3.0) for a in (5, -4)), rest_s=2.0)


def test_quadratic_roll_damping_is_named(tmp_path):
    q = np.zeros(5)
    q[2] = 0.05  # kg m^2 (|p| p), beside K_p = 0.1094 kg m^2/s
    trial, _ = simulated_trial(AAUSHIP, _decays(), Effects(quadratic_damping=q), tmp_path, "rollq", seed=4)
    rep = diagnose(trial, AAUSHIP)
    assert {d.dof for d in rep.dofs} >= {"roll", "pitch"}
    assert (rep.effect, rep.dof) == ("nonlinear_damping", "roll"), [(c.label, c.dof, round(c.shrink, 1))
                                                                   for c in rep.candidates[:4]]
    v = rep.verdict
    assert v.shrink > 50 and v.params[0].name == "d2" and v.params[0].value > 0
    roll = next(d for d in rep.dofs if d.dof == "roll")
    omega = {p.name: p.value for p in roll.baseline}["omega_n"]
    # sqrt(C / I) of the config, the added mass being zero in aauship.toml
    assert abs(omega - np.sqrt(6.97 / 0.0654)) < 0.15 * np.sqrt(6.97 / 0.0654)


def test_linear_roll_gives_no_roll_verdict(tmp_path):
    trial, _ = simulated_trial(AAUSHIP, _decays(), Effects(), tmp_path, "rollclean", seed=5)
    rep = diagnose(trial, AAUSHIP)
    roll = [c for c in rep.candidates if c.dof in ("roll", "pitch")]
    assert roll and not any(c.significant for c in roll)
    assert rep.effects == ()


def test_roll_a_slow_log_cannot_resolve_is_not_analysed(tmp_path):
    # AAUSHIP's roll period is 0.6 s: a 5 Hz log has 3 samples per period. Not resolvable, so
    # neither a verdict nor an "unexplained" roll gap on clean data.
    import pandas as pd

    from pipeline.flow import load_trial

    _, path = simulated_trial(AAUSHIP, _decays(), Effects(), tmp_path, "roll5hz", seed=5)
    df = pd.read_csv(path)
    slow = tmp_path / "roll_5hz.csv"
    step = int(round(1.0 / (5.0 * float(np.median(np.diff(df["t"]))))))  # to 5 Hz
    df.iloc[::step].to_csv(slow, index=False)
    from pipeline.errors import DiagnoseError

    assert step >= 10
    try:
        rep = diagnose(load_trial([slow], AAUSHIP), AAUSHIP)
    except DiagnoseError as exc:
        # Decays only, none resolvable: nothing to analyse, said as such.
        assert "expected a DOF" in str(exc)
        return
    assert "roll" not in {d.dof for d in rep.dofs}
    assert not [u for u in rep.unexplained if u.dof == "roll"] and rep.effect is None

"""Forward selection, sensor-or-actuator delays and the unexplained gap, on a twin-thruster boat
whose surge and yaw are driven by the same two thrusters (so their inputs change together).

The trials are simulated here (first-order surge and yaw, Euler at the log rate), written as
canonical CSV and read back by ``load_trial``, so they are not made by the project's simulator.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from pipeline.cli import main
from pipeline.diagnose import diagnose
from pipeline.flow import load_trial


def twin_log(path, seed=1, gnss_lag=0.0, act_lag=0.0, quad_yaw=0.0, extra=None, fs=10.0, minutes=8.0):
    """Write a twin-thruster trial as canonical CSV: thrusts held 25 s at random levels, GNSS speed
    over ground (optionally ``gnss_lag`` s late), gyro and compass; returns the path."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * fs)
    t = np.arange(n) / fs
    hold = int(25 * fs)
    t1 = np.repeat(rng.uniform(2, 12, n // hold + 1), hold)[:n]
    t2 = np.repeat(rng.uniform(2, 12, n // hold + 1), hold)[:n]
    tau_x, tau_n = t1 + t2, 0.3 * (t1 - t2)
    al = int(round(act_lag * fs))
    tx = np.concatenate([np.full(al, tau_x[0]), tau_x[:n - al]]) if al else tau_x
    tn = np.concatenate([np.full(al, tau_n[0]), tau_n[:n - al]]) if al else tau_n
    u, r, psi = np.zeros(n), np.zeros(n), np.zeros(n)
    h = 1.0 / fs
    for k in range(n - 1):
        fr = -r[k] - quad_yaw * abs(r[k]) * r[k] + 0.05 * tn[k]
        if extra is not None:
            fr += extra(t[k])
        u[k + 1] = u[k] + h * (-u[k] + 0.08 * tx[k]) / 6.0
        r[k + 1] = r[k] + h * fr / 2.5
        psi[k + 1] = psi[k] + h * r[k]
    lag = int(round(gnss_lag * fs))
    sog = np.concatenate([np.full(lag, u[0]), u[:n - lag]]) if lag else u
    pd.DataFrame({"t": t, "sog": sog + 0.01 * rng.standard_normal(n), "r": r + 0.002 * rng.standard_normal(n),
                  "psi": np.angle(np.exp(1j * (psi + 0.003 * rng.standard_normal(n)))),
                  "tau_x": tau_x, "tau_n": tau_n}).to_csv(path, index=False)
    return path


def _report(tmp_path, name, **kw):
    return diagnose(load_trial([twin_log(tmp_path / f"{name}.csv", **kw)], None))


def test_clean_twin_is_model_fine(tmp_path):
    rep = _report(tmp_path, "clean")
    assert rep.effects == () and rep.unexplained == ()
    assert rep.status == "model fine"
    doc = rep.to_dict()
    assert doc["verdict"] == {"effect": None, "dof": None}
    assert doc["effects"] == [] and doc["unexplained"] == [] and doc["status"] == "model fine"
    assert "shrink" in doc["ranking_rule"] and doc["gap_final"] == pytest.approx(doc["gap_before"])


def test_gnss_lag_is_a_sensor_delay_not_an_actuator_delay(tmp_path):
    rep = _report(tmp_path, "gnss", gnss_lag=0.6)
    names = [(e.effect, e.dof, e.input_channel) for e in rep.effects]
    assert ("sensor_delay", "surge", "gnss") in names, names
    assert not any(e.effect == "actuator_delay" for e in rep.effects)
    e = next(e for e in rep.effects if e.effect == "sensor_delay")
    assert "yaw" in e.why and e.candidate == "actuator_delay"


@pytest.mark.slow  # 11-16 s on an idle core: run by make test-ci (make test stays under 5 min)
def test_actuator_lag_stays_an_actuator_delay(tmp_path):
    rep = _report(tmp_path, "act", act_lag=0.6)
    assert rep.effects and rep.effects[0].effect == "actuator_delay"
    assert not any(e.effect == "sensor_delay" for e in rep.effects)
    tau = next(p for p in rep.effects[0].params if p.name == "tau_d")
    assert abs(tau.value - 0.6) < 0.15


@pytest.mark.slow  # 11-16 s on an idle core: run by make test-ci (make test stays under 5 min)
def test_two_effects_in_two_dofs_are_both_selected(tmp_path):
    rep = _report(tmp_path, "two", act_lag=0.6, quad_yaw=8.0)
    effects = {(e.effect, e.dof) for e in rep.effects}
    assert ("actuator_delay", "surge") in effects and any(d == "yaw" for _, d in effects), effects
    assert rep.effects[0].step == 1 and [e.step for e in rep.effects] == list(range(1, len(rep.effects) + 1))
    # Each step shrinks the trial gap further, and the verdict is the first step.
    gaps = [rep.gap_before] + [e.trial_gap_after for e in rep.effects]
    assert all(b < a for a, b in zip(gaps, gaps[1:]))
    assert (rep.effect, rep.dof) == (rep.effects[0].effect, rep.effects[0].dof)
    assert rep.gap_final == pytest.approx(rep.effects[-1].trial_gap_after)


def test_out_of_library_disturbance_is_unexplained_and_printed_first(tmp_path, capsys):
    path = twin_log(tmp_path / "square.csv", extra=lambda t: 0.02 * np.sign(np.sin(2 * np.pi * t / 37.0)))
    toml = tmp_path / "boat.toml"
    toml.write_text('name = "twin"\n')
    out = tmp_path / "d.json"
    assert main(["diagnose", "--vessel", str(toml), str(path), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["unexplained"], "a large gap no candidate explains must be reported"
    assert doc["status"] in ("unexplained", "partly explained")
    u = doc["unexplained"][0]
    assert u["dof"] == "yaw" and u["gap"] > 3 and 0 < u["share"] <= 1
    assert u["band"] and u["looks_like"] and set(u["correlations"]) >= {"tau_n", "tau_x"} - {"tau_x"}
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("UNEXPLAINED")
    assert not any("nothing left above" in line for line in printed)


def test_html_section_leads_with_the_unexplained_gap(tmp_path):
    from pipeline.diagnose.html import diagnose_html_section

    rep = _report(tmp_path, "sq", extra=lambda t: 0.02 * np.sign(np.sin(2 * np.pi * t / 37.0)))
    _, html = diagnose_html_section(rep, figures={})
    assert html.index("Unexplained") < html.index("Verdict")
    assert "Ranking rule" in html and "no effect." not in html.lower().split("unexplained")[0]


def test_next_step_works_on_the_candidate_residual_over_one_baseline_fit():
    """The data the next selection step sees is the selected candidate's held-out residual on top
    of the baseline fitted on every window, not on its held-out outputs (a different fold fit in
    every window, whose spread in gain would come back as a gap), and each window's measured start
    value moves with the correction."""
    from types import SimpleNamespace

    from pipeline.diagnose.gridfit import GridData
    from pipeline.diagnose.selection import DofState, forward_select
    from pipeline.records import CandidateResult, ChannelGap

    rng = np.random.default_rng(0)
    w, n = 3, 6
    y = rng.standard_normal((w, n))
    mask = np.ones((w, n), bool)
    data = GridData(dt=1.0, y=y, y0=y[:, 0].copy(), angle=None, mask=mask)
    ramp = np.arange(n, dtype=float)
    full = {"y": np.outer([1.0, 2.0, 3.0], ramp)}
    heldout = {"y": full["y"] * np.array([[0.8], [1.3], [0.9]])}   # fold fits with spread gains
    cand = {"y": full["y"] + 0.5 + 0.1 * ramp}
    res = CandidateResult(effect="current", dof="yaw", label="current", input_channel=None, gap_before=2.0,
                          gap_after=1.0, shrink=50.0, explained=0.1, p_value=1e-9, significant=True, params=(),
                          model=(), channels=(ChannelGap("r", 2.0, 1.0, 1e-9, 30.0),), gain=3.0)
    state = DofState(problem=None, data=data, results=[(res, SimpleNamespace(heldout=cand))], base_heldout=heldout,
                     channel_gaps={"r": 2.0}, channel_neff={"r": 30.0}, selected=[], base_full=full)
    seen = []

    def rescore(s):
        seen.append(s.data)
        s.results = []

    chosen = forward_select({"yaw": state}, rescore)
    assert [c[0].label for c in chosen] == ["current"]
    np.testing.assert_allclose(seen[0].y, full["y"] + y - cand["y"])
    # The correction cand - full is 0.5 + 0.1 t at block middles t = 0, 1, ...: 0.45 at the start.
    np.testing.assert_allclose(seen[0].y0, y[:, 0] - 0.45)


def _pair_state(gap, sig_a=False, b_on_a=True, a_on_b=True):
    """A one-DOF state whose two candidates, A (current) and B (rate limit), are not significant
    alone; a stub rescore says which becomes significant once the other is taken off."""
    from types import SimpleNamespace

    from pipeline.diagnose.gridfit import GridData
    from pipeline.diagnose.selection import DofState
    from pipeline.records import CandidateResult, ChannelGap

    w, n = 8, 20
    y = np.random.default_rng(1).standard_normal((w, n))
    data = GridData(dt=1.0, y=y, y0=y[:, 0].copy(), angle=None, mask=np.ones((w, n), bool), sigma_y=1.0)
    full = {"y": np.zeros((w, n))}

    def res(label, effect, shrink, significant, p=0.05):
        return CandidateResult(effect=effect, dof="yaw", label=label, input_channel=None, gap_before=gap,
                               gap_after=gap * (1 - shrink / 100), shrink=shrink, explained=0.1, p_value=p,
                               significant=significant, channels=(ChannelGap("r", gap, gap * (1 - shrink / 100),
                                                                             p, 8.0),))

    a = (res("current", "current", 32.0, sig_a), SimpleNamespace(heldout={"y": np.full((w, n), 1.0)}))
    b = (res("actuator_rate_limit[delta]", "actuator_rate_limit", 20.0, False),
         SimpleNamespace(heldout={"y": np.full((w, n), 2.0)}))
    state = DofState(problem=SimpleNamespace(channel="r", angle=None), data=data, results=[a, b], base_heldout=full,
                     channel_gaps={"r": gap}, channel_neff={"r": 8.0 * n}, selected=[], base_full=full)
    calls = []

    def rescore(s):
        # Which correction was taken off: the mean shift of the data tells A (1) from B (2).
        shift = round(float(np.mean(y - s.data.y)))
        calls.append(shift)
        if shift == 1:      # A off: B on top of A
            s.results = [(res("actuator_rate_limit[delta]", "actuator_rate_limit", 60.0, b_on_a, 1e-6), b[1])]
        elif shift == 2:    # B off: A on top of B
            s.results = [(res("current", "current", 70.0, a_on_b, 1e-6), a[1])]
        else:
            s.results = []
        s.base_full = full
    return state, rescore, calls


@pytest.mark.parametrize("gap, b_on_a, a_on_b, selected", [
    (40.0, True, True, ["current", "actuator_rate_limit[delta]"]),
    (40.0, True, False, []),       # A not significant on top of B: no pair
    (40.0, False, True, []),       # nothing significant on top of A or B
    (1.0, True, True, []),         # the gap is what a correct model leaves: nothing is tried
])
def test_two_effects_that_hide_each_other_are_selected_only_when_each_holds_on_top_of_the_other(
        gap, b_on_a, a_on_b, selected):
    from pipeline.diagnose.selection import forward_select, selected_effects

    state, rescore, calls = _pair_state(gap, b_on_a=b_on_a, a_on_b=a_on_b)
    chosen = forward_select({"yaw": state}, rescore)
    assert [c[0].label for c in chosen] == selected
    if gap <= 1.0:
        assert calls == []
    if selected:
        eff = selected_effects(chosen, {"yaw": state})
        assert eff[0].p_value == pytest.approx(1e-6) and "jointly" in eff[0].why
        assert state.selected == selected


@pytest.mark.parametrize("signal, expected", [(1.0, True), (0.0, False)])
def test_a_sway_speed_within_a_few_noise_units_per_sample_is_a_coupling_regressor(tmp_path, signal, expected):
    """The coupling regressor enters as block means over the analysis step, so its variation is
    compared with a block mean's noise: a sway speed that moves 2.5 per-sample noise units (a small
    boat's N_v v at 25 Hz) is a regressor; pure noise is not."""
    from pipeline.diagnose.problem import build_problems
    from pipeline.diagnose.segments import diagnose_segments

    rng = np.random.default_rng(3)
    fs, n = 25.0, int(8 * 60 * 25)
    t = np.arange(n) / fs
    hold = int(25 * fs)
    tau_n = np.repeat(rng.uniform(-1, 1, n // hold + 1), hold)[:n]
    r = np.zeros(n)
    for k in range(n - 1):
        r[k + 1] = r[k] + (-r[k] + 0.2 * tau_n[k]) / fs / 8.0
    v_true = -signal * r / np.std(r) * 2.5 * 0.01
    pd.DataFrame({"t": t, "tau_n": tau_n, "r": r + 0.002 * rng.standard_normal(n),
                  "psi": np.angle(np.exp(1j * (np.cumsum(r) / fs + 0.003 * rng.standard_normal(n)))),
                  "v": v_true + 0.01 * rng.standard_normal(n)}).to_csv(tmp_path / "trial.csv", index=False)
    trial = load_trial([tmp_path / "trial.csv"], None)
    p = next(q for q in build_problems(trial, diagnose_segments(trial)) if q.dof == "yaw")
    assert p.m >= 4
    assert ("v" in p.regressors) is expected


def _transform_result(dof, effect, label, shrink, input_channel=None):
    from pipeline.records import CandidateResult, ChannelGap

    ch = {"yaw": "r", "sway": "v", "surge": "u"}[dof]
    return CandidateResult(effect=effect, dof=dof, label=label, input_channel=input_channel, gap_before=10.0,
                           gap_after=10.0 * (1 - shrink / 100), shrink=shrink, explained=0.1, p_value=1e-12,
                           significant=True, channels=(ChannelGap(ch, 10.0, 10.0 * (1 - shrink / 100), 1e-12, 50.0),))


def _delay_and_limit_states(limit_shrink):
    """Yaw with a strong delay of every input; sway whose rate limit of tau_y ranks first by
    ``limit_shrink - 54.9`` points over its delay of every input (randomised seed 18, r010)."""
    from types import SimpleNamespace

    from pipeline.diagnose.gridfit import GridData
    from pipeline.diagnose.selection import DofState

    states = {}
    for dof, results in (("yaw", [_transform_result("yaw", "actuator_delay", "actuator_delay", 80.0)]),
                         ("sway", [_transform_result("sway", "actuator_rate_limit", "actuator_rate_limit[tau_y]",
                                                     limit_shrink, "tau_y"),
                                   _transform_result("sway", "actuator_delay", "actuator_delay", 54.9)])):
        y = np.zeros((3, 4))
        data = GridData(dt=1.0, y=y, y0=y[:, 0].copy(), angle=None, mask=np.ones((3, 4), bool))
        run = SimpleNamespace(heldout={"y": y})
        states[dof] = DofState(problem=SimpleNamespace(channel=results[0].channels[0].channel, angle=None),
                               data=data, results=[(r, run) for r in results], base_heldout={"y": y},
                               channel_gaps={results[0].channels[0].channel: 10.0},
                               channel_neff={results[0].channels[0].channel: 50.0}, selected=[],
                               base_full={"y": y})
    return states


@pytest.mark.parametrize("limit_shrink, second", [(56.6, "actuator_delay"), (70.0, "actuator_rate_limit[tau_y]")])
def test_delay_of_every_input_selected_elsewhere_is_preferred_to_a_rate_limit_nearly_as_good(limit_shrink, second):
    from pipeline.diagnose.selection import forward_select, selected_effects

    states = _delay_and_limit_states(limit_shrink)

    def rescore(s):
        s.results = []

    chosen = forward_select(states, rescore)
    assert [(c[0].dof, c[0].label) for c in chosen] == [("yaw", "actuator_delay"), ("sway", second)]
    eff = selected_effects(chosen, states)
    assert ("the delay of every input is selected in yaw" in eff[1].why) == (second == "actuator_delay")


@pytest.mark.parametrize("first, second, unsure", [
    (("surge", "actuator_delay", "actuator_delay", None),
     ("surge", "actuator_rate_limit", "actuator_rate_limit[tau_x]", "tau_x"), True),        # seed 20, r005
    (("surge", "actuator_rate_limit", "actuator_rate_limit[tau_x]", "tau_x"),
     ("surge", "actuator_delay", "actuator_delay", None), True),
    (("yaw", "actuator_delay", "actuator_delay", None),
     ("surge", "actuator_rate_limit", "actuator_rate_limit[tau_x]", "tau_x"), False),       # another DOF
    (("yaw", "actuator_delay", "actuator_delay[thruster_port]", "thruster_port"),
     ("yaw", "actuator_rate_limit", "actuator_rate_limit[thruster_stbd]", "thruster_stbd"), False),  # other actuator
    (("surge", "actuator_rate_limit", "actuator_rate_limit[tau_x]", "tau_x"),
     ("surge", "actuator_delay", "actuator_delay after actuator_rate_limit[tau_x]", None), False),  # composed
])
def test_delay_and_rate_limit_of_one_input_in_one_dof_are_reported_unsure(first, second, unsure):
    from types import SimpleNamespace

    from pipeline.diagnose.selection import selected_effects

    a = _transform_result(first[0], first[1], first[2], 60.0, first[3])
    b = _transform_result(second[0], second[1], second[2], 30.0, second[3])
    states = {d: SimpleNamespace(problem=SimpleNamespace(channel="x", inputs=()), results=[], first_results=[])
              for d in {a.dof, b.dof}}
    eff = selected_effects([(a, None, 1.0), (b, None, 0.5)], states)
    assert not eff[0].why.startswith("unsure")
    assert eff[1].why.startswith("unsure:") == unsure


@pytest.mark.parametrize("chosen, rival, unsure", [
    (("actuator_rate_limit", "actuator_rate_limit[delta]", 15.3, "delta"),
     ("actuator_delay", "actuator_delay", 12.2, None), True),                     # seed 22, r016
    (("actuator_delay", "actuator_delay", 97.0, None),
     ("actuator_rate_limit", "actuator_rate_limit[delta]", 47.1, "delta"), False),  # far apart (seed 20, r005)
    (("actuator_rate_limit", "actuator_rate_limit[delta]", 15.3, "delta"),
     ("actuator_delay", "actuator_delay", 8.0, None), False),                     # the rival explains too little
    (("actuator_rate_limit", "actuator_rate_limit[thruster_stbd]", 40.0, "thruster_stbd"),
     ("actuator_delay", "actuator_delay[thruster_port]", 38.0, "thruster_port"), False),  # another actuator
])
def test_a_first_delay_or_rate_limit_with_a_close_rival_of_the_same_input_is_unsure(chosen, rival, unsure):
    from types import SimpleNamespace

    from pipeline.diagnose.selection import selected_effects

    a = _transform_result("yaw", chosen[0], chosen[1], chosen[2], chosen[3])
    b = _transform_result("yaw", rival[0], rival[1], rival[2], rival[3])
    states = {"yaw": SimpleNamespace(problem=SimpleNamespace(channel="r", inputs=()), results=[],
                                     first_results=[(a, None), (b, None)])}
    (eff,) = selected_effects([(a, None, 1.0)], states)
    assert eff.why.startswith("unsure:") == unsure, eff.why

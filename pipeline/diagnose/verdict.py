"""The diagnosis end to end: problems -> cross-validated candidates -> scores -> :class:`GapReport`.

Verdict: among the significant candidates (:mod:`pipeline.diagnose.significance`), the one that
removes the largest part of the trial's total squared gap; none when no candidate is
significant. "How far": the trial gap before, and after the verdict's effect is added in every DOF
where that effect is significant.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable, Mapping

import numpy as np

from ..errors import DiagnoseError
from ..parallel import ordered_map
from ..records import CHANNEL_UNITS, Fits, Segments, Trial
from ..vessel import Vessel
from . import significance as sig
from . import oscillatory as osc
from . import selection as sel
from .candidates import Candidate, candidate_label, candidates_for, composed_candidates, is_input_transform
from .crossval import CandidateRun, cross_validate, cross_validate_all, jackknife_stderr
from .actuators import actuator_space
from .floor import heldout_floors, oscillatory_floor, replicate_model
from .gridfit import grid_data
from .problem import DofProblem, build_problems
from ..records import RANKING_RULE, CandidateResult, ChannelGap, DofSummary, EffectParam, GapReport, Trace
from .replay import default_band, rank_places, replay, traces, where
from .segments import diagnose_segments
from .timing import input_timing
from .frame import DofFrame, first_pass_time_constants, on_frame


def _unit(name: str, p: DofProblem, run: CandidateRun) -> str:
    """SI unit of a candidate parameter."""
    uy = CHANNEL_UNITS.get(p.channel, "")
    src = _input_of(run) or ""
    us = CHANNEL_UNITS.get(src, "")
    if name in ("T", "tau_d"):
        return "s"
    act = getattr(run.candidate, "actuator", None)
    if act is not None:
        # Actuator space: the rate of a normalised actuator signal; gains on the input it drives.
        us = CHANNEL_UNITS.get(getattr(run.candidate, "input", None) or next(iter(act.gains)), "")
        if name == "R":
            return "1/s"
    if name in ("k_fwd", "k_rev"):
        return f"({uy})/({us})"
    if name.startswith("k_"):
        return f"({uy})/({CHANNEL_UNITS.get(name[2:], '-')})"
    wave_ch = p.angle if run.candidate.data.angle is not None else p.channel
    return {"d2": f"1/({uy})", "V_n": "m/s", "V_e": "m/s", "b": "rad", "bias": uy, "b_sensor": uy, "ratio": "-",
            "R": f"{us}/s", "omega0": "rad/s", "lambda": "-", "sigma_w": CHANNEL_UNITS.get(wave_ch or "", ""),
            "c": f"({uy})/({us})"}.get(name, "")


def _params(run: CandidateRun, p: DofProblem, names) -> tuple[EffectParam, ...]:
    se = jackknife_stderr(run.full.params, run.fold_params)
    return tuple(EffectParam(n, float(run.full.params[n]), float(se.get(n, math.nan)), _unit(n, p, run))
                 for n in names if n in run.full.params)


def _input_of(run: CandidateRun) -> str | None:
    ch = getattr(run.candidate, "channel", None)
    if ch:
        return ch
    if run.candidate.effect == "coupling" and isinstance(run.full.state, tuple) and len(run.full.state) == 3:
        return run.full.state[2]
    return None


def _refine_time_constants(trial: Trial, segments: Segments, vessel: Vessel | None) -> dict[str, float]:
    """First pass: fit the baseline on every window to size the analysis step and blocks
    (:func:`pipeline.diagnose.frame.first_pass_time_constants`)."""
    return first_pass_time_constants(trial, segments, vessel)


def diagnose(trial: Trial, vessel: Vessel | None = None, segments: Segments | None = None, fits: Fits | None = None,
             progress: Callable[[int], Callable[[], None]] | None = None, jobs: int = 1,
             detected: Segments | None = None, frame: Mapping[str, DofFrame] | None = None) -> GapReport:
    """Diagnose the sim-to-real gap of a trial.

    Parameters
    ----------
    trial : Trial
        Aligned trial (any mix of coast-downs, steps, zig-zags and decays, any sample rate).
    vessel : Vessel, optional
        Vessel config (a rudder ship's may hold only ``name``).
    segments : Segments, optional
        Segments to replay; default: detected (:func:`pipeline.diagnose.segments.diagnose_segments`).
    fits : Fits, optional
        The fit stage's result; the diagnosis refits its own baselines fold by fold regardless, and
        notes the fit stage's Nomoto and damping values for comparison.
    progress : callable, optional
        ``progress(total_steps)`` returning a ``tick()`` called once per step (a progress bar).
    jobs : int
        Processes that cross-validate the DOFs side by side (1: in this process). The results do
        not depend on it.
    detected : Segments, optional
        Without ``segments``: the segment stage's detection on this trial, ``segment_trial(trial)``
        with no manifest segments, so that it is not run again (see
        :func:`pipeline.diagnose.segments.diagnose_segments`).
    frame : Mapping[str, DofFrame], optional
        Another trial's frame (:func:`pipeline.diagnose.frame.diagnosis_frame`, a trial of the same
        schedule and log): each DOF is diagnosed on its windows, analysis step, input timing and noise
        units instead of this trial's own, and only its DOFs are diagnosed (roll and pitch as usual).
        For measuring what an effect changes (the benchmark's power), not for a real trial.

    Returns
    -------
    GapReport

    Raises
    ------
    DiagnoseError
        No segment, or no DOF that is both excited by the trial and measured.
    """
    notes: list[str] = []
    segs = segments if segments is not None else diagnose_segments(trial, detected)
    if not segs.items:
        raise DiagnoseError(f"{trial.name}: expected at least one manoeuvre segment (coast-down, step, zig-zag, "
                            f"decay) or a logged input to replay, found none in channels "
                            f"{[c for c in trial.data.columns if c != 't']}")
    t_consts = (_refine_time_constants(trial, segs, vessel) if frame is None
                else {dof: f.t_guess for dof, f in frame.items()})
    space_note = actuator_space(trial, vessel).note
    if space_note:
        notes.append(space_note)
    problems = build_problems(trial, segs, vessel, time_constants=t_consts)
    if frame is not None:
        problems = [on_frame(p, frame[p.dof]) for p in problems if p.dof in frame]
    osc_problems = [q for q in (osc.build_oscillatory(trial, segs, dof) for dof in ("roll", "pitch")) if q is not None]
    # Independent units, side by side in worker processes when ``jobs`` allows: the roll and pitch
    # cross-validations (their results are used below, in the same order as before) and each DOF's input
    # timing and grid data.
    early = ordered_map(_early_unit, [("osc", q) for q in osc_problems]
                        + [("timing", p) if frame is None else ("framed", (p, frame[p.dof].advance)) for p in problems],
                        jobs=jobs)
    osc_done, timed = early[:len(osc_problems)], early[len(osc_problems):]
    logged = {p.dof: {c: p.raw[c] for c in p.inputs} for p in problems}
    problems = [p for p, _, _ in timed]
    for p, adv, _ in timed:
        if adv > 0:
            notes.append(f"{p.dof}: inputs taken {adv:.3g} s earlier than logged (the log's timing of the commands: "
                         f"a command sampled by the log is recorded up to one sample after it switched); the "
                         f"baseline and every candidate use that timing")
        notes += _stated_noise_notes(p)
    if not problems and not osc_problems:
        raise DiagnoseError(f"{trial.name}: expected a DOF whose response (u, v or r, or sog) is measured and "
                            f"excited by the segments, found none (channels "
                            f"{[c for c in trial.data.columns if c != 't']}, {len(segs.items)} segments)")
    datas = [d for _, _, d in timed]
    cands = [candidates_for(p, d) for p, d in zip(problems, datas)]
    from .crossval import assign_folds

    # The folds are counted for a progress bar only (0.6 s CPU on a 2-hour trial).
    tick = progress(sum(int(assign_folds(p).max()) + 2 for p in problems)) if progress else None

    results: list[CandidateResult] = []
    summaries: list[DofSummary] = []
    per_dof: dict[str, dict] = {}
    states: dict[str, sel.DofState] = {}
    pre = _cross_validate_all(problems, datas, cands, jobs, tick)
    scored_dofs = []
    for p, d, cs, runs0 in zip(problems, datas, cands, pre):
        runs, scored, base_score = _score_dof(p, d, cs, tick, runs=runs0)
        scored_dofs.append((runs, scored, base_score, _full_outputs(runs[0], len(p.windows))))
    # Every DOF's noise-floor replicates in one call, their units side by side (one call per DOF
    # put 3 units on 2 workers: the third ran with the other worker idle).
    # The replicates start at the baseline's initial states and, where the log samples its commands (the log's
    # timing was applied in a DOF), carry the switches' timing within a log sample
    # (pipeline.diagnose.floor.replicate_model).
    # A DOF whose own timing the data did not pin (an unmodelled effect dominated its misfit) takes the
    # trial's: one log times every command.
    pinned = [adv for _, adv, _ in timed if adv > 0]
    floors = heldout_floors([(p, d, s[3], replicate_model(s[0][0], logged.get(p.dof) if pinned else None,
                                                          (adv if adv > 0 else float(np.median(pinned or [0.0])))
                                                          * p.fs))
                             for p, d, s, (_, adv, _) in zip(problems, datas, scored_dofs, timed)])
    for p, d, (runs, scored, base_score, base_full), floor_of in zip(problems, datas, scored_dofs, floors):
        names = {"y": p.channel, "angle": p.angle}
        base = runs[0]
        results += [res for res, _, _ in scored]
        gaps, neff = sel.channel_gaps_of(base_score)
        per_dof[p.dof] = {"problem": p, "data": d, "runs": runs, "scored": scored, "names": names,
                          "channel_gaps": dict(gaps)}
        states[p.dof] = sel.DofState(problem=p, data=d, results=[(res, r) for res, r, _ in scored],
                                     base_heldout=base.heldout, channel_gaps=dict(gaps), channel_neff=dict(neff),
                                     selected=[], base_full=base_full, channel_floor=dict(floor_of))
        resid = sig.heldout_residuals(d, base.heldout)
        floor = d.sigma_y
        summaries.append(DofSummary(
            dof=p.dof, channels=p.outputs, inputs=p.inputs, dt=p.dt, n_windows=len(p.windows),
            n_folds=int(base.fold_of.max()) + 1, baseline=_params(base, p, tuple(base.full.params)),
            gap=base_score.gap_before, noise_floor=float(floor), replay_gap=math.nan,
            heldout_floor=dict(floor_of)))
        per_dof[p.dof]["resid"] = resid

    for q, (res, base_run, cand_run, summary, state) in zip(osc_problems, osc_done):
        results.append(res)
        summaries.append(summary)
        states[q.dof] = state
        per_dof[q.dof] = {"problem": q, "data": q.data, "runs": [base_run], "scored": [(res, cand_run, None)],
                          "names": {"y": q.channel, "angle": q.angle}, "channel_gaps": dict(state.channel_gaps),
                          "oscillatory": True}

    ranked = sorted(results, key=sel.rank_key)
    run_of = {(res.dof, res.label): r for v in per_dof.values() for res, r, _ in v["scored"]}

    def rescore(state: sel.DofState) -> None:
        """Cross-validate a DOF again on its corrected data (the next selection step), its folds
        spread over ``jobs`` worker processes as in the first round."""
        p = state.problem
        if isinstance(p, osc.OscProblem):
            # One candidate only: once it is selected nothing is left to test in this DOF, and the
            # old baseline's prediction on the corrected data leaves exactly the candidate's residual.
            state.results = []
            return
        taken = {label.split(" after ")[0] for label in state.selected}
        last = next((r for res, r in state.results if state.selected and res.label == state.selected[-1]), None)
        cs = [c for c in candidates_for(p, state.data) if candidate_label(c) not in taken]
        runs2, scored2, bs = _score_dof(p, state.data, cs, None,
                                        runs=_cross_validate_all([p], [state.data], [cs], jobs, None)[0])
        for res, r, _ in scored2:
            run_of[(res.dof, "+" + res.label)] = r
        state.results = [(res, r) for res, r, _ in scored2]
        state.results += _composed(p, last, taken, state, jobs)
        state.base_heldout = runs2[0].heldout
        state.base_full = _full_outputs(runs2[0], len(p.windows))
        state.channel_gaps, state.channel_neff = sel.channel_gaps_of(bs)

    chosen = sel.forward_select(states, rescore)
    effects = sel.selected_effects(chosen, states, params_of=lambda res: res.params)
    winner = chosen[0][0] if chosen else None
    gap_final = chosen[-1][2] if chosen else sel.trial_gap(states)

    # Trial gap: RMS over every scored channel of every DOF.
    before = {(dof, ch): g for dof, v in per_dof.items() for ch, g in v["channel_gaps"].items()}
    after = dict(before)
    if winner is not None:
        for dof, v in per_dof.items():
            best = min((res for res, _, _ in v["scored"] if res.significant and res.effect == winner.effect),
                       key=sel.rank_key, default=None)
            if best is not None:
                for cg in best.channels:
                    after[(dof, cg.channel)] = cg.gap_after
    gb = float(np.sqrt(np.nanmean(np.array(list(before.values())) ** 2)))
    ga = float(np.sqrt(np.nanmean(np.array(list(after.values())) ** 2)))

    # Where: places and spectra from the baseline's held-out residuals.
    raw_places = []
    spectra = []
    all_traces: list[Trace] = []
    for i, (dof, v) in enumerate(per_dof.items()):
        if v.get("oscillatory"):
            continue
        p, d = v["problem"], v["data"]
        waves_run = next(((res, r) for res, r, _ in v["scored"] if res.effect == "waves"), None)
        band = default_band(p)
        if waves_run is not None and waves_run[0].significant:
            om = waves_run[1].full.params.get("omega0", math.nan)
            if math.isfinite(om):
                band = (om / math.sqrt(2), om * math.sqrt(2))
        units = sig.noise_units(d)
        in_noise = {k: r / units[k] if np.isfinite(units[k]) else r for k, r in v["resid"].items()}
        pl, sp = where(p, d, in_noise, trial, band, v["names"])
        raw_places += [(dof, cat, name, ss, n) for cat, name, ss, n in pl]
        spectra += sp
        # Overlays: the DOF's best significant candidate, else its best by gain.
        cand = [x for x in v["scored"] if x[0].significant] or v["scored"]
        best = min(cand, key=lambda x: sel.rank_key(x[0]), default=None)
        base_run = v["runs"][0]
        if best is not None:
            all_traces += traces(p, d, base_run.heldout, best[1].heldout, best[0].label, "heldout", v["names"])
        else:
            all_traces += traces(p, d, base_run.heldout, None, None, "heldout", v["names"])
        # Whole-trial replay of the baseline fitted on every window.
        rd, rout, rp = replay(p, trial, lambda dd, c=base_run.candidate, f=base_run.full:
                              _replay_sim(c, f, dd))
        if rd is not None:
            all_traces += traces(rp, rd, rout, None, None, "replay", v["names"])
            rr = sig.heldout_residuals(rd, rout)
            gaps = [float(np.sqrt(np.nanmean(x**2))) for x in rr.values() if np.isfinite(x).any()]
            summaries[i] = _with_replay(summaries[i], float(np.sqrt(np.mean(np.square(gaps)))) if gaps else math.nan)
    places = rank_places(raw_places)
    heading_waves = any(e.effect == "waves" and getattr(states[e.dof].problem, "angle", None) == "psi" for e in effects)
    unexplained = sel.unexplained(states, places, trial, lambda p: {"y": p.channel, "angle": p.angle},
                                  heading_waves=heading_waves)
    for e in effects:
        if e.why:
            notes.append(f"{e.label} in {e.dof}: {e.why}")

    if fits is not None:
        for key in ("K_nomoto", "T_nomoto", "X_u", "Y_v", "N_r"):
            e = fits.estimates.get(key)
            if e is not None and e.success:
                notes.append(f"fit stage: {key} = {e.value:.4g} {e.unit}")
    for q in osc_problems:
        notes.append(f"{q.dof}: {len(q.windows)} windows ({', '.join(dict.fromkeys(w.label for w in q.windows))}), "
                     f"channels {', '.join(q.outputs)}, second-order baseline (natural frequency, damping ratio"
                     + (f", gain of {q.inputs[0]}" if q.inputs else ", free decays") + f"), analysis step {q.dt:.3g} s")
    for p in problems:
        notes.append(f"{p.dof}: {len(p.windows)} windows, response {p.channel}"
                     + (f" and heading {p.angle}" if p.angle else "")
                     + (f", inputs {', '.join(p.inputs)}" if p.inputs else ", no input (free decays)")
                     + f", analysis step {p.dt:.3g} s")
    thresholds = {"alpha_unexplained": sel.ALPHA_UNEXPLAINED, "unexplained_gap": sel.UNEXPLAINED_GAP,
                  "min_unexplained_scale": sel.MIN_UNEXPLAINED_SCALE,
                  "alpha": sig.ALPHA, "alpha_robust": sig.ALPHA_ROBUST, "min_shrink_percent": sig.MIN_SHRINK,
                  "min_explained": sig.MIN_EXPLAINED}
    return GapReport(
        trial=trial.name, vessel=vessel.name if vessel is not None else "",
        effect=effects[0].effect if effects else None, dof=effects[0].dof if effects else None,
        gap_before=gb, gap_after=ga if winner else gb, candidates=tuple(ranked), places=places,
        dofs=tuple(summaries), traces=tuple(all_traces), spectra=tuple(spectra), thresholds=thresholds,
        notes=tuple(notes), effects=effects, gap_final=gap_final, unexplained=unexplained,
        ranking_rule=f"{RANKING_RULE}; significance: {sig.SIGNIFICANCE_RULE}; {sig.ON_TOP_RULE}", unexplained_test=sel.UNEXPLAINED_TEST)


#: A composed delay counts only when it exceeds this many jackknife standard errors (a delay of zero
#: behind a rate limit is the rate limit refitted: seed 16 r018, a rate limit alone, gave tau_d = 0.0 +- 0.07 s
#: at 51.6 % shrink).
COMPOSED_DELAY_SE = 2.0


def _composed(p: DofProblem, last: CandidateRun | None, taken: set[str], state: sel.DofState,
              jobs: int = 1) -> list:
    """A delay composed behind a selected rate limit
    (:func:`pipeline.diagnose.candidates.composed_candidates`), scored on the original
    measurements against the rate limit alone; ``(CandidateResult, CandidateRun)`` pairs. The
    reference each one's correction is taken from is kept in ``state.result_base``; ``jobs``
    worker processes cross-validate."""
    if last is None or not is_input_transform(last.candidate) or getattr(last.candidate, "after", None):
        return []
    cs = [c for c in composed_candidates(p, last.candidate, last.full)]
    cs = cs[:1] + [c for c in cs[1:] if candidate_label(c).split(" after ")[0] not in taken]
    if len(cs) < 2:
        return []
    runs, scored, _ = _score_dof(cs[0].problem, cs[0].data, cs, None,
                                 runs=_cross_validate_all([cs[0].problem], [cs[0].data], [cs], jobs, None)[0])
    ref = _full_outputs(runs[0], len(p.windows))
    out = []
    for res, r, _ in scored:
        tau = next((q for q in res.params if q.name == "tau_d"), None)
        if res.significant and tau is not None and not tau.value > COMPOSED_DELAY_SE * tau.stderr:
            # A delay within two jackknife errors of zero is no delay: its shrink is the rate limit
            # refitted (both values are refined together), not a second effect.
            res = replace(res, significant=False)
        state.result_base[res.label] = ref if ref is not None else runs[0].heldout
        out.append((res, r))
    return out


def _stated_noise_notes(p: DofProblem) -> list[str]:
    """Where a DOF's noise floor does not come from its own windows, or the vessel config's
    ``[sensor_noise]`` capped it: where it comes from, and the two floors."""
    from .problem import MIN_CONTRASTS, block_noise, noise_source

    out = []
    for ch in p.outputs:
        s = p.stated_noise.get(ch)
        unit = CHANNEL_UNITS.get(ch, "")
        if s is None:
            src = noise_source(p.raw[ch], p.windows, p.m)
            if src == "whole log":
                got = block_noise(p.raw[ch], p.windows, p.m, trapezoid=True)
                out.append(f"{p.dof}: noise floor of {ch} measured over the whole log ({got:.3g} {unit} per "
                           f"analysis step): the DOF's windows hold fewer than {MIN_CONTRASTS} blocks of "
                           f"{max(p.m, 8)} samples, and the vessel config states no [sensor_noise] for it")
            elif src == "none":
                out.append(f"{p.dof}: no noise floor for {ch}: neither its windows nor the whole log hold "
                           f"{MIN_CONTRASTS} blocks of {max(p.m, 8)} samples and the vessel config states no "
                           f"[sensor_noise] for it; its gaps are in scale units and it has no held-out floor")
            continue
        told = block_noise(p.raw[ch], p.windows, p.m, trapezoid=True, stated=s)
        data = block_noise(p.raw[ch], p.windows, p.m, trapezoid=True, whole_log=False)
        if not np.isfinite(data) and np.isfinite(told):
            out.append(f"{p.dof}: noise floor of {ch} from the vessel config's [sensor_noise] ({s:.3g} {unit} per "
                       f"sample): {told:.3g} {unit} per analysis step; the data cannot measure it (fewer than "
                       f"{MIN_CONTRASTS} blocks of {max(p.m, 8)} samples in the DOF's windows)")
        elif told < data:
            out.append(f"{p.dof}: noise floor of {ch} from the vessel config's [sensor_noise] ({s:.3g} {unit} per "
                       f"sample): {told:.3g} {unit} per analysis step; the data alone gave {data:.3g} (what moves "
                       f"within a few samples, a wave among it, counted as noise there)")
        else:
            out.append(f"{p.dof}: noise floor of {ch} measured in the data ({data:.3g} {unit} per analysis step), "
                       f"below the vessel config's [sensor_noise] {s:.3g} {unit} per sample")
    return out


def _early_unit(_, job):
    """A unit of :func:`pipeline.parallel.ordered_map` in :func:`diagnose`: ``("osc", q)`` ->
    :func:`_oscillatory_dof` of ``q``; ``("timing", p)`` -> ``(problem, advance, grid data)``, the
    problem with its input timing (:func:`pipeline.diagnose.timing.input_timing`) and its grid data;
    ``("framed", (p, advance))`` -> ``(p, advance, grid data)`` (a problem on another trial's frame)."""
    kind, problem = job
    if kind == "osc":
        return _oscillatory_dof(problem)
    if kind == "framed":  # on another trial's frame: its timing is already applied (:func:`on_frame`)
        p, advance = problem
        return p, advance, grid_data(p)
    timed, advance = input_timing(problem)
    return timed, advance, grid_data(timed)


def _oscillatory_dof(q):
    """Cross-validate and score roll or pitch (:mod:`pipeline.diagnose.oscillatory`)."""
    base_run, cand_run = osc.cross_validate(q)
    names = {"y": q.channel, "angle": q.angle}
    s = sig.score(q.data, base_run.heldout, cand_run.heldout, 1, names, folds=base_run.fold_of)

    def eparams(run, keys):
        se = jackknife_stderr(run.full, run.fold_params)
        return tuple(EffectParam(k, float(run.full[k]), float(se.get(k, math.nan)), osc.UNITS.get(k, ""))
                     for k in keys if k in run.full)

    res = CandidateResult(
        effect="nonlinear_damping", dof=q.dof, label="nonlinear_damping", input_channel=None,
        gap_before=s.gap_before, gap_after=s.gap_after, shrink=s.shrink, explained=s.explained,
        p_value=s.p_value, significant=s.significant, params=eparams(cand_run, ("d2",)),
        model=eparams(cand_run, tuple(cand_run.full)),
        channels=tuple(ChannelGap(c.channel, c.gap_before, c.gap_after, c.p_value, c.n_eff) for c in s.channels),
        gain=s.gain)
    bs = sig.score(q.data, base_run.heldout, base_run.heldout, 1, names)
    gaps, neff = sel.channel_gaps_of(bs)
    # Its held-out floor, as every other DOF's (pipeline.diagnose.floor.oscillatory_floor).
    floor_of = oscillatory_floor(q, base_run)
    summary = DofSummary(dof=q.dof, channels=q.outputs, inputs=q.inputs, dt=q.dt, n_windows=len(q.windows),
                         n_folds=int(base_run.fold_of.max()) + 1,
                         baseline=eparams(base_run, tuple(base_run.full)), gap=bs.gap_before,
                         noise_floor=float(q.data.sigma_y if q.rate else q.data.sigma_angle), replay_gap=math.nan,
                         heldout_floor=dict(floor_of))
    state = sel.DofState(problem=q, data=q.data, results=[(res, cand_run)], base_heldout=base_run.heldout,
                         channel_gaps=dict(gaps), channel_neff=dict(neff), selected=[], channel_floor=dict(floor_of))
    return res, base_run, cand_run, summary, state


def _cross_validate_all(problems: list[DofProblem], datas: list, cands: list, jobs: int,
                        tick) -> list[list[CandidateRun] | None]:
    """Every DOF's cross-validation, its folds spread over ``jobs`` worker processes
    (:func:`pipeline.diagnose.crossval.cross_validate_all`); None per DOF when ``jobs`` is 1 (done
    later in turn)."""
    if jobs <= 1:
        return [None] * len(problems)
    return cross_validate_all(problems, datas, cands, tick=tick, jobs=jobs)


def _score_dof(p: DofProblem, d, cs: list[Candidate], tick, runs: list[CandidateRun] | None = None,
               ) -> tuple[list[CandidateRun], list, sig.Score]:
    """Cross-validate (unless ``runs`` are given) and score every candidate of one DOF against its
    baseline (``cs[0]``)."""
    runs = cross_validate(p, d, cs, tick=tick) if runs is None else runs
    names = {"y": p.channel, "angle": p.angle}
    base = runs[0]
    scored = []
    for r in runs[1:]:
        s = sig.score(d, base.heldout, r.heldout, r.candidate.n_extra, names, folds=base.fold_of)
        res = CandidateResult(
            effect=r.candidate.effect, dof=p.dof, label=r.label, input_channel=_input_of(r),
            gap_before=s.gap_before, gap_after=s.gap_after, shrink=s.shrink, explained=s.explained,
            p_value=s.p_value, significant=s.significant,
            params=_params(r, p, r.full.effect_params),
            model=_params(r, p, tuple(r.full.params)),
            channels=tuple(ChannelGap(c.channel, c.gap_before, c.gap_after, c.p_value, c.n_eff) for c in s.channels),
            gain=s.gain)
        scored.append((res, r, s))
    base_score = sig.score(d, base.heldout, base.heldout, 1, names)
    return runs, scored, base_score


def _full_outputs(run: CandidateRun, n_windows: int) -> dict[str, np.ndarray] | None:
    """Outputs on every window of a candidate fitted on every window (None if it cannot simulate)."""
    try:
        return run.candidate.simulate(run.full, np.arange(n_windows))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None


def _replay_sim(candidate: Candidate, fitted, data) -> dict[str, np.ndarray]:
    from .gridfit import predict_linear

    spec, theta = fitted.state
    return predict_linear(data, spec, fitted.params["T"], theta)


def _with_replay(s: DofSummary, gap: float) -> DofSummary:
    return replace(s, replay_gap=gap)

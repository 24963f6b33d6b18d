"""Closed-loop check of the heading autopilot: PD alone, PD on the Kalman estimate, and with bias feed-forward.

The ship is the first-order Nomoto model :func:`pipeline.model.nomoto_rhs` (RK4 between samples, rudder
held), the current a constant rudder bias ``b`` (Fossen 2021 sec. 7.2; the seed's model), the waves
the second-order model of :func:`pipeline.model.waves.simulate_waves` added to the compass, and the
compass noise a sampled white noise of variance R. The rudder saturates at ``max_angle`` and moves at
most ``max_rate``. The controller runs at the filter's sample time. Three cases:

``pd``
    PD on the compass heading ``y = psi + psi_w + v``: the seed's part III.
``pd_kalman``
    PD on the filter's ``psi_hat`` (wave filtering), no bias feed-forward.
``pd_kalman_ff``
    PD on ``psi_hat`` plus the estimated bias ``b_hat`` fed forward to the rudder.

Everything inside is SI and radians; :meth:`pipeline.records.LoopMetrics.to_dict` gives degrees for the report.
The records (:class:`~pipeline.records.Scenario`, ``LoopMetrics``, ``ClosedLoopRun``, ``ClosedLoopCheck``)
are in :mod:`pipeline.records`.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import AutopilotError
from ..model.nomoto import NomotoParams, nomoto_rhs
from ..model.waves import simulate_waves
from ..geo import wrap_pi
from ..records import DEFAULT_STEP, AutopilotConfig, ClosedLoopCheck, ClosedLoopRun, LoopMetrics, Scenario
from .kalman import kalman_predict, kalman_update
from .pd import discretise_pd

#: Closed-loop cases, in report order.
CASES = ("pd", "pd_kalman", "pd_kalman_ff")
CASE_LABELS = {
    "pd": "PD on the compass",
    "pd_kalman": "PD on the Kalman heading (wave filtering)",
    "pd_kalman_ff": "PD on the Kalman heading + bias feed-forward",
}
#: Window over which a rudder swing is measured [s] (the seed's "40 degrees within 5 s").
SWING_WINDOW = 5.0
#: Default current, as a rudder bias [rad]: the seed's rudder settled near 3 deg against it.
DEFAULT_CURRENT_BIAS = math.radians(3.0)


def _rk4(x: np.ndarray, u: np.ndarray, h: float, params: NomotoParams) -> np.ndarray:
    k1 = nomoto_rhs(0.0, x, u, params)
    k2 = nomoto_rhs(0.0, x + h / 2 * k1, u, params)
    k3 = nomoto_rhs(0.0, x + h / 2 * k2, u, params)
    k4 = nomoto_rhs(0.0, x + h * k3, u, params)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def kalman_gains(model, n: int) -> np.ndarray:
    """Kalman gains of the first ``n`` compass samples, from the model's ``p0``.

    The covariance recursion of :func:`kalman_update` and :func:`kalman_predict` does not depend on
    the measurements or the rudder, so the gains are the same in every case and scenario with this
    filter; computed once (cached on the model), the closed loop only updates the state.

    Parameters
    ----------
    model : pipeline.records.KalmanModel
        The filter.
    n : int
        Number of samples.

    Returns
    -------
    numpy.ndarray, shape (n, 5)
        Gain of sample ``k`` in row ``k``.
    """
    key = (id(model), n)
    cached = _GAINS.get(key)
    if cached is not None and cached[0] is model:
        return cached[1]
    gains = np.empty((n, model.x0.size))
    xk, pk = model.x0.copy(), model.p0.copy()
    for k in range(n):
        _, p_post, gains[k] = kalman_update(model, xk, pk, 0.0)
        _, pk = kalman_predict(model, xk, p_post, 0.0)
    _GAINS.clear()  # one filter at a time: the cache never grows
    _GAINS[key] = (model, gains)
    return gains


_GAINS: dict = {}


def simulate_heading_loop(config: AutopilotConfig, scenario: Scenario, case: str) -> ClosedLoopRun:
    """Simulate one case of the heading autopilot in one scenario.

    Parameters
    ----------
    config : AutopilotConfig
        Controller, filter and rudder limits.
    scenario : Scenario
        Ship and disturbances.
    case : str
        ``pd``, ``pd_kalman`` or ``pd_kalman_ff``.

    Returns
    -------
    ClosedLoopRun
        Time series and metrics. The filter runs in every case (its estimates are shown), but only
        the Kalman cases feed it back.

    Raises
    ------
    AutopilotError
        Unknown case, non-positive duration or plant parameters.
    """
    if case not in CASES:
        raise AutopilotError(f"closed-loop case: expected one of {list(CASES)}, found {case!r}")
    if not (scenario.duration > 20 * config.ts):
        raise AutopilotError(f"scenario {scenario.name!r}: expected a duration above {20 * config.ts:g} s, "
                             f"found {scenario.duration!r}")
    if not (scenario.K > 0 and scenario.T > 0):
        raise AutopilotError(f"scenario {scenario.name!r}: expected K > 0 and T > 0, found K={scenario.K!r}, "
                             f"T={scenario.T!r}")
    ts = config.ts
    n = int(round(scenario.duration / ts)) + 1
    t = ts * np.arange(n)
    rng = np.random.default_rng(scenario.seed)
    # Waves and noise are drawn up front from one seeded generator, so the three cases of a
    # scenario see the same sea and the same compass noise and differ only in the controller.
    psi_w = simulate_waves(t, scenario.waves, rng) if scenario.waves is not None else np.zeros(n)
    noise = rng.standard_normal(n) * math.sqrt(scenario.noise_var) if scenario.noise_var > 0 else np.zeros(n)
    plant = NomotoParams(K=scenario.K, T=scenario.T, b=scenario.current_bias)
    pdd = discretise_pd(config.pd, ts)
    km = config.kalman
    max_angle, max_step = config.rudder_max_angle, config.rudder_max_rate * ts
    use_filter = case != "pd"
    feed_forward = case == "pd_kalman_ff"

    gains = kalman_gains(km, n)
    c_row = km.c[0]
    ad, bd = km.ad, km.bd[:, 0]
    x = np.zeros(2)
    xk = km.x0.copy()
    z = 0.0
    delta_prev = 0.0
    out = np.empty((n, 8))  # psi, r, y, psi_hat, psi_w_hat, b_hat, delta, delta_cmd
    for k in range(n):
        y = x[0] + psi_w[k] + noise[k]
        # kalman_update / kalman_predict with the gain of this step precomputed: the covariance
        # recursion does not depend on the measurements, only the state update does.
        x_post = xk + gains[k] * float(wrap_pi(y - c_row @ xk))
        fb = x_post[2] if use_filter else y
        e = float(wrap_pi(scenario.psi_ref - fb))
        cmd = pdd.output(z, e) + (x_post[4] if feed_forward else 0.0)
        z = pdd.next_state(z, e)
        delta = min(max(delta_prev + min(max(cmd - delta_prev, -max_step), max_step), -max_angle), max_angle)
        out[k] = (x[0], x[1], y, x_post[2], x_post[1], x_post[4], delta, cmd)
        xk = ad @ x_post + bd * delta
        x = _rk4(x, np.array([delta]), ts, plant)
        delta_prev = delta

    run = dict(t=t, psi=out[:, 0], r=out[:, 1], psi_w=psi_w, y=out[:, 2], psi_hat=out[:, 3],
               psi_w_hat=out[:, 4], b_hat=out[:, 5], delta=out[:, 6], delta_cmd=out[:, 7])
    metrics = loop_metrics(run, scenario, ts, config.rudder_max_rate)
    return ClosedLoopRun(scenario=scenario, case=case, metrics=metrics, **run)


def _max_swing(x: np.ndarray, width: int) -> float:
    if len(x) < width:
        return float(np.ptp(x)) if len(x) else math.nan
    win = np.lib.stride_tricks.sliding_window_view(x, width)
    return float(np.max(win.max(axis=1) - win.min(axis=1)))


def loop_metrics(run: dict, scenario: Scenario, ts: float, max_rate: float) -> LoopMetrics:
    """Measure steady error, settling time, rudder rate and swings of one run.

    Parameters
    ----------
    run : dict
        Series ``t, psi, psi_w, y, psi_hat, b_hat, delta, delta_cmd`` as in :class:`ClosedLoopRun`.
    scenario : Scenario
        For the reference.
    ts : float
        Sample time [s].
    max_rate : float
        Rudder-rate limit [rad/s].

    Returns
    -------
    LoopMetrics
        The steady window is the last quarter of the run.
    """
    t = run["t"]
    t0 = t[-1] - 0.25 * (t[-1] - t[0])
    w = t >= t0
    err = scenario.psi_ref - run["psi"]
    band = max(0.05 * abs(scenario.psi_ref), math.radians(0.5))
    outside = np.flatnonzero(np.abs(err) > band)
    if len(outside) == 0:
        settling = 0.0
    elif outside[-1] == len(t) - 1:
        settling = math.nan
    else:
        settling = float(t[outside[-1] + 1])
    d = run["delta"]
    rate = np.diff(d[w]) / ts
    width = int(round(SWING_WINDOW / ts)) + 1
    return LoopMetrics(
        steady_error=float(np.mean(err[w])),
        settling_time=settling,
        settle_band=band,
        rms_rudder_rate=float(np.sqrt(np.mean(rate**2))) if len(rate) else math.nan,
        max_swing=_max_swing(d[w], width),
        max_swing_cmd=_max_swing(run["delta_cmd"][w], width),
        rate_limited=float(np.mean(np.abs(rate) >= 0.999 * max_rate)) if len(rate) else math.nan,
        mean_rudder=float(np.mean(d[w])),
        heading_estimate_rms=float(np.sqrt(np.mean((run["psi_hat"][w] - run["psi"][w]) ** 2))),
        compass_error_rms=float(np.sqrt(np.mean((run["y"][w] - run["psi"][w]) ** 2))),
        bias_estimate=float(np.mean(run["b_hat"][w])),
        heading_swing=float(np.ptp(run["psi"][w])),
        steady_window=(float(t0), float(t[-1])),
    )


def default_scenarios(config: AutopilotConfig, plant_K: float | None = None, plant_T: float | None = None,
                      duration: float = 600.0, current_bias: float = DEFAULT_CURRENT_BIAS,
                      psi_ref: float = DEFAULT_STEP, seed: int = 1) -> tuple[Scenario, ...]:
    """The two standard scenarios: the identified model in calm water, and the sea.

    Parameters
    ----------
    config : AutopilotConfig
        Gives the identified K, T, the wave model and R.
    plant_K, plant_T : float, optional
        Ship for the ``sea`` scenario (the vessel config's truth when known); default the identified.
    duration : float
        Simulated time [s].
    current_bias : float
        Current as rudder bias in the ``sea`` scenario [rad].
    psi_ref : float
        Heading step [rad].
    seed : int
        Generator seed.

    Returns
    -------
    tuple of Scenario
        ``model`` (identified model, no current, waves or noise) and ``sea`` (current, waves, noise).
    """
    k = config.K if plant_K is None else plant_K
    t = config.T if plant_T is None else plant_T
    return (
        Scenario(name="model", K=config.K, T=config.T, duration=duration, psi_ref=psi_ref,
                 description="identified Nomoto model, calm water, no noise"),
        Scenario(name="sea", K=k, T=t, duration=duration, psi_ref=psi_ref, current_bias=current_bias,
                 waves=config.waves, noise_var=config.kalman.r, seed=seed,
                 description=(f"{'vessel-config' if plant_K is not None else 'identified'} Nomoto model with "
                              f"current ({math.degrees(current_bias):.1f} deg rudder bias), waves "
                              f"(omega0 {config.waves.omega0:.3g} rad/s, lambda {config.waves.lam:.3g}) "
                              f"and compass noise ({math.degrees(math.sqrt(config.kalman.r)):.3g} deg RMS)")),
    )


def closed_loop_check(config: AutopilotConfig, scenarios: tuple[Scenario, ...] | None = None) -> ClosedLoopCheck:
    """Run every case of :data:`CASES` in every scenario (default :func:`default_scenarios`).

    Parameters
    ----------
    config : AutopilotConfig
        Controller, filter, rudder limits.
    scenarios : tuple of Scenario, optional
        Experiments.

    Returns
    -------
    ClosedLoopCheck
        Runs and metrics.
    """
    scen = tuple(scenarios) if scenarios is not None else default_scenarios(config)
    runs = tuple(simulate_heading_loop(config, s, c) for s in scen for c in CASES)
    return ClosedLoopCheck(scenarios=scen, runs=runs)

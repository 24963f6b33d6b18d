"""What the diagnosis analyses: one :class:`DofProblem` per excited DOF, cut into windows.

A window is a stretch of the trial that one or more overlapping segments cover; the model is
re-initialised at each window start from the measured state and driven by the recorded inputs.
Every DOF is replayed over every window (a yaw model during a sway step predicts no yaw: if the
boat turns anyway, that is a coupling gap). Long windows are cut into time blocks so that the
cross-validation has enough independent pieces.

A DOF with a measured channel is analysed whether or not it has an input of its own: a sway with
no sway force and no free decay of its own, moved only by the turns through coupling (a catamaran
whose sway the yaw rate drives), is replayed over the windows where it moves above its long-run
noise (:func:`_long_run_noise`: a sway speed derived from GNSS has noise correlated over several
samples). Its baseline is the first-order model with no input, a decay from the measured state
(the sway row of :mod:`pipeline.model.vessel5dof` when the mass and damping matrices have no sway-yaw
terms); the ``coupling`` candidate adds the other DOFs' velocities, and once selected it joins the
baseline, so that the next candidates (a quadratic damping, a current) are tested on top of it
(:mod:`pipeline.diagnose.selection`). A DOF faster than the log keeps blocks of at least
:data:`MIN_BLOCK_STEPS` steps.

Signals are block-averaged from the trial rate to an analysis step ``dt`` of about a twentieth of
the DOF's time constant (capped so that the wave band stays resolved), which keeps the refits fast
on long trials without losing the dynamics: averaging is a proper anti-alias filter, and the
models predict block averages exactly (see :mod:`pipeline.diagnose.gridfit`).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property
from typing import Mapping

import numpy as np

from ..errors import DiagnoseError
from ..fit.data import first_present_channel
from ..records import Gap, Segment, Segments, Trial
from ..segment import noise_std
from ..segment.replay import gaps_of
from ..vessel import Actuator, Vessel
from .actuators import ActuatorSpace, actuator_key, actuator_space, held_input

#: DOF name -> response (velocity) channels in order of preference. A boat without a heading
#: sensor still has speed over ground, which is surge speed when it goes straight.
RESPONSE: Mapping[str, tuple[str, ...]] = {
    "surge": ("u", "sog"), "sway": ("v",), "yaw": ("r",), "roll": ("p",), "pitch": ("q",),
}
#: DOF name -> generalised-force input channel.
FORCE: Mapping[str, str] = {"surge": "tau_x", "sway": "tau_y", "yaw": "tau_n", "roll": "tau_k", "pitch": "tau_m"}
#: Velocity channels the coupling candidate may use as regressors.
VELOCITIES = ("u", "v", "p", "q", "r")
#: DOF -> the velocity that drives it through coupling when it has no input of its own (sizes its
#: time constant, :func:`_problem`): sway is moved by the turns.
COUPLING_DRIVERS: Mapping[str, tuple[str, ...]] = {"sway": ("r",), "yaw": ("v",)}
#: Largest analysis step [s]: keeps the Nyquist frequency (pi/dt) above pi rad/s, so the wave band
#: of a ship (0.3-1.5 rad/s) stays resolved even when its time constant is a minute.
DT_MAX = 1.0
#: Analysis steps per time constant.
STEPS_PER_T = 20.0
#: Longest window, in time constants, of a DOF's own manoeuvre before it is cut into blocks: the
#: cross-validation needs several pieces even when a DOF has a single step (AAUSHIP sway).
BLOCK_T = 2.5
#: Shortest block [analysis steps] a DOF's own window is cut into (:func:`_blocks`): windows under 4
#: steps are dropped, so a DOF whose time constant is under the log interval keeps blocks of this
#: many steps (5: the integer block edges leave at least 4). Not more: where ``BLOCK_T`` time
#: constants are a few steps, longer blocks leave fewer pieces (8 steps took seed 45 r020's sway,
#: AAUSHIP at 7.7 Hz, from 27 windows to 17 and lost its quadratic damping, p 2e-8 -> 0.03).
MIN_BLOCK_STEPS = 5


@dataclass(frozen=True)
class Window:
    """One stretch of the trial replayed from its measured initial state.

    Attributes
    ----------
    i0, i1 : int
        Trial sample range ``[i0, i1)``.
    t0, t1 : float
        Start and end [s, trial clock].
    kinds : tuple[str, ...]
        Kinds of the segments covering it (``step``, ``coast_down``, ...), time-ordered.
    dofs : tuple[str, ...]
        DOFs of the segments covering it.
    label : str
        Short description (for figures).
    """

    i0: int
    i1: int
    t0: float
    t1: float
    kinds: tuple[str, ...]
    dofs: tuple[str, ...] = ()
    label: str = ""


@dataclass(frozen=True)
class DofProblem:
    """Everything the refits of one DOF need, on the analysis grid.

    Attributes
    ----------
    dof : str
        DOF name (surge, sway, yaw, ...).
    channel : str
        Response channel (``u``, ``v``, ``r``, ``sog``).
    angle : str or None
        Attitude channel integrated from the response (``psi`` for yaw) or None.
    heading : str or None
        Heading used to rotate a current into the body frame (``psi``, else ``cog``).
    inputs : tuple[str, ...]
        Input channels that drive the DOF.
    regressors : tuple[str, ...]
        Other DOFs' measured velocities offered to the coupling candidate.
    fs : float
        Trial rate [Hz].
    m : int
        Trial samples per analysis sample.
    dt : float
        Analysis step [s] (``m / fs``).
    windows : tuple[Window, ...]
        Windows (after cutting into blocks), time-ordered.
    t_guess : float
        Time constant [s] of the first quick fit that sized ``dt``.
    raw : Mapping[str, numpy.ndarray]
        Trial-rate signals: inputs (NaN filled with the last value, then 0), the response, the
        angle and heading (unwrapped), regressors.
    noise : Mapping[str, float]
        White-noise standard deviation of each output channel at the trial rate [SI].
    stated_noise : Mapping[str, float]
        Output channels' white noise per sample stated in the vessel config (``[sensor_noise]``)
        [SI]; empty when none is stated.
    derived_from : str or None
        For a body velocity that was not logged but derived from GNSS speed and course and the
        heading (:func:`derived_velocity`): the channels it came from; None for a measured one.
    actuators : tuple[pipeline.vessel.Actuator, ...]
        Actuators that drive the DOF's inputs (actuator space, :mod:`pipeline.diagnose.actuators`),
        their gains restricted to these inputs; their signals are in ``raw`` under
        :func:`pipeline.diagnose.actuators.actuator_key`. Empty when the candidates act on the inputs.
    noise_unit : Mapping[str, float]
        Output channel -> noise per analysis step [SI] to use as the channel's noise unit instead of
        measuring it (:func:`pipeline.diagnose.gridfit.grid_data`); empty (the default): measured. Set
        only by a diagnosis on another trial's frame (:mod:`pipeline.diagnose.frame`).
    """

    dof: str
    channel: str
    angle: str | None
    heading: str | None
    inputs: tuple[str, ...]
    regressors: tuple[str, ...]
    fs: float
    m: int
    dt: float
    windows: tuple[Window, ...]
    t_guess: float
    raw: Mapping[str, np.ndarray] = field(repr=False)
    noise: Mapping[str, float] = field(default_factory=dict)
    derived_from: str | None = None
    stated_noise: Mapping[str, float] = field(default_factory=dict)
    actuators: tuple = ()
    noise_unit: Mapping[str, float] = field(default_factory=dict)

    @property
    def outputs(self) -> tuple[str, ...]:
        """Output channels scored: the response and, for yaw, the heading."""
        return (self.channel,) + ((self.angle,) if self.angle else ())

    @cached_property
    def n(self) -> int:
        """Longest window in analysis samples."""
        return max(len_blocks(w, self.m) for w in self.windows)


def len_blocks(w: Window, m: int) -> int:
    """Analysis samples in window ``w`` at ``m`` trial samples each.

    Parameters
    ----------
    w : Window
        The window.
    m : int
        Trial samples per analysis sample.
    """
    return (w.i1 - w.i0) // m


def block_average(x: np.ndarray, windows: tuple[Window, ...], m: int, n: int, trapezoid: bool = False) -> np.ndarray:
    """Block means of ``m`` trial samples per analysis sample, one row per window, NaN-padded.

    Parameters
    ----------
    x : numpy.ndarray, shape (N,)
        Trial-rate signal.
    windows : tuple[Window, ...]
        Windows.
    m : int
        Samples per block.
    n : int
        Columns of the output (longest window).
    trapezoid : bool
        For point samples of a state: weight the block's first sample and the next block's first
        sample by 1/2, which makes the mean that of the state over ``[t_k, t_k + dt)``, the
        interval the model's exact block means and the held inputs refer to. A plain mean of the
        samples ``t_k ... t_k + dt - h`` is that average half a sample early, a lag that a delay
        candidate would otherwise "explain". Inputs (held over each sample) use plain means.

    Returns
    -------
    numpy.ndarray, shape (len(windows), n)
        NaN where a window is shorter or every sample of a block is missing.
    """
    out = np.full((len(windows), n), np.nan)
    for k, w in enumerate(windows):
        nb = len_blocks(w, m)
        if nb == 0:
            continue
        seg = x[w.i0:w.i0 + nb * m].reshape(nb, m)
        if trapezoid:
            after = w.i0 + m * np.arange(1, nb + 1)
            nxt = np.where(after < len(x), x[np.minimum(after, len(x) - 1)], np.nan)
            # Where the closing sample is missing, the block's own last sample stands in.
            nxt = np.where(np.isfinite(nxt), nxt, seg[:, -1])
            seg = np.concatenate([0.5 * seg[:, :1], seg[:, 1:], 0.5 * nxt[:, None]], axis=1)
        ok = np.isfinite(seg)
        # Weights: a trapezoid's two half samples count as one sample between them.
        cnt = ok.sum(axis=1) - (1.0 if trapezoid else 0.0)
        s = np.where(ok, seg, 0.0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[k, :nb] = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    return out


#: Input moments kept for reuse (:func:`input_moments`), newest last: ``(u, windows, m, n) -> moments``.
_MOMENTS: "OrderedDict[tuple[int, int, int, int], tuple[np.ndarray, tuple, np.ndarray]]" = OrderedDict()
#: How many :func:`input_moments` results are kept.
MOMENTS_KEPT = 8


def input_moments(u: np.ndarray, windows: tuple[Window, ...], m: int, n: int) -> np.ndarray:
    """Moments of a held input within each block: ``sum u_j``, ``sum (m-1-j) u_j``, ``sum (m-1-j)^2 u_j``.

    They let :mod:`pipeline.diagnose.gridfit` weight the samples of a block by how long each acts
    before the block ends (an input switching inside a block, as a zig-zag's does), to second order
    in ``h / T``, for any time constant T.

    The last :data:`MOMENTS_KEPT` results are kept by the identity of ``u`` and ``windows``: a call
    with the same objects returns the kept (read-only) result, and a call with another input
    that equals a kept one on some windows (a delayed or rate-limited copy of it, which differs
    only around the input's changes) computes only the other windows. Every window's numbers come
    from the same operations on the same samples either way, so they do not depend on what was kept.

    Parameters
    ----------
    u : numpy.ndarray
        Held input on the trial grid [SI]; not modified afterwards (what is kept is found by its
        identity).
    windows : tuple[Window, ...]
        Windows.
    m : int
        Samples per block.
    n : int
        Blocks of the longest window.

    Returns
    -------
    numpy.ndarray, shape (3, len(windows), n)
        Zero-padded; NaN inputs count as zero. Read-only.
    """
    key = (id(u), id(windows), int(m), int(n))
    kept = _MOMENTS.get(key)
    if kept is not None and kept[0] is u and kept[1] is windows:
        _MOMENTS.move_to_end(key)
        return kept[2]
    src = u
    u = np.asarray(u, float)
    base = _closest_kept(u, windows, m, n) if isinstance(src, np.ndarray) else None
    todo = range(len(windows))
    if base is None:
        out = np.zeros((3, len(windows), n))
    else:
        out = base[1].copy()
        todo = _windows_differing(u, base[0], windows, m)
    lag = (m - 1 - np.arange(m)).astype(float)
    lag2 = lag**2
    u = np.where(np.isfinite(u), u, 0.0) if not np.isfinite(u).all() else u
    # Each window's blocks through the same reductions as ever (a window's products are a BLAS call of
    # its own: stacking windows into one call changes how BLAS groups rows, hence the last bits),
    # written in place.
    o0, o1, o2 = out
    for k in todo:
        w = windows[k]
        nb = len_blocks(w, m)
        if nb == 0:
            continue
        seg = u[w.i0:w.i0 + nb * m].reshape(nb, m)
        np.add.reduce(seg, axis=1, out=o0[k, :nb])
        np.matmul(seg, lag, out=o1[k, :nb])
        np.matmul(seg, lag2, out=o2[k, :nb])
    out.setflags(write=False)
    if isinstance(src, np.ndarray):
        _MOMENTS[key] = (src, windows, out)
        while len(_MOMENTS) > MOMENTS_KEPT:
            _MOMENTS.popitem(last=False)
    return out


#: Samples compared to choose the kept input an input is closest to (:func:`input_moments`).
PROBES = 256


def _closest_kept(u: np.ndarray, windows: tuple[Window, ...], m: int, n: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The kept ``(input, moments)`` of the same windows and blocks that equals ``u`` on the most of
    :data:`PROBES` evenly spaced samples (at least half of them), or None."""
    best, best_hits = None, 0
    stride = max(len(u) // PROBES, 1)
    probe = u[::stride]
    for (_, _, km, kn), (src, wins, out) in _MOMENTS.items():
        if wins is not windows or km != m or kn != n or src.shape != u.shape or src.dtype != u.dtype:
            continue
        hits = int(np.count_nonzero(src[::stride] == probe))
        if hits > best_hits:
            best, best_hits = (src, out), hits
    return best if 2 * best_hits >= len(probe) else None


def _windows_differing(u: np.ndarray, v: np.ndarray, windows: tuple[Window, ...], m: int) -> list[int]:
    """Windows whose block samples differ between float64 arrays ``u`` and ``v`` in any bit (a
    signed zero or a NaN's payload counts)."""
    i0, i1 = _block_spans(windows, m)
    lo, hi = (int(i0.min()), int(i1.max())) if len(i0) else (0, 0)
    diff = lo + np.flatnonzero(u[lo:hi].view(np.int64) != v[lo:hi].view(np.int64))
    hit = np.searchsorted(diff, i1) > np.searchsorted(diff, i0)
    return np.flatnonzero(hit).tolist()


#: :func:`_block_spans` results by ``(id(windows), m)``, with the windows they are of.
_SPANS: dict[tuple[int, int], tuple[tuple, tuple[np.ndarray, np.ndarray]]] = {}


def _block_spans(windows: tuple[Window, ...], m: int) -> tuple[np.ndarray, np.ndarray]:
    """First and one-past-last trial sample of each window's whole blocks (kept per windows object)."""
    kept = _SPANS.get((id(windows), m))
    if kept is not None and kept[0] is windows:
        return kept[1]
    i0 = np.array([w.i0 for w in windows], int)
    spans = (i0, i0 + np.array([len_blocks(w, m) for w in windows], int) * m)
    if len(_SPANS) >= MOMENTS_KEPT:
        _SPANS.clear()
    _SPANS[(id(windows), m)] = (windows, spans)
    return spans


def _contrasts(x: np.ndarray, windows: tuple[Window, ...], q: int, mb: int | None = None) -> np.ndarray:
    """Contrasts ``q1 - q2 - q3 + q4`` of the means of four consecutive ``q``-sample quarters, one
    per block of ``mb >= 4 q`` samples (default ``4 q``) of each window."""
    mb = 4 * q if mb is None else mb
    cs = []
    for w in windows:
        nb = (w.i1 - w.i0) // mb
        if nb == 0:
            continue
        blk = x[w.i0:w.i0 + nb * mb].reshape(nb, mb)[:, :4 * q].reshape(nb, 4, q).mean(axis=2)
        cs.append(blk[:, 0] - blk[:, 1] - blk[:, 2] + blk[:, 3])
    c = np.concatenate(cs) if cs else np.zeros(0)
    return c[np.isfinite(c)]


def _third_differences(x: np.ndarray, windows: tuple[Window, ...], q: int) -> np.ndarray:
    """Third differences ``b1 - 3 b2 + 3 b3 - b4`` of four consecutive ``q``-sample means: they cancel
    any quadratic within the block, so a manoeuvre leaks in only through its third derivative.
    For independent means of variance ``v`` they have variance ``20 v``."""
    mb = 4 * q
    cs = []
    for w in windows:
        nb = (w.i1 - w.i0) // mb
        if nb == 0:
            continue
        blk = x[w.i0:w.i0 + nb * mb].reshape(nb, 4, q).mean(axis=2)
        cs.append(blk[:, 0] - 3 * blk[:, 1] + 3 * blk[:, 2] - blk[:, 3])
    c = np.concatenate(cs) if cs else np.zeros(0)
    return c[np.isfinite(c)]


def _robust_sd(c: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(c - np.median(c))))


#: Ratio of the per-sample-equivalent noise at quarter size ``2q`` to that at ``q`` below which the
#: noise counts as white at that scale (white noise: 1; noise correlated over ``L`` samples rises
#: steeply until ``q`` is about ``L``; a smooth signal leaking in rises by about 2^2.5 per doubling).
WHITE_RATIO = 1.4
#: Longest quarter [trial samples] searched for the correlation scale of the noise.
MAX_QUARTER = 512


def noise_scale(x: np.ndarray, windows: tuple[Window, ...]) -> tuple[float, int]:
    """Long-run noise level and correlation scale of a channel whose noise is correlated over
    several trial samples (a 5 Hz GNSS speed interpolated to 50 Hz, a held sensor).

    The quarter contrast of :func:`block_noise` is measured at quarter sizes ``q = 1, 2, 4, ...``
    and expressed as the white noise per sample that would give it, ``s(q) = sd(contrast) sqrt(q) / 2``.
    White noise gives the same ``s`` at every ``q``. Noise that is smooth over ``L`` samples
    (interpolated or held between the sensor's own samples) gives a contrast near zero at ``q << L``
    (a straight piece cancels) and reaches a plateau ``s_inf`` (its long-run standard deviation,
    ``sqrt`` of the spectral density at zero) once ``q`` is about ``L`` to ``2 L``; a smooth signal
    leaking into the contrast keeps rising instead. The noise counts as correlated when ``s(2)``
    exceeds ``s(1)`` by ``WHITE_RATIO`` and a plateau (a doubling of ``q`` that raises ``s`` by less
    than ``WHITE_RATIO``) follows.

    Parameters
    ----------
    x : numpy.ndarray
        Trial-rate signal.
    windows : tuple[Window, ...]
        Windows to measure it in.

    Returns
    -------
    (s_inf, q_star) : (float, int)
        Long-run noise standard deviation per sample [unit of x] and the quarter size [samples] at
        which the plateau begins; ``(nan, 1)`` when the noise is white at the trial rate or no
        plateau is found (a noise-free signal).
    """
    def s_of(q: int) -> float:
        c = _third_differences(x, windows, q)
        return _robust_sd(c) * np.sqrt(q / 20.0) if len(c) >= 16 else float("nan")

    s1, s2 = s_of(1), s_of(2)
    if not (np.isfinite(s1) and np.isfinite(s2)) or (s1 > 0 and s2 <= WHITE_RATIO * s1):
        return float("nan"), 1
    q, s_q = 2, s2
    while 2 * q <= MAX_QUARTER:
        s_next = s_of(2 * q)
        if not np.isfinite(s_next):
            break
        if s_q > 0 and s_next < WHITE_RATIO * s_q:
            return float(max(s_q, s_next)), q
        q, s_q = 2 * q, s_next
    return float("nan"), 1


#: Fewest quarter contrasts (blocks of ``max(m, 8)`` samples) from which :func:`block_noise`
#: measures a channel's white noise.
MIN_CONTRASTS = 8


def noise_measurable(x: np.ndarray, windows: tuple[Window, ...], m: int) -> bool:
    """Whether the windows hold enough blocks for :func:`block_noise` to measure the noise of
    ``m``-sample block means of ``x`` from the data (else only a stated noise, or the whole log,
    gives it: :func:`noise_source`).

    Parameters
    ----------
    x : numpy.ndarray
        Trial-rate signal.
    windows : tuple[Window, ...]
        Windows to measure it in.
    m : int
        Samples per block.
    """
    mb = max(m, 8)
    return len(_contrasts(x, windows, mb // 4, mb)) >= MIN_CONTRASTS


def _whole_log(x: np.ndarray) -> tuple[Window, ...]:
    """One window spanning every sample of ``x`` (the whole-log fallback of :func:`block_noise`)."""
    return (Window(0, len(x), 0.0, float(len(x)), ("whole log",), (), "whole log"),)


def noise_source(x: np.ndarray, windows: tuple[Window, ...], m: int, stated: float | None = None) -> str:
    """Where :func:`block_noise` takes the noise of ``x`` from: ``"windows"`` (measured in the DOF's
    windows), ``"stated"`` (the vessel config's ``[sensor_noise]`` alone: the windows are too short),
    ``"whole log"`` (measured over the whole log: the windows are too short and nothing is stated)
    or ``"none"`` (NaN).

    Parameters
    ----------
    x, windows, m, stated
        As for :func:`block_noise`.
    """
    if noise_measurable(x, windows, m):
        return "windows"
    if stated is not None and np.isfinite(stated) and stated > 0:
        return "stated"
    return "whole log" if noise_measurable(x, _whole_log(x), m) else "none"


def block_noise(x: np.ndarray, windows: tuple[Window, ...], m: int, trapezoid: bool = False,
                stated: float | None = None, whole_log: bool = True) -> float:
    """White-noise standard deviation of an ``m``-sample block mean of ``x`` [SI].

    Blocks of ``mb = max(m, 8)`` samples are split in quarters and the contrast
    ``q1 - q2 - q3 + q4`` of the quarter means is taken: it cancels any level and slope within the
    block, and for noise of variance ``s^2`` per sample it has variance ``16 s^2 / mb``, sixteen
    times that of the block mean. Robust (median absolute deviation), so manoeuvres and outliers
    do not inflate it; scaled from the ``4 q`` samples the contrast spans to ``m`` as white noise.

    Noise correlated over several trial samples (a sensor interpolated or held to the trial rate:
    body velocities derived from a 5 Hz GNSS in a 50 Hz trial) has almost no contrast at the
    block's own scale; it is measured at its own correlation scale instead (:func:`noise_scale`):
    the block mean's standard deviation is ``s_inf / sqrt(max(m, 0.75 q_star))``, the long-run
    level spread over ``m`` samples, or over the noise's own correlation length (about
    ``q_star / 2`` to ``q_star``) when the block is shorter than that.

    Where the windows hold fewer than ``MIN_CONTRASTS`` blocks of ``mb`` samples (a DOF faster than
    the log, cut into windows of a few samples: the twin's yaw at 1-2 Hz), a stated noise is used
    alone (below); without one, and with ``whole_log``, the same contrasts are taken over the whole
    log as one window, manoeuvres of every DOF and the quiet stretches between them: the robust
    spread is the quiet stretches' (randomised seed 43 r008, the twin at 1.92 Hz with r and psi
    noise 0.004 and 0.006 per sample: 0.0049 and 0.0069 from the whole log, none from the windows).
    :func:`noise_source` says which of the three gave it.

    Parameters
    ----------
    x : numpy.ndarray
        Trial-rate signal.
    windows : tuple[Window, ...]
        Windows to measure it in.
    m : int
        Samples per block.
    trapezoid : bool
        The block means are trapezoidal (:func:`block_average` with ``trapezoid=True``): weights
        ``1/2, 1, ..., 1, 1/2`` over ``m + 1`` samples, variance ``(m - 1/2) s^2 / m^2`` instead
        of ``s^2 / m`` (half a sample's at ``m = 1``) for white noise.
    stated : float, optional
        The sensor's white noise per sample as stated in the vessel config (``[sensor_noise]``)
        [unit of x]. The white part of the estimate is at most this: the contrast takes in
        whatever moves within ``mb`` samples, and a wave a few samples per period (a heading logged
        at 1-3 Hz) counts as noise there (a 1.3 deg heading wave at 1.1 Hz raised a 0.002 rad
        compass to a floor of 0.026 rad). A sensor better than stated keeps its measured floor;
        a noise correlated over several samples keeps its measured long-run level. Where the
        windows hold fewer than ``MIN_CONTRASTS`` blocks of ``mb`` samples, the data cannot
        measure the white part in them and the stated noise is used alone.
    whole_log : bool
        Fall back on the whole log where the windows cannot measure it and nothing is stated.

    Returns
    -------
    float
        The block mean's noise [unit of x]; NaN when neither the windows nor the whole log can
        measure it and none is stated.
    """
    mb = max(m, 8)
    q = mb // 4
    c = _contrasts(x, windows, q, mb)
    told = stated is not None and np.isfinite(stated) and stated > 0
    if len(c) < MIN_CONTRASTS and not told and whole_log and len(x):
        windows = _whole_log(x)
        c = _contrasts(x, windows, q, mb)
    if len(c) < MIN_CONTRASTS and not told:
        return float("nan")
    white = float("inf")
    if len(c) >= MIN_CONTRASTS:
        # The contrast uses the first 4 q of the mb samples: it measures a 4q-sample block mean.
        s_mb = _robust_sd(c) / 4.0
        s_m = s_mb * np.sqrt(4 * q / m)
        white = float(s_m * np.sqrt((m - 0.5) / m) if trapezoid else s_m)
    if told:
        own = stated / np.sqrt(m)
        white = min(white, float(own * np.sqrt((m - 0.5) / m) if trapezoid else own))
    s_inf, q_star = noise_scale(x, windows)
    if np.isfinite(s_inf):
        if told:
            # A sensor of that noise held or interpolated over about 0.75 q_star trial samples
            # has the long-run level stated sqrt(0.75 q_star); more is not noise.
            s_inf = min(s_inf, float(stated * np.sqrt(max(0.75 * q_star, 1.0))))
        coloured = float(s_inf / np.sqrt(max(m, 0.75 * q_star)))
        return max(white, coloured)
    return white


def initial_values(x: np.ndarray, windows: tuple[Window, ...], half: int) -> np.ndarray:
    """Measured value at each window start [SI]: a straight line through the ``2 half + 1``
    samples ending there, evaluated at the start.

    One-sided because a window starts where an input changes, so the response has a kink there
    (a zig-zag's reversal is a peak: a median across it is biased). The samples after the start
    are used only when there are none before it (the start of the data, or after a dropout).

    Parameters
    ----------
    x : numpy.ndarray
        Trial-rate signal.
    windows : tuple[Window, ...]
        Windows.
    half : int
        The line runs through ``2 half + 1`` samples; 0: the sample at the start itself.
    """
    out = np.empty(len(windows))
    span = 2 * half + 1
    for k, w in enumerate(windows):
        if half <= 0 and w.i0 < len(x) and np.isfinite(x[w.i0]):
            out[k] = float(x[w.i0])
            continue
        for lo, hi in ((w.i0 - span + 1, w.i0 + 1), (w.i0, w.i0 + span)):
            lo, hi = max(lo, 0), min(hi, len(x))
            idx = np.arange(lo, hi)
            vals = x[lo:hi]
            ok = np.isfinite(vals)
            if ok.sum() >= 3:
                c = np.polyfit(idx[ok] - w.i0, vals[ok], 1)
                out[k] = float(c[1])
                break
        else:
            after = x[w.i0:w.i1]
            after = after[np.isfinite(after)]
            out[k] = after[0] if len(after) else 0.0
    return out


def _unwrap_nan(x: np.ndarray) -> np.ndarray:
    out = np.asarray(x, float).copy()
    ok = np.isfinite(out)
    if ok.sum() > 1:
        out[ok] = np.unwrap(out[ok])
    return out


def _merge_windows(trial: Trial, segments: tuple[Segment, ...]) -> list[Window]:
    """Overlapping segments merge into one window; merely adjacent ones stay apart."""
    fs = trial.fs
    t = trial.t
    spans = sorted((s.t_start, s.t_end, s.kind, s.dof) for s in segments if s.t_end > s.t_start)
    merged: list[list] = []
    tol = 0.5 / fs
    for a, b, kind, dof in spans:
        if merged and a < merged[-1][1] - tol:
            merged[-1][1] = max(merged[-1][1], b)
            merged[-1][2].append(kind)
            merged[-1][3].append(dof)
        else:
            merged.append([a, b, [kind], [dof]])
    out = []
    for a, b, kinds, dofs in merged:
        i0 = int(np.searchsorted(t, a - tol))
        i1 = int(np.searchsorted(t, b + tol))
        if i1 - i0 < 4:
            continue
        out.append(Window(i0, i1, float(t[i0]), float(t[i1 - 1]), tuple(dict.fromkeys(kinds)),
                          tuple(dict.fromkeys(dofs)), "+".join(dict.fromkeys(kinds))))
    return out


def _cut_gaps(trial: Trial, windows: list[Window], gaps: tuple[Gap, ...]) -> list[Window]:
    """A window never spans a dropout of a channel it uses (``gaps``): cut it at the gap."""
    out = []
    t = trial.t
    for w in windows:
        pieces = [(w.i0, w.i1)]
        for g in gaps:
            nxt = []
            for a, b in pieces:
                ga = int(np.searchsorted(t, g.t_start))
                gb = int(np.searchsorted(t, g.t_end))
                if ga >= b or gb <= a:
                    nxt.append((a, b))
                    continue
                if ga - a >= 4:
                    nxt.append((a, ga))
                if b - gb >= 4:
                    nxt.append((gb, b))
            pieces = nxt
        out += [Window(a, b, float(t[a]), float(t[b - 1]), w.kinds, w.dofs, w.label) for a, b in pieces]
    return out


def _blocks(windows: list[Window], own: list[Window], t_const: float, t: np.ndarray,
            shortest: float = 0.0) -> list[Window]:
    """Cut the DOF's own windows longer than ``BLOCK_T`` time constants into equal blocks.

    Windows where the DOF is only a bystander stay whole: cutting them would only add pieces in
    which nothing happens. No block is shorter than ``shortest`` [s]: a DOF faster than the log
    (AAUSHIP sway, T = 0.4 s, in a 1.7 Hz log) would otherwise be cut into blocks of one or two
    samples, each too short to replay, and the DOF dropped (randomised seed 41 r021).
    """
    out = []
    limit = max(BLOCK_T * t_const, shortest)
    for w in windows:
        length = w.t1 - w.t0
        k = int(length // limit) if limit > 0 and w in own else 1
        if k <= 1:
            out.append(w)
            continue
        edges = np.linspace(w.i0, w.i1, k + 1).astype(int)
        for j in range(k):
            a, b = int(edges[j]), int(edges[j + 1])
            out.append(Window(a, b, float(t[a]), float(t[b - 1]), w.kinds, w.dofs, f"{w.label} ({j + 1}/{k})"))
    return out


def dof_inputs(trial: Trial, vessel: Vessel | None, dof: str) -> tuple[str, ...]:
    """Input channels that drive ``dof`` and vary in the trial.

    Parameters
    ----------
    trial : Trial
        The trial.
    vessel : Vessel or None
        Its config (a rudder with a sway force also drives sway).
    dof : str
        DOF name.
    """
    names = [FORCE[dof]]
    if dof == "yaw":
        names.append("delta")
    if dof == "sway" and vessel is not None and vessel.rudder.get("sway_force"):
        names.append("delta")
    out = []
    for c in names:
        if trial.has(c):
            u = trial.data[c].to_numpy()
            if np.nanmax(np.abs(u)) > 0:
                out.append(c)
    return tuple(out)


def quick_time_constant(y: np.ndarray, u: np.ndarray | None, fs: float, windows: list[Window]) -> float:
    """Rough time constant [s]: least squares of y_dot = (-y + k u)/T on smoothed data.

    Equation error on derivatives is biased by noise, but it only sizes the analysis step and the
    search ranges, so a factor of two is of no consequence.

    Parameters
    ----------
    y : numpy.ndarray
        Response on the trial grid [SI].
    u : numpy.ndarray or None
        Summed normalised inputs, or None for free decays.
    fs : float
        Trial rate [Hz].
    windows : list[Window]
        Windows to use.
    """
    rows_d, rows_y, rows_u = [], [], []
    w_s = max(int(0.05 * fs), 1)
    kernel = np.ones(w_s) / w_s
    for w in windows:
        yy = y[w.i0:w.i1]
        if len(yy) < 3 * w_s + 3 or not np.all(np.isfinite(yy)):
            continue
        ys = np.convolve(yy, kernel, mode="same")
        d = np.gradient(ys) * fs
        sl = slice(w_s, len(yy) - w_s)
        rows_d.append(d[sl])
        rows_y.append(ys[sl])
        rows_u.append(u[w.i0:w.i1][sl] if u is not None else np.zeros(len(ys[sl])))
    if not rows_d:
        return np.nan
    d, yv, uv = (np.concatenate(r) for r in (rows_d, rows_y, rows_u))
    a = np.column_stack([yv, uv, np.ones_like(yv)]) if u is not None else np.column_stack([yv, np.ones_like(yv)])
    coef, *_ = np.linalg.lstsq(a, d, rcond=None)
    if coef[0] >= 0:
        return np.nan
    return float(-1.0 / coef[0])


#: Longest input delay searched, in time constants (the delay candidate's range).
INPUT_HISTORY_T = 0.6


def _after_record_starts(trial: Trial, windows: list[Window], hist: float, keep_all: bool = False,
                         gaps: tuple[Gap, ...] | None = None) -> list:
    """Move window starts that lie within ``hist`` seconds after the start of the record (or the
    end of a dropout or run gap; of ``gaps``, default every gap of the trial) to ``hist`` seconds
    after it.

    A delayed input needs its history: what the actuators did before the record began is not
    logged, and a model that assumes the first logged value was acting all along turns a step
    from rest at the first sample into a spurious "no delay". Replay never integrates across a
    gap, so every run start is a record start. (Assumption kept explicit: runs of one trial are
    laid end to end on the trial clock with a gap between them.) With ``keep_all`` a window that
    becomes too short is returned as None in its place.
    """
    t = trial.t
    starts = [float(t[0])] + [float(g.t_end) for g in (trial.gaps if gaps is None else gaps)]
    out = []
    for w in windows:
        s0 = max((s for s in starts if s <= w.t0 + 1e-9), default=float(t[0]))
        if w.t0 - s0 < hist:
            i0 = int(np.searchsorted(t, s0 + hist))
            if w.i1 - i0 < 4:
                if keep_all:
                    out.append(None)
                continue
            w = Window(i0, w.i1, float(t[i0]), w.t1, w.kinds, w.dofs, w.label)
        out.append(w)
    return out


#: Most analysis samples per DOF problem (over all windows): bounds the cost of a refit on long
#: trials; the step grows beyond T/20 only when the windows are longer than this many steps.
MAX_SAMPLES = 12000


def build_problems(trial: Trial, segments: Segments, vessel: Vessel | None = None,
                   dofs: tuple[str, ...] = ("surge", "sway", "yaw"),
                   time_constants: Mapping[str, float] | None = None) -> list[DofProblem]:
    """One :class:`DofProblem` per DOF that the trial excites and measures.

    Parameters
    ----------
    trial : Trial
        Aligned trial.
    segments : Segments
        Its segments (detected or from a manifest).
    vessel : Vessel, optional
        Vessel config (decides whether the rudder also pushes sideways).
    dofs : tuple[str, ...]
        DOFs to consider.
    time_constants : Mapping[str, float], optional
        Time constant per DOF [s] from a first fit; sizes the analysis step and the blocks.
        Default: a rough equation-error estimate.

    Returns
    -------
    list[DofProblem]
        Possibly empty when no DOF is both excited and measured.

    Raises
    ------
    DiagnoseError
        When the trial has no segments at all.
    """
    if not segments.items:
        raise DiagnoseError(f"{trial.name}: expected at least one segment (coast-down, step, zig-zag, decay) "
                            f"to replay, found none")
    base = _merge_windows(trial, segments.items)
    space = actuator_space(trial, vessel)
    problems = []
    for dof in dofs:
        p = _problem(trial, vessel, dof, base, (time_constants or {}).get(dof), space)
        if p is not None:
            problems.append(p)
    return problems


def derived_velocity(trial: Trial, channel: str) -> str | None:
    """The channels a body velocity ``u`` or ``v`` was derived from, or None when it was logged.

    Align derives ``u = sog cos(cog - psi)`` and ``v = sog sin(cog - psi)`` where no body velocity
    is logged (:mod:`pipeline.align`); such a channel carries the heading's motion (waves on the
    heading appear in it multiplied by the speed) and the GNSS noise. Recognised from the data:
    the channel equals that expression to rounding.

    Parameters
    ----------
    trial : Trial
        The trial.
    channel : str
        ``u`` or ``v``.
    """
    if channel not in ("u", "v") or not all(trial.has(c) for c in ("sog", "cog", "psi")):
        return None
    x = trial.data[channel].to_numpy(float)
    sog, cog, psi = (trial.data[c].to_numpy(float) for c in ("sog", "cog", "psi"))
    beta = cog - psi
    y = sog * (np.cos(beta) if channel == "u" else np.sin(beta))
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 10:
        return None
    scale = max(float(np.max(np.abs(x[ok]))), 1e-9)
    return "sog, cog and psi" if float(np.max(np.abs(x[ok] - y[ok]))) < 1e-6 * scale else None


def _moves(y: np.ndarray, w: Window, noise: float) -> bool:
    """True when the response in ``w`` leaves the noise band (worth replaying for a bystander DOF)."""
    seg = y[w.i0:w.i1]
    seg = seg[np.isfinite(seg)]
    if len(seg) < 4:
        return False
    # 20-sample means: noise drops by sqrt(20), a steady offset or slow response does not.
    k = len(seg) // 20
    means = seg[:k * 20].reshape(k, 20).mean(axis=1) if k else seg
    return bool(np.percentile(np.abs(means), 95) > 6 * noise / np.sqrt(20 if k else 1))


#: Samples per mean of :func:`_long_run_noise`.
LONG_RUN_SAMPLES = 20


def _long_run_noise(y: np.ndarray, windows: list[Window]) -> float:
    """Per-sample noise [unit of y] that gives the noise of ``LONG_RUN_SAMPLES``-sample means as
    :func:`block_noise` measures it, correlated noise included.

    A sway speed derived from GNSS speed and course (5-10 Hz, interpolated to the trial rate) has noise
    correlated over several samples, which the sample-to-sample estimate (:func:`noise_std`) misses:
    a mean over 20 samples then keeps far more noise than ``noise / sqrt(20)``, and such noise alone
    would pass the "moves" and "excited" tests of a DOF driven only through coupling. 0 when it cannot
    be measured.
    """
    s = block_noise(y, tuple(windows), LONG_RUN_SAMPLES, whole_log=False) if windows else float("nan")
    return float(s * np.sqrt(LONG_RUN_SAMPLES)) if np.isfinite(s) else 0.0


def _excursion(x: np.ndarray, windows: list[Window], noise: float, fs: float) -> float:
    """Largest excursion of ``x`` from its median in any window, in units of the noise of means over
    half a second or a fiftieth of the window (so that a slow ship logged by a noisy gyro counts)."""
    peak = 0.0
    for w in windows:
        seg = x[w.i0:w.i1]
        seg = seg[np.isfinite(seg)]
        k_s = max(int(0.5 * fs), len(seg) // 50, 1)
        nb = len(seg) // k_s
        if nb < 2:
            continue
        means = seg[:nb * k_s].reshape(nb, k_s).mean(axis=1)
        peak = max(peak, float(np.max(np.abs(means - np.median(means)))) / (noise / np.sqrt(k_s)))
    return peak


def halves(w: Window, t: np.ndarray) -> list[Window]:
    """Window ``w`` cut in two halves (labelled ``(1/2)`` and ``(2/2)``).

    Parameters
    ----------
    w : Window
        The window.
    t : numpy.ndarray
        Trial clock [s].
    """
    mid = (w.i0 + w.i1) // 2
    return [Window(w.i0, mid, w.t0, float(t[mid - 1]), w.kinds, w.dofs, f"{w.label} (1/2)"),
            Window(mid, w.i1, float(t[mid]), w.t1, w.kinds, w.dofs, f"{w.label} (2/2)")]


def _windowing(trial: Trial, windows0: list[Window], own_w: list[Window], t_const: float, inputs: bool,
               gaps: tuple[Gap, ...]) -> tuple[tuple[Window, ...], int] | None:
    """The analysis windows and trial samples per analysis step of a DOF, or None when fewer than two
    windows of at least 4 steps are left.

    Window starts near a record start move on by the input history (when the DOF has ``inputs``); the
    step is a twentieth of ``t_const`` (within the bounds of :data:`DT_MAX` and :data:`MAX_SAMPLES`);
    the DOF's own windows ``own_w`` are cut into blocks (:func:`_blocks`); a lone window is halved.
    """
    fs, t = trial.fs, trial.t
    if inputs:
        # At most a quarter of the shortest own window is given up for the input history.
        shortest = min((w.t1 - w.t0 for w in (own_w or windows0)), default=0.0)
        hist = min(INPUT_HISTORY_T * t_const, 0.25 * shortest)
        moved = dict(zip(map(id, windows0), _after_record_starts(trial, windows0, hist, keep_all=True, gaps=gaps)))
        own_w = [moved[id(w)] for w in own_w if id(w) in moved and moved[id(w)] is not None]
        windows0 = [v for v in moved.values() if v is not None]
        if not windows0:
            return None
    total = sum(w.t1 - w.t0 for w in windows0)
    dt_target = min(max(t_const / STEPS_PER_T, 1.0 / fs, total / MAX_SAMPLES), DT_MAX)
    m = max(int(round(dt_target * fs)), 1)
    windows = [w for w in _blocks(windows0, own_w, t_const, t, MIN_BLOCK_STEPS * m / fs) if len_blocks(w, m) >= 4]
    if len(windows) == 1 and len_blocks(windows[0], m) >= 8:
        # Cross-validation needs two pieces at least: a lone window is cut in halves.
        windows = halves(windows[0], t)
    if len(windows) < 2:
        return None
    return tuple(windows), m


def _problem(trial: Trial, vessel: Vessel | None, dof: str, base: list[Window],
             t_const: float | None, space: ActuatorSpace | None = None) -> DofProblem | None:
    fs = trial.fs
    t = trial.t
    ch = first_present_channel(trial, RESPONSE[dof])
    if ch is None:
        return None
    inputs = dof_inputs(trial, vessel, dof)
    angle = "psi" if dof == "yaw" and trial.has("psi") else None
    heading = "psi" if trial.has("psi") else ("cog" if trial.has("cog") else None)
    # Only a dropout of a channel this DOF uses cuts its windows: a GNSS gap leaves a yaw record of
    # gyro, compass and rudder whole (a channel derived from GNSS, u from sog, is cut by it).
    gaps = gaps_of(trial, (ch, angle, heading, *inputs))
    base = _cut_gaps(trial, base, gaps)
    own_w = [w for w in base if dof in w.dofs]
    # Driven only through coupling: no input of its own and no segment of its own (no free decay was
    # found), but measured, and another DOF's velocity is logged that may drive it (a catamaran's sway
    # in turns). Its windows are those where it moves, well above the noise.
    coupled = not inputs and not own_w
    if coupled and not any(trial.has(c) for c in VELOCITIES if c != ch):
        return None
    y = trial.data[ch].to_numpy(float)
    noise = noise_std(y)
    if not np.isfinite(noise):
        return None
    noise = max(noise, 1e-12)
    if coupled:
        noise = max(noise, _long_run_noise(y, base))
    windows0 = [w for w in base if dof in w.dofs or _moves(y, w, noise)]
    if not windows0:
        return None
    if coupled:
        # Its own windows (cut into blocks for the cross-validation like a manoeuvre of its own).
        own_w = list(windows0)
    # Excited: some window moves the response, or the attitude it integrates to (the heading), well
    # above its noise: a small ship's turn at high gyro noise hardly leaves the gyro's noise, but
    # the compass sees its heading change by tens of noise units (randomised seeds 22 and 25: four
    # Nomoto ships, T = 3-4 s, refused with gyro peaks of 2-10 and compass peaks of 13-43).
    excited = [(y, noise)]
    if angle:
        a = _unwrap_nan(trial.data[angle].to_numpy(float))
        excited.append((a, max(noise_std(a), 1e-12)))
    if not max(_excursion(x, windows0, s, fs) for x, s in excited) > 10:
        return None
    raw = {ch: y}
    for c in inputs:
        raw[c] = held_input(trial.data[c].to_numpy(float))
    drivers = [c for c in COUPLING_DRIVERS.get(dof, ()) if coupled and trial.has(c)]
    if drivers:
        # Driven through coupling: a free decay fitted to it (the first pass's baseline) takes the time
        # constant of what drives it (the turns'), not its own, and an analysis step sized by that
        # leaves a sway of T = 0.4 s a 1 s step; its own is estimated with the driver as its input.
        t_const = quick_time_constant(y, np.nan_to_num(trial.data[drivers[0]].to_numpy(float)), fs, own_w)
    if t_const is None or not np.isfinite(t_const) or t_const <= 0:
        # For the time-constant guess only: inputs scaled to comparable size and summed.
        u_sum = sum(raw[c] / max(np.max(np.abs(raw[c])), 1e-12) for c in inputs) if inputs else None
        t_const = quick_time_constant(y, u_sum, fs, own_w or windows0)
        if not np.isfinite(t_const) or t_const <= 0:
            t_const = 0.2 * float(np.median([w.t1 - w.t0 for w in (own_w or windows0)]))
    made = _windowing(trial, windows0, own_w, t_const, bool(inputs), gaps)
    if made is None:
        return None
    windows, m = list(made[0]), made[1]
    noises = {ch: noise}
    if angle:
        raw[angle] = _unwrap_nan(trial.data[angle].to_numpy(float))
        noises[angle] = noise_std(raw[angle])
    if heading and heading not in raw:
        raw[heading] = _unwrap_nan(trial.data[heading].to_numpy(float))
    regs = []
    for c in VELOCITIES:
        if c == ch or not trial.has(c):
            continue
        x = trial.data[c].to_numpy(float)
        if any(w.t0 < g.t_end and g.t_start < w.t1 for g in set(gaps_of(trial, (c,))) - set(gaps) for w in windows):
            # A dropout inside the windows that does not cut them (a sway speed derived from a GNSS
            # that dropped out, in a yaw record of gyro, compass and rudder): no regressor.
            continue
        vals = np.concatenate([x[w.i0:w.i1] for w in windows])
        vals = vals[np.isfinite(vals)]
        if len(vals) < 10:
            continue
        # A regressor that barely varies is a constant bias in disguise: the current and
        # bias candidates cover that more simply. It enters as block means over the analysis
        # step (m samples), so its variation is compared with the white noise of a block mean:
        # a sway speed of a few noise units per sample, integrated by the yaw dynamics, is a
        # clear regressor (N_v v on a small boat: v within 5 per-sample noise units).
        if np.std(vals) < 0.05 * np.sqrt(np.mean(vals**2)) or np.std(vals) < 5 * noise_std(x) / np.sqrt(m):
            continue
        raw[c] = x
        regs.append(c)
    if coupled and not regs:
        # Nothing logged that moves in its windows could drive it: a replay of free decays from the
        # measured state would call the coupling itself the gap.
        return None
    acts = []
    for a in (space.actuators if space is not None else ()):
        gains = {c: g for c, g in a.gains.items() if c in inputs}
        if gains:
            acts.append(Actuator(a.name, gains))
            raw[actuator_key(a.name)] = space.signals[a.name]
    return DofProblem(dof=dof, channel=ch, angle=angle, heading=heading, inputs=inputs, regressors=tuple(regs),
                      fs=fs, m=m, dt=m / fs, windows=tuple(windows), t_guess=float(t_const), raw=raw, noise=noises,
                      derived_from=derived_velocity(trial, ch),
                      stated_noise={c: float(v) for c, v in getattr(vessel, "sensor_noise", {}).items()
                                    if c in (ch, angle)},
                      actuators=tuple(acts))

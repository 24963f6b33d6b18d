"""PD heading autopilot for the first-order Nomoto model, designed by crossover frequency and phase margin.

Controller and plant (Fossen 2021, sec. 15.2; the ship-autopilot seed, part III)::

    h_pd(s) = K_pd (1 + T_d s) / (1 + T_f s)        delta = h_pd(s) (psi_r - psi)
    h_s(s)  = K / (s (T s + 1))

With ``T_d = T`` the controller's zero cancels the ship's pole and the loop transfer function is
``h_0(s) = K_pd K / (s (1 + T_f s))``. For crossover ``omega_c`` and phase margin ``phi``::

    angle h_0(j omega_c) = -90 deg - atan(T_f omega_c) = phi - 180 deg  =>  T_f = tan(90 deg - phi) / omega_c
    |h_0(j omega_c)| = 1                                                 =>  K_pd = omega_c sqrt(1 + (T_f omega_c)^2) / K

For the seed's omega_c = 0.1 rad/s, phi = 50 deg and K = 0.1561 1/s this gives T_f = 8.391 s and
K_pd = 0.836 (T_d = T = 72.44 s). Angles are radians everywhere; degrees only where a name says so.

References
----------
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley.
Nomoto, K., Taguchi, T., Honda, K., Hirano, S. (1957). On the steering qualities of ships.
International Shipbuilding Progress 4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import AutopilotError
from ..records import PDGains
from .defaults import CROSSOVER_TIMES_T  # the default lives where the CLI's --help can read it



def default_crossover(T: float) -> float:
    """The one default PD crossover frequency: ``CROSSOVER_TIMES_T / T`` [rad/s].

    ``vesselid autopilot``, ``vesselid run`` and :func:`pd_gains` all take it from here.

    Parameters
    ----------
    T : float
        Nomoto time constant [s], positive.
    """
    return CROSSOVER_TIMES_T / _positive("Nomoto T", T, "s")
#: Default design phase margin [rad] (the seed's 50 deg).
DEFAULT_PHASE_MARGIN = math.radians(50.0)


def _positive(name: str, value: float, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise AutopilotError(f"{name}: expected a positive number [{unit}], found {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise AutopilotError(f"{name}: expected a positive number [{unit}], found {value!r}")
    return v


def pd_gains(K: float, T: float, crossover: float | None = None,
             phase_margin: float = DEFAULT_PHASE_MARGIN) -> PDGains:
    """PD gains from the Nomoto model, a crossover frequency and a phase margin.

    Parameters
    ----------
    K : float
        Nomoto gain [1/s], positive (positive rudder gives positive yaw rate).
    T : float
        Nomoto time constant [s].
    crossover : float, optional
        Crossover frequency omega_c [rad/s]; default :func:`default_crossover` of ``T``.
    phase_margin : float
        Phase margin [rad], strictly between 0 and pi/2 (the loop ``K_pd K / (s (1 + T_f s))`` has at
        most 90 deg of margin).

    Returns
    -------
    PDGains
        ``T_d = T``, ``T_f = tan(pi/2 - phi) / omega_c``, ``K_pd = omega_c sqrt(1 + (T_f omega_c)^2) / K``.

    Raises
    ------
    AutopilotError
        Non-positive K, T or crossover; phase margin outside (0, 90) deg.
    """
    K = _positive("Nomoto K", K, "1/s")
    T = _positive("Nomoto T", T, "s")
    wc = _positive("crossover frequency", default_crossover(T) if crossover is None else crossover, "rad/s")
    pm = float(phase_margin)
    if not (0.0 < pm < math.pi / 2):
        raise AutopilotError(f"phase margin: expected between 0 and 90 deg (exclusive), found "
                             f"{math.degrees(pm):.6g} deg")
    tf = math.tan(math.pi / 2 - pm) / wc
    kpd = wc * math.sqrt(1.0 + (tf * wc) ** 2) / K
    return PDGains(kpd=kpd, td=T, tf=tf, crossover=wc, phase_margin=pm)


def loop_frequency_response(omega: np.ndarray, K: float, T: float, gains: PDGains) -> np.ndarray:
    """Loop transfer function ``h_pd(j omega) h_s(j omega)`` for a plant (K, T) [-].

    Parameters
    ----------
    omega : numpy.ndarray
        Frequencies [rad/s], positive.
    K, T : float
        Plant Nomoto gain [1/s] and time constant [s] (may differ from the design model).
    gains : PDGains
        Controller.

    Returns
    -------
    numpy.ndarray (complex)
        ``h_0(j omega)``.
    """
    s = 1j * np.asarray(omega, float)
    return gains.kpd * (1 + gains.td * s) / (1 + gains.tf * s) * K / (s * (T * s + 1))


def loop_margins(K: float, T: float, gains: PDGains) -> tuple[float, float]:
    """Crossover frequency [rad/s] and phase margin [rad] of the PD loop on a plant (K, T).

    The design model gives back ``gains.crossover`` and ``gains.phase_margin``; a plant whose K or T
    differs from the design (the identified values have standard errors) does not, because the
    zero no longer cancels the pole.

    Parameters
    ----------
    K, T : float
        Plant Nomoto gain [1/s] and time constant [s].
    gains : PDGains
        Controller.

    Returns
    -------
    tuple of float
        ``(omega_c, phase_margin)``; the highest crossing of |h_0| = 1 is used.
    """
    K = _positive("Nomoto K", K, "1/s")
    T = _positive("Nomoto T", T, "s")
    w = np.logspace(-5, 3, 4001)
    mag = np.log(np.abs(loop_frequency_response(w, K, T, gains)))
    idx = np.flatnonzero(np.sign(mag[:-1]) != np.sign(mag[1:]))
    if len(idx) == 0:
        return math.nan, math.nan
    i = int(idx[-1])
    lo, hi = w[i], w[i + 1]
    for _ in range(80):  # bisection on log|h_0|: monotone within one grid cell
        mid = math.sqrt(lo * hi)
        if np.log(np.abs(loop_frequency_response(np.array([mid]), K, T, gains)))[0] > 0:
            lo = mid
        else:
            hi = mid
    wc = math.sqrt(lo * hi)
    phase = float(np.angle(loop_frequency_response(np.array([wc]), K, T, gains))[0])
    # The integrator and the lag keep the phase in (-180, 0] deg at crossover for these plants;
    # unwrap anyway so a margin is never reported 360 deg off.
    if phase > 0:
        phase -= 2 * math.pi
    return wc, phase + math.pi


def margin_table(K: float, T: float, K_stderr: float, T_stderr: float, gains: PDGains,
                 z: float = 1.96) -> list[dict]:
    """Crossover and phase margin at the corners of the (K, T) confidence box.

    Parameters
    ----------
    K, T : float
        Identified Nomoto gain [1/s] and time constant [s].
    K_stderr, T_stderr : float
        Their standard errors (NaN: that corner is skipped).
    gains : PDGains
        Controller designed on (K, T).
    z : float
        Half-width of the box in standard errors (1.96: 95 % per parameter).

    Returns
    -------
    list of dict
        One row per plant: ``K``, ``T``, ``crossover`` [rad/s], ``phase_margin`` [rad].
    """
    rows = [(K, T)]
    if math.isfinite(K_stderr) and math.isfinite(T_stderr):
        for dk in (-1, 1):
            for dt in (-1, 1):
                k, t = K + dk * z * K_stderr, T + dt * z * T_stderr
                if k > 0 and t > 0:
                    rows.append((k, t))
    out = []
    for k, t in rows:
        wc, pm = loop_margins(k, t, gains)
        out.append({"K": k, "T": t, "crossover": wc, "phase_margin": pm})
    return out


@dataclass(frozen=True)
class DiscretePD:
    """The PD controller at sample time ``ts``, exact for a zero-order-held error.

    ``h_pd(s) = K_pd [T_d/T_f + (1 - T_d/T_f) / (1 + T_f s)]``: a feed-through plus a first-order lag,
    so with lag state ``z``::

        delta[k] = K_pd (T_d/T_f e[k] + (1 - T_d/T_f) z[k])
        z[k+1]   = a z[k] + (1 - a) e[k],   a = exp(-ts / T_f)

    Attributes
    ----------
    kpd : float
        Proportional gain [-].
    ratio : float
        ``T_d / T_f`` [-] (the high-frequency gain is ``K_pd T_d / T_f``).
    a : float
        Lag pole ``exp(-ts / T_f)`` [-].
    ts : float
        Sample time [s].
    """

    kpd: float
    ratio: float
    a: float
    ts: float

    def output(self, z: float, e: float) -> float:
        """Rudder command [rad] for lag state ``z`` [rad] and heading error ``e`` [rad].

        Parameters
        ----------
        z : float
            Lag state at this sample [rad].
        e : float
            Heading error ``psi_r - psi`` at this sample [rad].
        """
        return self.kpd * (self.ratio * e + (1.0 - self.ratio) * z)

    def next_state(self, z: float, e: float) -> float:
        """Lag state at the next sample [rad].

        Parameters
        ----------
        z : float
            Lag state at this sample [rad].
        e : float
            Heading error ``psi_r - psi`` at this sample [rad], held over the sample.
        """
        return self.a * z + (1.0 - self.a) * e


def discretise_pd(gains: PDGains, ts: float) -> DiscretePD:
    """Exact zero-order-hold discretisation of the PD controller.

    Parameters
    ----------
    gains : PDGains
        Continuous gains.
    ts : float
        Sample time [s].

    Returns
    -------
    DiscretePD
        Controller in feed-through + lag form.
    """
    ts = _positive("sample time", ts, "s")
    return DiscretePD(kpd=gains.kpd, ratio=gains.td / gains.tf, a=math.exp(-ts / gains.tf), ts=ts)

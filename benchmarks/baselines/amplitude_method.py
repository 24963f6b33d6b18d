"""The ship-autopilot seeds' two-frequency amplitude method for Nomoto K and T (kept as a baseline).

Two sinusoidal rudder tests at ``omega_1`` and ``omega_2`` give the amplitude ratios
``A_i = |H(j omega_i)|`` of ``H(s) = K / (s (T s + 1))``::

    A_i = K / (omega_i sqrt(T^2 omega_i^2 + 1))

Equating the two expressions for ``K^2`` gives (seed 000, Task B)::

    T = sqrt((A_1^2 omega_1^2 - A_2^2 omega_2^2) / (A_2^2 omega_2^4 - A_1^2 omega_1^4))
    K = A_1 omega_1 sqrt(T^2 omega_1^2 + 1)

The students read each amplitude as half the peak-to-peak heading over the second half of the
record (their MATLAB ``max``/``min`` of ``H(H_len/2:H_len)``), which is exact without disturbances
and badly biased once waves and compass noise add their own peaks: their T fell from 72.4 s to
14.5 s. :func:`sinusoid_amplitude` reproduces that reading so the benchmark can run the seed's
method on the same records as the whole-record fits.

Units: ``A_i`` is a ratio of heading amplitude to rudder amplitude, the same number in deg/deg
and rad/rad. The seed's ``A_1 = 29.358`` and ``A_2 = 0.831`` are heading amplitudes in degrees
for a 1 degree rudder, i.e. already ratios.

References
----------
Nomoto, K., Taguchi, T., Honda, K., Hirano, S. (1957). On the steering qualities of ships.
International Shipbuilding Progress 4, 354-370.
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley,
sec. 7.2.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.errors import FitError

#: The seeds' steady part: the second half of the record.
STEADY_FRACTION = 0.5


def nomoto_amplitude_method(A1: float, A2: float, w1: float, w2: float) -> tuple[float, float]:
    """Nomoto K and T from the amplitude ratios at two frequencies (the seeds' Task B).

    Parameters
    ----------
    A1, A2 : float
        ``|psi| / |delta|`` at ``w1`` and ``w2`` [rad/rad = deg/deg].
    w1, w2 : float
        Rudder frequencies [rad/s], different.

    Returns
    -------
    K : float
        Gain [1/s].
    T : float
        Time constant [s].

    Raises
    ------
    FitError
        Non-positive inputs, equal frequencies, or amplitudes no first-order Nomoto model can
        produce (the ratio under the square root is not positive).

    Examples
    --------
    The seed's table (003, eq. 1.5-1.9): ``nomoto_amplitude_method(29.358, 0.831, 0.005, 0.05)``
    gives K = 0.156 1/s and T = 72.44 s.
    """
    vals = (A1, A2, w1, w2)
    if not all(math.isfinite(v) and v > 0 for v in vals):
        raise FitError(f"amplitude method: expected positive finite A1, A2, w1, w2, found {vals}")
    if w1 == w2:
        raise FitError(f"amplitude method: expected two different frequencies, found w1 = w2 = {w1}")
    num = A1**2 * w1**2 - A2**2 * w2**2
    den = A2**2 * w2**4 - A1**2 * w1**4
    if not (num / den > 0 if den != 0 else False):
        raise FitError(f"amplitude method: amplitudes A1 = {A1:.4g}, A2 = {A2:.4g} at w = {w1:.4g}, {w2:.4g} rad/s "
                       f"fit no K/(s(Ts+1)): expected (A1^2 w1^2 - A2^2 w2^2)/(A2^2 w2^4 - A1^2 w1^4) > 0, "
                       f"found {num:.3g}/{den:.3g}")
    T = math.sqrt(num / den)
    K = A1 * w1 * math.sqrt(T**2 * w1**2 + 1.0)
    return K, T


def sinusoid_amplitude(t: np.ndarray, psi: np.ndarray, delta: np.ndarray,
                       steady_fraction: float = STEADY_FRACTION) -> float:
    """Amplitude ratio ``|psi| / |delta|`` of a sinusoid test, read the way the seeds read it.

    Half the peak-to-peak heading over the steady part (the last ``steady_fraction`` of the
    record) divided by half the peak-to-peak rudder over the same part. Waves and noise go
    straight into the peaks: that is the seed's method, bias included.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times [s].
    psi : numpy.ndarray
        Measured heading [rad] (unwrapped here).
    delta : numpy.ndarray
        Rudder angle [rad].
    steady_fraction : float
        Trailing fraction of the record taken as steady (the seeds: 0.5).

    Returns
    -------
    float
        Amplitude ratio [rad/rad].

    Raises
    ------
    FitError
        Mismatched lengths, too few samples or a constant rudder.
    """
    t = np.asarray(t, float)
    psi = np.asarray(psi, float)
    delta = np.asarray(delta, float)
    if not (t.shape == psi.shape == delta.shape) or t.size < 4:
        raise FitError(f"sinusoid amplitude: expected t, psi, delta of one length >= 4, found "
                       f"{t.shape}, {psi.shape}, {delta.shape}")
    if not 0 < steady_fraction <= 1:
        raise FitError(f"sinusoid amplitude: expected 0 < steady_fraction <= 1, found {steady_fraction}")
    keep = t >= t[0] + (1.0 - steady_fraction) * (t[-1] - t[0])
    ok = keep & np.isfinite(psi) & np.isfinite(delta)
    heading = np.unwrap(psi[np.isfinite(psi)])
    full = np.full(psi.shape, np.nan)
    full[np.isfinite(psi)] = heading
    a_psi = float(np.ptp(full[ok])) / 2
    a_delta = float(np.ptp(delta[ok])) / 2
    if not a_delta > 0:
        raise FitError("sinusoid amplitude: expected a varying rudder in the steady part, found a constant one")
    return a_psi / a_delta

"""Records of the whole-record Nomoto fits: the input record and the fit result."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..model.waves import WaveParams
from .residual_tests import ResidualTest


@dataclass(frozen=True)
class NomotoRecord:
    """One uniformly sampled record for a whole-record Nomoto fit.

    Attributes
    ----------
    t : numpy.ndarray
        Sample times [s], uniform.
    delta : numpy.ndarray
        Rudder angle [rad], held over each sample interval (zero-order hold), finite.
    psi : numpy.ndarray or None
        Compass heading [rad] (wrapped or not; unwrapped inside). NaN marks a missing sample.
    r : numpy.ndarray or None
        Yaw rate [rad/s], if logged.
    name : str
        For messages.
    """

    t: np.ndarray
    delta: np.ndarray
    psi: np.ndarray | None = None
    r: np.ndarray | None = None
    name: str = ""


@dataclass(frozen=True)
class NomotoFit:
    """Result of :func:`fit_nomoto` (lmfit-style: values, errors, covariance, criteria, checks).

    Attributes
    ----------
    order : int
        1 or 2.
    noise_model : str
        ``white`` (OE) or ``waves`` (PEM with the wave model).
    names : tuple[str, ...]
        Parameter names in covariance order: ``K``, ``T`` (or ``T1``, ``T2``, ``T3``), ``b`` (if
        estimated), per record ``psi0``/``r0`` (``[i]`` suffix for several records), and for the PEM
        the estimated ones of ``omega0`` [rad/s], ``lambda`` [-], ``kw_ratio`` [s^-1/2].
    values, stderr : numpy.ndarray
        Estimates and standard errors in SI units (NaN errors when the covariance is singular).
    covariance : numpy.ndarray
        Parameter covariance.
    waves : WaveParams or None
        Wave model used (estimated or fixed), K_w in rad s^-1/2.
    noise_var : Mapping[str, float]
        Variance of the white measurement noise per channel [rad^2, (rad/s)^2].
    innovation_var : Mapping[str, float]
        Mean square of the weighted residuals' channel (innovations for the PEM) [SI^2].
    y_fit : tuple[Mapping[str, numpy.ndarray], ...]
        Simulated noise-free output per record and channel.
    residuals : tuple[Mapping[str, numpy.ndarray], ...]
        Residuals per record and channel (``y - y_sim`` for OE, innovations for PEM).
    n : int
        Residuals used.
    neg2loglik : float
        ``-2 log L`` of the Gaussian innovations with the variances concentrated out.
    aic, bic : float
        ``-2 log L + 2p`` and ``-2 log L + p ln n``.
    converged : bool
        Solver convergence.
    at_bound : tuple[str, ...]
        Parameters outside their plausible range (time constants between a tenth of a sample and
        100 record lengths, |b| < pi/2, omega_0 between the record and the Nyquist frequency, ...);
        the solver itself is unbounded.
    residual_tests : tuple[ResidualTest, ...]
        Whiteness and input cross-correlation per record and channel (Ljung 1999, sec. 16.6).
    message : str
        What is doubtful (coloured residuals, ranges, singular covariance) and what was chosen.
    channels : tuple[str, ...]
        Channels fitted (``psi``, ``r``).
    timings : Mapping[str, float]
        Wall time of the fit [s] (``total_s``).
    robust_covariance, robust_stderr : numpy.ndarray or None
        Newey-West covariance and standard errors when the residuals stayed coloured and they are
        larger than the white-noise ones (:func:`pipeline.fit.nomoto_oe.correlated_residual_errors`);
        None otherwise. ``covariance`` and ``stderr`` stay the white-noise ones (the structure
        stage pools segments with them); a segment fit reports these.
    """

    order: int
    noise_model: str
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    waves: WaveParams | None
    noise_var: Mapping[str, float]
    innovation_var: Mapping[str, float]
    y_fit: tuple[Mapping[str, np.ndarray], ...]
    residuals: tuple[Mapping[str, np.ndarray], ...]
    n: int
    neg2loglik: float
    aic: float
    bic: float
    converged: bool
    at_bound: tuple[str, ...]
    residual_tests: tuple[ResidualTest, ...] = ()
    message: str = ""
    channels: tuple[str, ...] = ("psi",)
    timings: Mapping[str, float] = field(default_factory=dict)
    robust_covariance: np.ndarray | None = None
    robust_stderr: np.ndarray | None = None

    def value(self, name: str) -> float:
        """Estimate of one parameter [SI].

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.values[self.names.index(name)])

    def error(self, name: str) -> float:
        """Standard error of one parameter [SI].

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.stderr[self.names.index(name)])

    def reported_error(self, name: str) -> float:
        """Standard error of one parameter as reported [SI]: the Newey-West one where the residuals
        are coloured (``robust_stderr``, never smaller than the white-noise one), else :meth:`error`.

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        se = self.robust_stderr if self.robust_stderr is not None else self.stderr
        return float(se[self.names.index(name)])

    @property
    def K(self) -> float:
        """Nomoto gain [1/s]."""
        return self.value("K")

    @property
    def T(self) -> float:
        """Nomoto time constant [s]; for the second order the equivalent ``T1 + T2 - T3``."""
        if self.order == 1:
            return self.value("T")
        if self.order == 3:
            return self.value("T12") - self.value("T3")
        return self.value("T1") + self.value("T2") - self.value("T3")

    @property
    def b(self) -> float:
        """Rudder bias [rad] (0 when not estimated)."""
        return self.value("b") if "b" in self.names else 0.0

    @property
    def success(self) -> bool:
        """Converged, no parameter on a bound and a finite covariance."""
        return self.converged and not self.at_bound and bool(np.all(np.isfinite(self.stderr)))

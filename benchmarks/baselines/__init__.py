"""Baselines and bounds the benchmarks compare the pipeline's fits with; not part of the package.

- ``amplitude_method``: the seeds' two-frequency amplitude method for Nomoto K and T
  (:func:`nomoto_amplitude_method`, :func:`sinusoid_amplitude`).
- ``arx``: ARX(2, 2, 1) + offset by least squares, read as K / (s (T s + 1)) (:func:`fit_arx_nomoto`).
- ``crlb``: Cramer-Rao lower bounds of the first-order and Nomoto fits (:func:`decay_crlb`,
  :func:`least_squares_crlb`, :func:`nomoto_crlb`).

The pipeline never imports these at run time; benchmarks/*.py and the tests that check the
baselines themselves do (the repository root on ``sys.path``).
"""

from .amplitude_method import nomoto_amplitude_method, sinusoid_amplitude
from .arx import ArxFit, fit_arx_nomoto
from .crlb import decay_crlb, least_squares_crlb, nomoto_crlb

__all__ = ["nomoto_amplitude_method", "sinusoid_amplitude", "fit_arx_nomoto", "ArxFit",
           "nomoto_crlb", "decay_crlb", "least_squares_crlb"]

"""autopilot stage: identified Nomoto model (+ wave record) -> AutopilotResult.

The records it passes on (:class:`~pipeline.records.AutopilotResult`, :class:`~pipeline.records.AutopilotConfig`,
:class:`~pipeline.records.WaveFit`, ...) are in :mod:`pipeline.records`; this package holds what makes them.

Modules
-------
``waves_fit``    Welch PSD of the wave-induced heading and a least-squares fit of omega_0, lambda, K_w.
``pd``           PD gains from crossover frequency and phase margin; loop margins; discrete PD.
``kalman``       5-state model [xi_w, psi_w, psi, r, b], observability, Van Loan, the discrete filter.
``config``       Design of an :class:`~pipeline.records.AutopilotConfig`, ``AUTOPILOT.toml`` writer/reader, input readers,
                 ArduPilot export.
``closed_loop``  Heading-loop simulation: PD alone, with wave filtering, with bias feed-forward.
``design``       :func:`build_autopilot` (what the CLI and ``run`` call).
``outputs``      :func:`write_autopilot_outputs`: the config, ArduPilot parameters, check, figures, fragment.
``report_section`` :func:`autopilot_html_section` for the HTML report.
``figures``      Closed-loop and wave-fit figures (PNG bytes).
``cli``          ``vesselid waves`` and ``vesselid autopilot``.

Units are SI and radians throughout; degrees only in report text and CLI flags that say so.
"""

from ..lazy import lazy_exports

#: Public name -> module defining it; loaded on first use, so ``vesselid autopilot --help`` stays fast.
_EXPORTS = {
    "CASES": ".closed_loop", "closed_loop_check": ".closed_loop",
    "default_scenarios": ".closed_loop", "simulate_heading_loop": ".closed_loop",
    "ardupilot_params": ".config", "build_autopilot_config": ".config",
    "read_autopilot_toml": ".config", "read_coefficients_json": ".config", "read_waves_json": ".config",
    "write_ardupilot_params": ".config", "write_autopilot_toml": ".config",
    "KALMAN_STATES": ".kalman", "KalmanRun": ".kalman", "kalman_model": ".kalman",
    "kalman_predict": ".kalman", "kalman_update": ".kalman", "observability": ".kalman",
    "run_kalman_filter": ".kalman", "sampled_noise_variance": ".kalman", "steady_state": ".kalman",
    "DiscretePD": ".pd", "default_crossover": ".pd", "discretise_pd": ".pd",
    "loop_margins": ".pd", "margin_table": ".pd", "pd_gains": ".pd",
    "autopilot_html_section": ".report_section",
    "build_autopilot": ".design", "nomoto_from_fits": ".design",
    "write_autopilot_outputs": ".outputs", "write_autopilot_outputs_and_section": ".outputs",
    "HeadingRecord": ".waves_fit", "fit_wave_record": ".waves_fit", "wave_fit_to_dict": ".waves_fit",
    "fit_wave_spectrum": ".waves_fit", "read_heading_record": ".waves_fit", "welch_psd": ".waves_fit",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)

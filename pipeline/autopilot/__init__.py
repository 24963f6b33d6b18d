"""autopilot stage: identified Nomoto model (+ wave record) -> AutopilotConfig.

Modules
-------
``waves_fit``    Welch PSD of the wave-induced heading and a least-squares fit of omega_0, lambda, K_w.
``pd``           PD gains from crossover frequency and phase margin; loop margins; discrete PD.
``kalman``       5-state model [xi_w, psi_w, psi, r, b], observability, Van Loan, the discrete filter.
``config``       :class:`AutopilotConfig`, ``AUTOPILOT.toml`` writer/reader, input readers, ArduPilot export.
``closed_loop``  Heading-loop simulation: PD alone, with wave filtering, with bias feed-forward.
``design``       :func:`build_autopilot` and :func:`write_autopilot_outputs` (what the CLI and ``run`` call).
``report_section`` :func:`autopilot_html_section` for the HTML report.
``figures``      Closed-loop and wave-fit figures (PNG bytes).
``cli``          ``vesselid waves`` and ``vesselid autopilot``.

Units are SI and radians throughout; degrees only in report text and CLI flags that say so.
"""

from .closed_loop import (CASES, ClosedLoopCheck, ClosedLoopRun, LoopMetrics, Scenario, closed_loop_check,
                          default_scenarios, simulate_heading_loop)
from .config import (ArduPilotExport, AutopilotConfig, NomotoCoefficients, SourceFile, ardupilot_params,
                     build_autopilot_config, read_autopilot_toml, read_coefficients_json, read_waves_json,
                     write_ardupilot_params, write_autopilot_toml)
from .kalman import (KALMAN_STATES, KalmanModel, KalmanRun, kalman_model, kalman_predict,
                     kalman_update, observability, run_kalman_filter, sampled_noise_variance, steady_state)
from .pd import DiscretePD, PDGains, default_crossover, discretise_pd, loop_margins, margin_table, pd_gains
from .report_section import autopilot_html_section
from .design import AutopilotResult, build_autopilot, nomoto_from_fits, write_autopilot_outputs
from .waves_fit import HeadingRecord, WaveFit, fit_wave_record, fit_wave_spectrum, read_heading_record, welch_psd

__all__ = [
    "CASES", "ClosedLoopCheck", "ClosedLoopRun", "LoopMetrics", "Scenario", "closed_loop_check",
    "default_scenarios", "simulate_heading_loop",
    "ArduPilotExport", "AutopilotConfig", "NomotoCoefficients", "SourceFile", "ardupilot_params",
    "build_autopilot_config", "read_autopilot_toml", "read_coefficients_json", "read_waves_json",
    "write_ardupilot_params", "write_autopilot_toml",
    "KALMAN_STATES", "KalmanModel", "KalmanRun", "kalman_model", "kalman_predict",
    "kalman_update", "observability", "run_kalman_filter", "sampled_noise_variance", "steady_state",
    "DiscretePD", "PDGains", "default_crossover", "discretise_pd", "loop_margins", "margin_table", "pd_gains",
    "autopilot_html_section",
    "AutopilotResult", "build_autopilot", "nomoto_from_fits", "write_autopilot_outputs",
    "HeadingRecord", "WaveFit", "fit_wave_record", "fit_wave_spectrum", "read_heading_record", "welch_psd",
]

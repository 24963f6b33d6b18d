"""The autopilot's default design values, in a module that imports nothing (the CLI's ``--help`` shows them).

:mod:`.config`, :mod:`.kalman` and :mod:`.pd` use these; the parser of ``vesselid autopilot`` reads
them from here without loading numpy, scipy or casadi.
"""

#: Default filter sample time [s] (the seed's 10 Hz).
DEFAULT_TS = 0.1
#: Default continuous process-noise intensities ``(q_w [-], q_b [rad^2/s])`` (the seed's hand-out).
#: In this package's convention the wave noise w_w has unit intensity, so q_w = 30 is a tuning
#: choice, not a physical value: it makes the filter follow the measured wave band more closely.
DEFAULT_Q = (30.0, 1e-6)
#: omega_c T of the ship-autopilot seed's design (0.1 rad/s for T = 72.4 s). The default crossover keeps
#: this product, so a small, fast model ship gets the same loop shape instead of a crossover 30x too low.
CROSSOVER_TIMES_T = 0.1 * 72.4

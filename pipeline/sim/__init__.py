"""sim stage: vessel + effects -> synthetic trials, written in every log format the ingest reads.

The simulator is the truth source of every regression test: :func:`simulate` integrates the
shared model right-hand sides of :mod:`pipeline.model` through a manoeuvre :class:`Schedule`
with the chosen :class:`Effects`, samples it with :class:`SensorSpec` sensors, and the writers
in :mod:`pipeline.sim.writers` put the resulting RawLog into log files.
"""

from .effects import EFFECT_NAMES, Effects
from .manoeuvres import (Manoeuvre, Schedule, chain, free_decay, rest, rudder_step, sea_trial, sinusoid,
                         step_and_coast, zigzag)
from .sensors import NOISE_LEVELS, SensorSpec, default_sensors
from .simulate import SimResult, simulate

__all__ = ["Effects", "EFFECT_NAMES", "Manoeuvre", "Schedule", "chain", "free_decay", "rest", "rudder_step",
           "sea_trial", "sinusoid", "step_and_coast", "zigzag", "NOISE_LEVELS", "SensorSpec", "default_sensors",
           "SimResult", "simulate"]

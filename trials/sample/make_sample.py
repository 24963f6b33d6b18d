"""Regenerate the bundled sample trial: an AAUSHIP-like sea-trial day, simulated.

    .venv/bin/python trials/sample/make_sample.py

Writes ``sample.csv`` (canonical CSV) beside this file from ``vessel_configs/aauship.toml`` with
seed 2024 and nominal sensor noise, sensors at 50 Hz (GPS at 10 Hz) to keep the file small.
"""

from pathlib import Path

from pipeline.sim import sea_trial, simulate
from pipeline.sim.sensors import default_sensors
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

HERE = Path(__file__).resolve().parent
VESSEL = HERE.parents[1] / "vessel_configs" / "aauship.toml"

if __name__ == "__main__":
    vessel = load_vessel(VESSEL)
    sensors = tuple(s if s.rate <= 50 else type(s)(s.name, s.channels, 50.0, s.noise, s.bias, s.suffix)
                    for s in default_sensors("nominal"))
    result = simulate(vessel, sea_trial(vessel), sensors=sensors, seed=2024)
    out = write_log(result.log, HERE / "sample.csv", vessel=vessel)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {result.truth['t'].iloc[-1]:.0f} s)")

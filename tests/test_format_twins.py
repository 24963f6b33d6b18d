"""A trial written in each log format gives the same coefficients as its CSV twin (issue 3).

One simulated sea-trial day is written through every writer, read back through the matching
reader and the whole pipeline; each coefficient must agree with the CSV result within one
standard error (the formats differ only by their field quantisation). The tlog carries no body
velocity: its u and v are derived from GLOBAL_POSITION_INT (NED ground velocity in 1 cm/s steps, rotated
by the heading), and the first-order fits use only that message's own sample times (the Trial's real
sample times), so its X_u and Y_v come from other samples than the CSV's logged u, v: for those two the
difference of two estimates with independent errors is allowed, within 2 sqrt(se_a^2 + se_b^2).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.fit import fit_trial
from pipeline.flow import load_trial, segment_trial
from pipeline.sim import sea_trial, simulate
from pipeline.sim.writers import write_log
from pipeline.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
from conftest import AAUSHIP as VESSEL  # noqa: E402 - loaded once per session
NAMES = ("X_u", "Y_v", "N_r", "K_p", "M_q", "K_nomoto", "T_nomoto")
FORMATS = ("tlog", "bin", "bag", "db3", "mcap", "rosbag2-folder")
#: Coefficients a format estimates from other measurements than the CSV twin (velocities from GNSS).
OTHER_MEASUREMENTS = {"tlog": {"X_u", "Y_v"}}


@pytest.fixture(scope="module")
def fits_by_format(tmp_path_factory, sea_trial_day):
    folder = tmp_path_factory.mktemp("twins")
    result = sea_trial_day
    out = {}
    for fmt in ("csv",) + FORMATS:
        name = "trial_bag" if fmt == "rosbag2-folder" else f"trial.{fmt}"
        path = write_log(result.log, folder / name, vessel=VESSEL)
        trial = load_trial([path], VESSEL)
        out[fmt] = fit_trial(trial, segment_trial(trial), VESSEL, extend=False)  # diagonal only: no grey-box
    return out


@pytest.mark.slow
@pytest.mark.parametrize("fmt", FORMATS)
def test_same_coefficients_as_csv_twin(fits_by_format, fmt):
    csv, other = fits_by_format["csv"].estimates, fits_by_format[fmt].estimates
    for name in NAMES:
        a, b = csv[name], other[name]
        assert a.success and b.success, f"{fmt} {name}: {b.message}"
        if name in OTHER_MEASUREMENTS.get(fmt, ()):
            bound = 2 * (a.stderr**2 + b.stderr**2) ** 0.5
        else:
            bound = max(a.stderr, b.stderr)
        assert abs(a.value - b.value) <= bound, (
            f"{fmt} {name}: {b.value:.6g} vs CSV {a.value:.6g} (stderr {a.stderr:.2g})")

"""README.md's excerpt of what `make run` identifies is what `make run` writes.

The README states a table of coefficients "measured with this commit" on the bundled sample trial, and that
every value lies within a stated number of standard errors of the truth. This test runs the same command
(`vesselid run trials/sample/trial.toml`) and checks every row of that table against the written
`coefficients.json` to the digits the README prints, and the truth claim against the fit.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[1]

#: A row of the excerpt: | `X_u` | -2.8598 ± 0.00098 | [-2.8618, -2.8579] | kg/s | 8 | -2.86 |
ROW = re.compile(r"^\| `(?P<name>\w+)` \| (?P<value>\S+) ± (?P<se>\S+) \| \[(?P<lo>\S+), (?P<hi>\S+)\] \| "
                 r"(?P<unit>[^|]+?) \| (?P<n>\d+) \| (?P<truth>\S+) \|$")


def _excerpt() -> tuple[list[dict], float]:
    text = (ROOT / "README.md").read_text()
    start = text.index("An excerpt of what `make run` identified")
    rows = [m.groupdict() for m in map(ROW.match, text[start:].splitlines()) if m]
    bound = re.search(r"Every value is within ([\d.]+) standard errors of the truth", text[start:])
    assert rows and bound, "README.md: expected the excerpt table of `make run` and its truth claim"
    return rows, float(bound.group(1))


def _half_unit(printed: str) -> float:
    """Half a unit in the last printed digit of a decimal number (what rounding to it may move)."""
    mantissa = printed.lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exponent = int(printed.lower().split("e")[1]) if "e" in printed.lower() else 0
    return 0.5 * 10.0 ** (exponent - decimals) * (1 + 1e-9)


@pytest.mark.slow  # the whole sample run, every stage (about 25 s CPU)
def test_readme_excerpt_is_what_make_run_writes(tmp_path, capsys):
    rows, bound = _excerpt()
    code = main(["run", str(ROOT / "trials/sample/trial.toml"), "--out", str(tmp_path / "sample")])
    assert code == 0, capsys.readouterr().err
    got = json.loads((tmp_path / "sample" / "coefficients.json").read_text())["coefficients"]
    for row in rows:
        est = got[row["name"]]
        for key, value in (("value", est["value"]), ("se", est["stderr"]),
                           ("lo", est["ci95"][0]), ("hi", est["ci95"][1])):
            assert abs(value - float(row[key])) <= _half_unit(row[key]), (row["name"], key, value, row[key])
        assert est["unit"] == row["unit"].strip() and est["n_segments"] == int(row["n"]), (row["name"], est)
        assert est["success"], (row["name"], est["message"])
        z = (est["value"] - float(row["truth"])) / est["stderr"]
        assert abs(z) <= bound, f"{row['name']}: {z:+.2f} standard errors from the truth, README says <= {bound}"


def test_half_unit_reads_the_printed_digits():
    assert _half_unit("-2.8598") == pytest.approx(0.00005)
    assert _half_unit("1.711986") == pytest.approx(5e-7)
    assert _half_unit("32") == pytest.approx(0.5)
    assert _half_unit("1.5e-6") == pytest.approx(5e-8)

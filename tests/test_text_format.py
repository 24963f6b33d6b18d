"""The one number/text formatter every HTML writer and text table uses."""

from __future__ import annotations

import math

from pipeline.text_format import esc, number, plus_minus


def test_number_formats_and_names_what_is_missing():
    assert number(1234.5678, ".4g") == "1235"
    assert number(0.5, ".2f", unit="m/s") == "0.50 m/s"
    for bad in (None, math.nan, math.inf, "text"):
        assert number(bad) == "n/a"
        assert number(bad, missing="-") == "-"
    assert number("2.5", ".3g") == "2.5"          # numbers read back from a table
    assert number(1.5e-268, ".3g", zero=1e-9) == "0"  # round-off printed as 0
    assert number(1.5e-268, ".3g") == "1.5e-268"


def test_plus_minus_drops_a_missing_error_bar_and_says_so():
    assert plus_minus(-2.8612, 0.0312) == "-2.861 &plusmn; 0.031"
    assert plus_minus(-2.8612, 0.0312, sign=" ± ", unit="s") == "-2.861 ± 0.031 s"
    assert plus_minus(3.0, math.nan, no_stderr=" (no standard error)") == "3 (no standard error)"
    assert plus_minus(None, 0.1, missing="") == ""


def test_esc_escapes_quotes_and_markup():
    assert esc('<a href="x">&') == "&lt;a href=&quot;x&quot;&gt;&amp;"
    assert esc(3) == "3"

"""``--time-field NAME:UNIT`` on ``process`` and ``calibrate``: a value that is not one is a single line, before any work."""

from __future__ import annotations

import pytest
from helpers import SAMPLE_LOGS, run_cli_here


@pytest.mark.parametrize("command, out", [("process", "out"), ("calibrate", "cal.yaml")])
def test_a_time_field_that_is_not_name_and_unit_is_one_line_before_any_work(tmp_path, command, out):
    code, printed, err = run_cli_here(command, str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / out),
                                      "--time-field", "time_offset_ns")
    assert code == 2 and printed == ""
    assert err.strip().splitlines() == ["fmcwlog: error: --time-field expects NAME:UNIT with UNIT one of s, ms, us, "
                                        "ns, abs_s, abs_ns, got 'time_offset_ns'"]
    assert list(tmp_path.iterdir()) == []


def test_the_time_field_option_is_said_in_both_commands_help():
    for command in ("process", "calibrate"):
        code, printed, _ = run_cli_here(command, "--help")
        assert code == 0 and "--time-field NAME:UNIT" in printed and "abs_ns" in printed

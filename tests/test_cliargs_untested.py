"""senerf.cliargs lines no other test ran: a float flag given text that is no number at all.

(check_device's refusals, cliargs.py's other unrun lines in tests/bench and test_cliargs.py's set, are run by
tests/test_cli.py: test_malformed_devices_are_refused_by_name and
test_cuda_ordinal_and_gpu_memory_are_checked_before_anything_is_written.)"""

from __future__ import annotations

import pytest

from senerf.cliargs import OneLineParser, float_flag
from senerf.errors import InputError


@pytest.mark.parametrize("text", ["abc", "", "1,5", "0x10"])
def test_float_flag_names_the_flag_for_text_that_is_no_number(text):
    # Catches: float()'s ValueError not turned into an InputError (argparse then says "invalid checked value",
    # naming neither the problem nor a number), or the message not quoting what was given.
    parser = OneLineParser(prog="prog")
    parser.add_argument("--x", type=float_flag("--x", minimum=0.0))
    with pytest.raises(InputError) as info:
        parser.parse_args([f"--x={text}"])
    assert str(info.value) == f"argument --x: expected a number, got {text!r}"
    assert parser.parse_args(["--x=1e-3"]).x == 0.001           # the accepted side: any float() syntax

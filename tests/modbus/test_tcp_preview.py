"""A dry run over Modbus TCP shows the MBAP ADU that would be sent, not an RTU frame with a CRC."""

from __future__ import annotations

import pytest

from starterbus.cli.main import main


@pytest.mark.parametrize(
    ("argv", "adu"),
    [
        (["start", "--model", "jjr5000"], "00 00 00 06 02 06 00 00 00 09"),
        (["write", "--model", "jjr5000", "current_limit=300"], "00 00 00 06 02 06 01 03 01 2C"),
        (["write", "--model", "jjr5000", "--raw", "0x0100=5"], "00 00 00 06 02 06 01 00 00 05"),
    ],
)
def test_a_dry_run_shows_the_mbap_adu(argv: list[str], adu: str, capsys: pytest.CaptureFixture[str]) -> None:
    command, *rest = argv
    assert main([command, "modbus-tcp://127.0.0.1:9?unit=2", *rest, "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"TT TT {adu}  (MBAP; TT TT: the transaction id, given when sent)" in out

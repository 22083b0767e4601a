"""An optional part that is not installed is one line naming the pip extra, before anything is opened."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from starterbus.cli.main import main


@pytest.mark.parametrize(
    ("argv", "extra"),
    [
        (["opcua", "--demo", "--duration", "1"], "opcua"),
        (["opcua-user", "USERS.toml", "alice"], "opcua"),
        (["plot", "h.db", "--device", "m1", "--event", "1"], "plot"),
    ],
)
def test_a_missing_extra_is_one_line(
    argv: list[str], extra: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in [m for m in sys.modules if m.split(".")[0] in ("asyncua", "matplotlib")] + ["asyncua", "matplotlib"]:
        monkeypatch.setitem(sys.modules, name, None)  # `import` now raises ImportError
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"starterbus[{extra}]" in err[0] and "pip install" in err[0], err
    assert list(tmp_path.iterdir()) == []  # nothing written

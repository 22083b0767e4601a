"""``backup -o FILE`` never clobbers a file without ``--force``, refuses before the device is read, and never leaves
a half-written file (a temporary file renamed over the target)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.errors import ConfigurationError
from starterbus.core.outfiles import check_target, write_atomically
from starterbus.ops import backup as backups

from .conftest import Line


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def test_an_existing_backup_is_refused_before_the_device_is_read(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    existing = tmp_path / "pump.toml"
    assert main(["backup", line.url(4), "--model", "ssd1", "-o", str(existing)]) == 0  # a backup of another model
    before = existing.read_bytes()
    capsys.readouterr()
    line.functions.clear()

    assert main(["backup", line.url(2), "--model", "jjr5000", "-o", str(existing)]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert f"-o {existing}: the file exists; nothing done (give --force to replace it" in err
    assert existing.read_bytes() == before and line.functions == []  # nothing sent, nothing written
    assert leftovers(tmp_path) == []


def test_force_replaces_it(line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    existing = tmp_path / "pump.toml"
    existing.write_text("# an older backup\n", encoding="utf-8")
    assert main(["backup", line.url(2), "--model", "jjr5000", "-o", str(existing), "--force"]) == 0
    assert backups.load(existing)[0].model == "jjr5000"
    assert "saved to" in capsys.readouterr().out and leftovers(tmp_path) == []


@pytest.mark.parametrize(
    ("name", "message"),
    [("missing/x.toml", "does not exist"), (".", "is a directory")],
)
def test_an_unwritable_target_is_refused_before_the_device_is_read(
    name: str, message: str, line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line.functions.clear()
    assert main(["backup", line.url(2), "--model", "jjr5000", "-o", str(tmp_path / name)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and line.functions == []


def test_a_file_that_appears_meanwhile_is_not_clobbered(tmp_path: Path) -> None:
    target = check_target(tmp_path / "b.toml")
    target.write_text("someone else's\n", encoding="utf-8")  # between the check and the write
    with pytest.raises(ConfigurationError, match="appeared while this ran; nothing written"):
        write_atomically(target, "ours\n")
    assert target.read_text(encoding="utf-8") == "someone else's\n" and leftovers(tmp_path) == []


def test_a_failed_write_leaves_the_old_file_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "b.toml"
    target.write_text("the good backup\n", encoding="utf-8")

    def full_disk(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(ConfigurationError, match=r"b.toml: cannot write: No space left on device; nothing written"):
        write_atomically(target, "the new one\n", replace=True)
    assert target.read_text(encoding="utf-8") == "the good backup\n" and leftovers(tmp_path) == []


def test_a_private_file_is_private_from_the_first_byte(tmp_path: Path) -> None:
    target = tmp_path / "users.toml"
    target.write_text("old\n", encoding="utf-8")
    target.chmod(0o644)
    write_atomically(target, "new\n", replace=True, mode=0o600)
    assert target.stat().st_mode & 0o777 == 0o600 and target.read_text(encoding="utf-8") == "new\n"

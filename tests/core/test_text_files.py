"""Files users edit (fleet, backup, users, config, profile, script, frame log, credentials) are read as UTF-8
with or without a byte-order mark; any other encoding is one line naming the file, line, column, offset and byte.
"""

from __future__ import annotations

import codecs
import re
from collections.abc import Callable
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.cli.target import default_fleet
from starterbus.core.errors import ConfigurationError, ProfileError
from starterbus.core.profile import load_profile_file
from starterbus.core.registry import get_profile
from starterbus.core.textinput import decode_text, read_text_file
from starterbus.fleet.config import load_fleet
from starterbus.opcua.users import Role, UserEntry, dump_users, hash_password, load_users
from starterbus.ops import backup as backups
from starterbus.serve.broker import load_credentials

TOY = Path(__file__).with_name("toy_profile.toml")

FLEET = """\
# 泵房 (pump room): a comment in Chinese, as a Chinese Windows editor writes it
[[bus]]
name = "line"
url = "modbus-rtu:///dev/ttyS9"

  [[bus.device]]
  name = "pump-a"
  model = "jjr5000"
  address = 2
"""


def backup_text() -> str:
    profile = get_profile("jjr5000")
    key = profile.parameters[0].key
    entry = backups.Entry(key, profile.points[key].default or 0, "")
    return "# 备份 (backup)\n" + backups.dumps(backups.Backup("jjr5000", {key: entry}), profile)


def users_text() -> str:
    entry = UserEntry("operator", Role.OPERATOR, hash_password("secret", iterations=1000))
    return "# 用户 (users)\n" + dump_users({"operator": entry})


def check_fleet(path: Path) -> None:
    assert [d.name for d in load_fleet(path).devices] == ["pump-a"]


def check_backup(path: Path) -> None:
    taken, profile = backups.load(path)
    assert taken.model == profile.name == "jjr5000" and len(taken.parameters) == 1


def check_users(path: Path) -> None:
    assert list(load_users(path)) == ["operator"]


def check_config(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CONFIG_HOME", str(path.parent.parent))
    monkeypatch.delenv("STARTERBUS_FLEET", raising=False)
    assert default_fleet(None) == "工厂.toml"


def check_profile(path: Path) -> None:
    assert load_profile_file(path).name == "toy"


def check_credentials(path: Path) -> None:
    assert load_credentials(str(path)) == ("user", "密码")


CASES: dict[str, tuple[str, Callable[[], str], Callable[..., None]]] = {
    "fleet": ("plant.toml", lambda: FLEET, check_fleet),
    "backup": ("pump-a.toml", backup_text, check_backup),
    "users": ("users.toml", users_text, check_users),
    "config": ("starterbus/config.toml", lambda: 'fleet = "工厂.toml"\n', check_config),
    "profile": ("toy.toml", lambda: TOY.read_text(encoding="utf-8"), check_profile),
    "credentials": ("mqtt.txt", lambda: "user\n密码\n", check_credentials),
}


def write(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def run_check(check: Callable[..., None], path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if check is check_config:
        check(path, monkeypatch)
    else:
        check(path)


@pytest.mark.parametrize("kind", CASES)
@pytest.mark.parametrize("bom", [False, True], ids=["utf8", "utf8-bom"])
def test_utf8_with_or_without_a_byte_order_mark_is_read(
    kind: str, bom: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    name, text, check = CASES[kind]
    data = (codecs.BOM_UTF8 if bom else b"") + text().encode("utf-8")
    run_check(check, write(tmp_path, name, data), monkeypatch)


@pytest.mark.parametrize("kind", CASES)
def test_a_gbk_file_is_one_line_naming_file_line_column_offset_and_byte(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    name, text, check = CASES[kind]
    data = text().encode("gbk")
    offset = next(i for i, b in enumerate(data) if b >= 0x80)
    line = data.count(b"\n", 0, offset) + 1
    column = offset - (data.rfind(b"\n", 0, offset) + 1) + 1  # ASCII before the first Chinese character
    path = write(tmp_path, name, data)
    with pytest.raises(ConfigurationError) as info:
        run_check(check, path, monkeypatch)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    assert f"line {line}, column {column} (byte offset {offset}): byte 0x{data[offset]:02X} is not UTF-8" in message
    assert "save the" in message and "as UTF-8" in message
    if kind == "profile":
        assert isinstance(info.value, ProfileError)


def test_the_column_counts_characters_and_the_offset_counts_the_byte_order_mark() -> None:
    data = codecs.BOM_UTF8 + 'a = 1\nb = "é中" # '.encode() + "中".encode("gbk")
    with pytest.raises(ConfigurationError, match=re.escape("f.toml: line 2, column 12 (byte offset 23): byte 0xD6")):
        decode_text(data, "f.toml")


def test_utf16_says_so() -> None:
    with pytest.raises(ConfigurationError, match=r"^f.toml: the fleet file is UTF-16 .*: save it as UTF-8$"):
        decode_text("a = 1".encode("utf-16"), "f.toml", "fleet file")


def test_an_unreadable_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError, match=r"missing.toml: cannot read the backup: No such file"):
        read_text_file(tmp_path / "missing.toml", "backup")


@pytest.mark.parametrize(
    "argv",
    [
        ["validate", "{path}"],
        ["poll", "{path}", "--once"],
        ["backup", "pump-a", "--fleet", "{path}", "-o", "{out}"],
        ["simulate", "--model", "jjr5000", "--script", "{path}"],
        ["decode", "modbus-rtu", "--file", "{path}"],
        ["restore", "{path}", "modbus-rtu:///dev/null", "--model", "jjr5000", "--dry-run"],
    ],
    ids=lambda argv: argv[0],
)
def test_the_cli_prints_one_line_and_exits_non_zero(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(tmp_path, "gbk.toml", FLEET.encode("gbk"))
    out = tmp_path / "out.toml"
    assert main([a.format(path=path, out=out) for a in argv]) != 0
    captured = capsys.readouterr()
    err = captured.err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{path}: line 1, column 3 (byte offset 2): byte 0xB1 is not UTF-8" in err  # 泵 is B1 C3 in GBK
    assert not out.exists()

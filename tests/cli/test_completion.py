"""Shell completion beyond commands and options: installed models, the fleet's device names and the parameter
keys of the model in question, from ``starterbus __complete`` (which opens no device) and through the bash, zsh
and fish scripts."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.completion import script
from starterbus.cli.completion_words import FILES, candidates
from starterbus.cli.main import main
from starterbus.core.registry import get_profile, profiles
from starterbus.core.transport import Transport

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))

FLEET = """
[[bus]]
name = "l1"
url = "modbus-rtu:///dev/ttyUSB7"
  [[bus.device]]
  name = "conveyor"
  model = "jjr5000"
  address = 2
  [[bus.device]]
  name = "crusher"
  model = "jjr8000"
  address = 3
"""


@pytest.fixture
def fleet(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A fleet file, none configured by default (no $STARTERBUS_FLEET, an empty config home); no device opens."""
    path = tmp_path / "plant.toml"
    path.write_text(FLEET, encoding="utf-8")
    monkeypatch.delenv("STARTERBUS_FLEET", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))

    def refuse(self: Transport) -> None:
        raise AssertionError(f"completion opened {self.url.text}")

    monkeypatch.setattr(Transport, "open", refuse)
    yield path


def keys(model: str, *, writable: bool = False) -> list[str]:
    points = get_profile(model).points.values()
    return [p.key for p in points if p.writable or not writable]


def test_models_for_model_options_and_params(fleet: Path) -> None:
    models = profiles.names()
    assert {"jjr5000", "jjr8000", "ssd1"} <= set(models)
    assert candidates(["status", "URL", "--model", ""]) == models
    assert candidates(["params", "jj"]) == [m for m in models if m.startswith("jj")]
    assert candidates(["read", "URL", "--model=ss"]) == ["--model=ssd1"]
    assert candidates(["status", "URL", "--model", "./my"]) == [FILES]  # a profile .toml


def test_device_names_from_each_place_a_fleet_is_named(fleet: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert candidates(["status", ""]) == []  # no fleet anywhere: the shell offers file names
    assert candidates(["status", "--fleet", str(fleet), ""]) == ["conveyor", "crusher"]
    assert candidates(["plot", "h.db", "--fleet", str(fleet), "--device", "cr"]) == ["crusher"]
    config = Path(os.environ["XDG_CONFIG_HOME"]) / "starterbus" / "config.toml"
    config.parent.mkdir(parents=True)
    config.write_text(f'fleet = "{fleet.as_posix()}"\n', encoding="utf-8")
    assert candidates(["read", "co"]) == ["conveyor"]
    other = fleet.with_name("other.toml")
    other.write_text(FLEET.replace('"conveyor"', '"mill"'), encoding="utf-8")
    monkeypatch.setenv("STARTERBUS_FLEET", str(other))  # before the config file, as every command does
    assert candidates(["start", ""]) == ["mill", "crusher"]  # in the order of the fleet file
    assert candidates(["diff", "c"]) == ["crusher", FILES]


def test_parameter_keys_of_the_model_or_of_the_device(fleet: Path) -> None:
    assert candidates(["read", "modbus-rtu:///dev/x?unit=2", "--model", "ssd1", ""]) == keys("ssd1")
    assert candidates(["read", "--fleet", str(fleet), "crusher", ""]) == keys("jjr8000")
    assert candidates(["watch", "conveyor", "--fleet", str(fleet), "phase_"]) == [
        k for k in keys("jjr5000") if k.startswith("phase_")
    ]
    writable = candidates(["write", "--fleet", str(fleet), "conveyor", "current_limit=10", ""])
    assert writable == [f"{k}=" for k in keys("jjr5000", writable=True)]
    assert "phase_a_current=" not in writable and "current_limit=" in writable
    picked = candidates(["crosscheck", "a", "b", "--model", "jjr5000", "--keys", "current_limit,ramp"])
    assert picked == ["current_limit,ramp_time"]
    assert candidates(["read", "nowhere", "--fleet", str(fleet), ""]) == []  # a name the fleet lacks: no keys


def test_options_choices_and_nested_commands(fleet: Path) -> None:
    assert candidates(["st"]) == ["start", "status", "stop"]
    assert "--model" in candidates(["read", "x", "--"]) and "--fleet" in candidates(["read", "x", "--f"])
    assert candidates(["completion", ""]) == ["bash", "zsh", "fish"]
    assert {"modbus-rtu", "devicenet"} <= set(candidates(["decode", ""]))
    assert "--no-crc" in candidates(["decode", "modbus-rtu", "--"])


def test_a_broken_fleet_or_model_offers_nothing_quietly(
    fleet: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"[[bus]\n\xff")
    assert main(["__complete", "--", "status", "--fleet", str(bad), ""]) == 0
    assert main(["__complete", "--", "read", "x", "--model", "nosuchmodel", ""]) == 0
    assert capsys.readouterr() == ("", "")
    assert main(["__complete", "--bash", "starterbus read x --model=jj", "jj"]) == 0  # bash splits at "="
    assert capsys.readouterr().out.split() == [m for m in profiles.names() if m.startswith("jj")]


def _env(fleet: Path) -> dict[str, str]:
    path = f"{Path(EXE).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    return {**os.environ, "PATH": path, "STARTERBUS_FLEET": str(fleet), "XDG_CONFIG_HOME": str(fleet.parent)}


BASH_DRIVER = """
source "$1"
complete_line() {
    COMP_LINE="$1"; COMP_POINT=${#COMP_LINE}
    read -ra COMP_WORDS <<< "$COMP_LINE"
    [[ "$COMP_LINE" == *" " ]] && COMP_WORDS+=("")
    COMP_CWORD=$(( ${#COMP_WORDS[@]} - 1 ))
    _starterbus
    printf '%s\\n' "${COMPREPLY[@]}" | sort | paste -sd ' '
}
complete_line "starterbus st"
complete_line "starterbus status --model "
complete_line "starterbus read "
complete_line "starterbus read crusher phase_"
complete_line "starterbus read modbus-rtu:///dev/ttyUSB0?unit=2 --model ssd1 motor_"
complete_line "starterbus write conveyor current_l"
"""


def test_the_bash_script(fleet: Path, tmp_path: Path) -> None:
    path = tmp_path / "starterbus.bash"
    path.write_text(script("bash") + "\n", encoding="utf-8")
    result = subprocess.run(["bash", "-c", BASH_DRIVER, "bash", str(path)], capture_output=True, text=True,
                            env=_env(fleet), timeout=120, check=False)  # fmt: skip
    assert result.returncode == 0 and result.stderr == "", result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "start status stop"
    assert lines[1] == " ".join(sorted(profiles.names()))
    assert lines[2] == "conveyor crusher"
    assert lines[3] == " ".join(sorted(k for k in keys("jjr8000") if k.startswith("phase_")))
    assert lines[4] == " ".join(sorted(k for k in keys("ssd1") if k.startswith("motor_")))
    assert lines[5] == "current_limit="


@pytest.mark.skipif(shutil.which("zsh") is None, reason="zsh is not installed")
def test_the_zsh_script(fleet: Path, tmp_path: Path) -> None:
    path = tmp_path / "_starterbus"
    path.write_text(script("zsh") + "\n", encoding="utf-8")
    driver = (
        'compadd() { [[ $1 == -S ]] && shift 2; shift; (( $# )) && print -r -- "$*"; }; _files() { print files; }; '
        't() { words=("$@"); CURRENT=$#; source "$SCRIPT"; }; '
        "t starterbus st; t starterbus status --model ''; t starterbus read crusher phase_; t starterbus poll ''"
    )
    result = subprocess.run(["zsh", "-fc", driver], capture_output=True, text=True, timeout=120, check=False,
                            env={**_env(fleet), "SCRIPT": str(path)})  # fmt: skip
    assert result.returncode == 0 and result.stderr == "", result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split()[:1] == ["backup"] and "status" in lines[0].split()
    assert lines[1].split() == profiles.names()
    assert lines[2].split() == [k for k in keys("jjr8000") if k.startswith("phase_")]
    assert lines[3] == "files"  # FLEET.toml: file names


@pytest.mark.skipif(shutil.which("fish") is None, reason="fish is not installed")
def test_the_fish_script(fleet: Path, tmp_path: Path) -> None:
    path = tmp_path / "starterbus.fish"
    path.write_text(script("fish") + "\n", encoding="utf-8")
    driver = (
        f"source {path}; complete -C'starterbus status --model j'; echo ==; complete -C'starterbus read con'; "
        "echo ==; complete -C'starterbus write crusher start_de'"
    )
    result = subprocess.run(["fish", "--no-config", "-c", driver], capture_output=True, text=True, timeout=120,
                            check=False, env=_env(fleet))  # fmt: skip
    assert result.returncode == 0 and result.stderr == "", result.stderr
    models, devices, assignments = (part.split() for part in result.stdout.split("==\n"))
    assert models == [m for m in profiles.names() if m.startswith("j")]
    assert devices == ["conveyor"]
    assert assignments == [f"{k}=" for k in keys("jjr8000", writable=True) if k.startswith("start_de")]

"""The ``Examples:`` of every command's ``--help``, in one table so that a test parses each line with the real
parser (tests/cli/test_help_examples.py) and an example cannot outlive the options it shows.

A line is what a user types: shell quoting, a trailing ``# comment``, a redirection (``> FILE``) or a pipe at
the end. ``conveyor-1`` is a device of the fleet file (``--fleet FILE``, ``$STARTERBUS_FLEET`` or the user's
config file); ``plant.toml`` is a fleet file.
"""

from __future__ import annotations

import argparse

_RTU = "'modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600&parity=E'"
_DNET = "'devicenet://socketcan/can0?mac=5'"

EXAMPLES: dict[str, tuple[str, ...]] = {
    "models": ("starterbus models", "starterbus models --json"),
    "params": (
        "starterbus params jjr8000                # key, 名称, addresses, range, unit, certainty",
        "starterbus params jjr5000 --json         # every choice of every parameter",
    ),
    "transports": ("starterbus transports", "starterbus transports --json   # capabilities and load errors"),
    "read": (
        "starterbus read conveyor-1                               # every measurement",
        "starterbus read conveyor-1 current_limit ramp_time --fleet plant.toml",
        f"starterbus read {_RTU} --model jjr5000 0x0100 --json",
        f"starterbus read {_DNET} --model jjr8000 m3",
    ),
    "write": (
        "starterbus write conveyor-1 ramp_time=12 current_limit=350 --dry-run   # the frames, nothing sent",
        'starterbus write conveyor-1 start_mode="voltage ramp" --yes',
        f"starterbus write {_RTU} --model jjr5000 motor_rated_current=390 --yes --audit-log audit.jsonl",
    ),
    "status": ("starterbus status conveyor-1", f"starterbus status {_RTU} --model jjr5000 --json"),
    "start": (
        "starterbus start conveyor-1 --yes --show-status",
        "starterbus start conveyor-1 --dry-run                    # the frames, nothing sent",
        f"starterbus start {_DNET} --model jjr8000 --yes --hold-for 30   # the run lives with the connection",
    ),
    "stop": ("starterbus stop conveyor-1 --yes", "starterbus stop conveyor-1 --yes --wait 30 --json"),
    "reset": ("starterbus reset conveyor-1 --yes --show-status", f"starterbus reset {_RTU} --model jjr5000 --yes"),
    "simulate": (
        "starterbus simulate --model jjr5000 --unit 2 --modbus-rtu PTY",
        "starterbus simulate --unit 2:jjr5000 --unit 3:ssd1 --modbus-rtu PTY --script faults.txt",
        "starterbus simulate --unit 2:jjr5000 --modbus-rtu PTY --fault 2:6 --json   # tripped from the start",
        "starterbus simulate --model jjr8000 --mac 5 --devicenet virtual:bus0 --devicenet-bridge 127.0.0.1:54701",
        "starterbus simulate --model jjr5000 --unit 1 --profibus-gateway 127.0.0.1:5020 --ppo 1",
    ),
    "decode": (
        "starterbus decode modbus-rtu --model jjr5000 02 03 01 00 00 01 85 C5 02 03 02 01 86 7C 76",
        "starterbus decode profibus-pkw --model jjr5000 --ppo 1 --direction out 02 03 01 5E 00 0B 00 00",
        "starterbus decode devicenet --model jjr8000 -f candump.log     # a `candump -l` log",
        "candump -L can0 | starterbus decode devicenet --model jjr8000 -",
    ),
    "poll": (
        "starterbus poll plant.toml                               # live table",
        "starterbus poll plant.toml --once --json",
        "starterbus poll plant.toml --csv plant.csv --record plant.db --keep 30d --keep 500MB",
        "starterbus poll plant.toml --plan                        # poll plans and wire budgets; sends nothing",
    ),
    "demo": ("starterbus demo", "starterbus demo --duration 60 --json"),
    "crosscheck": (
        "starterbus crosscheck --model jjr8000 'modbus-rtu:///dev/ttyUSB0?unit=2' "
        "'profibus-pkw+gateway://127.0.0.1:5020?ppo=1' 'devicenet://remote/127.0.0.1:54701?mac=5'",
        "starterbus crosscheck --model jjr5000 'modbus-rtu:///dev/ttyUSB0?unit=2' "
        "'modbus-rtu+tcp://10.0.0.7:4001?unit=2' --no-parameters --json",
    ),
    "scan": (
        "starterbus scan modbus-rtu:///dev/ttyUSB0 --quick -o plant.toml",
        "starterbus scan modbus-rtu:///dev/ttyUSB0 --units 1-10 --baudrates 9600,19200 --parities E --json",
    ),
    "identify": (
        "starterbus identify pump-a --fleet examples/fleet.toml",
        f"starterbus identify {_DNET} --model jjr8000 --json",
    ),
    "watch": (
        "starterbus watch conveyor-1 --fleet plant.toml",
        f"starterbus watch {_RTU} --model jjr5000 current_limit ramp_time --once",
        "starterbus watch conveyor-1 --interval 0.5 --count 10 --json",
    ),
    "validate": ("starterbus validate examples/fleet.toml", "starterbus validate plant.toml line-2.toml --json"),
    "completion": (
        "starterbus completion bash > ~/.local/share/bash-completion/completions/starterbus",
        'starterbus completion zsh > "${fpath[1]}/_starterbus"',
        "starterbus completion fish > ~/.config/fish/completions/starterbus.fish",
    ),
    "serve": (
        "starterbus serve --demo          # simulated fleet and a local mosquitto",
        "starterbus serve plant.toml --mqtt mqtts://broker.plant:8883 --ca-file /etc/starterbus/ca.pem "
        "--group plant-1 --node mcc-3 --metrics 127.0.0.1:9477",
        "starterbus serve plant.toml --mqtt mqtts://broker.plant:8883 --opcua opc.tcp://0.0.0.0:4840/starterbus "
        "--opcua-users users.toml",
    ),
    "backup": (
        "starterbus backup conveyor-1 -o conveyor-1.toml",
        f"starterbus backup {_RTU} --model jjr5000 -o conveyor-1.toml --json",
    ),
    "diff": (
        "starterbus diff conveyor-1.toml conveyor-1                 # the backup against the device now",
        "starterbus diff conveyor-1 conveyor-2 --json",
        "starterbus diff conveyor-1.toml 'modbus-rtu:///dev/ttyUSB0?unit=3@jjr5000'",
        "starterbus diff defaults conveyor-1.toml                   # what differs from the profile's defaults",
    ),
    "restore": (
        "starterbus restore conveyor-1.toml conveyor-1 --dry-run    # the differences and frames; nothing sent",
        "starterbus restore conveyor-1.toml conveyor-1 --yes",
        "starterbus restore conveyor-1.toml 'modbus-rtu:///dev/ttyUSB0?unit=3' --model jjr5000 --yes --json",
    ),
    "history": (
        "starterbus history plant.db --events",
        "starterbus history plant.db --device conveyor-1 --since 10m --limit 3",
        "starterbus history plant.db --events --kind fault --since 2026-11-23T08:00 --json",
        "starterbus history plant.db --csv > plant.csv",
    ),
    "record": (
        "starterbus record conveyor-1 --start --yes -o starts       # start it and record the start",
        f"starterbus record {_RTU} --model jjr5000 -o starts --limit 600 --name conveyor-1   # the next start",
    ),
    "plot": (
        "starterbus plot starts/starts.db --device conveyor-1 --event 1 -o start.png",
        "starterbus plot plant.db --device conveyor-1 --event 42    # a start or a trip from `poll --record`",
    ),
    "opcua": (
        "starterbus opcua --demo --endpoint opc.tcp://127.0.0.1:4840/starterbus --users users.toml",
        "starterbus opcua plant.toml --endpoint opc.tcp://0.0.0.0:4840/starterbus --users users.toml "
        "--pki /var/lib/starterbus/pki",
    ),
    "opcua-trust": (
        "starterbus opcua-trust --pki /var/lib/starterbus/pki     # the refused client certificates, and the trusted",
        "starterbus opcua-trust --pki /var/lib/starterbus/pki UaExpert_3F2A9C0D1E4B5A6F7081920A1B2C3D4E5F607182.der",
    ),
    "opcua-user": (
        "starterbus opcua-user users.toml alice --role operator     # asks for the password twice",
        "starterbus opcua-user users.toml scada --role read-only",
        "starterbus opcua-user users.toml alice --delete",
    ),
}


def attach(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Append each command's examples to its epilog (after what the command's own module wrote there)."""
    for name, parser in sub.choices.items():
        lines = EXAMPLES.get(name)
        if not lines:
            continue
        examples = "Examples:\n" + "\n".join(f"  {line}" for line in lines)
        parser.epilog = f"{parser.epilog}\n\n{examples}" if parser.epilog else examples
        parser.formatter_class = argparse.RawDescriptionHelpFormatter


__all__ = ["EXAMPLES", "attach"]

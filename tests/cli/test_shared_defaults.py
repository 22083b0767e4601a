"""Options that name the same thing in several commands have the same default: `opcua-trust` lists and trusts
the certificates of the PKI directory that `opcua` and `serve --opcua` use when no directory is given."""

from __future__ import annotations

import argparse

from starterbus.cli.parser import build_parser
from starterbus.opcua.server import OpcUaSettings


def defaults(command: str, *argv: str) -> argparse.Namespace:
    return build_parser([command]).parse_args([command, *argv])


def test_one_default_pki_directory_for_opcua_serve_and_opcua_trust() -> None:
    served = defaults("serve", "--demo").opcua_pki
    assert served == defaults("opcua", "--demo").pki == defaults("opcua-trust").pki
    assert str(OpcUaSettings("opc.tcp://127.0.0.1:4840").pki_dir) == served

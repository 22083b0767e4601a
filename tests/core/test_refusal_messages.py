"""Device refusals that mean the same thing read the same, whatever protocol brought them."""

from __future__ import annotations

import pytest

from starterbus.core.errors import REFUSAL_TEXT, Refusal, RemoteDeviceError, classify_refusal
from starterbus.core.registry import get_profile


def meaning(model: str, transport: str, table: str, code: int) -> str:
    return str(get_profile(model).transport_settings(transport)[table][code])


@pytest.mark.parametrize(
    ("a", "b", "reason"),
    [
        (("jjr5000", "modbus-rtu", "exceptions", 4), ("jjr5000", "profibus-pkw", "errors", 4), Refusal.WRITE_PROTECTED),
        (("jjr8000", "profibus-pkw", "errors", 3), ("devicenet", 0x10), Refusal.WHILE_RUNNING),
    ],
)
def test_same_refusal_same_words(a: tuple[object, ...], b: tuple[object, ...], reason: Refusal) -> None:
    def error(spec: tuple[object, ...]) -> RemoteDeviceError:
        if spec[0] == "devicenet":
            return RemoteDeviceError("devicenet", 0x10, "device state conflict")
        model, transport, table, code = spec
        return RemoteDeviceError(
            str(transport), int(str(code)), meaning(str(model), str(transport), str(table), int(str(code)))
        )

    first, second = error(a), error(b)
    assert first.reason is second.reason is reason
    assert str(first).startswith(REFUSAL_TEXT[reason]) and str(second).startswith(REFUSAL_TEXT[reason])
    assert first.meaning in str(first)  # the device's own words are kept


def test_an_ambiguous_text_is_not_guessed() -> None:
    text = meaning("jjr5000", "modbus-rtu", "exceptions", 3)  # "value out of limits, or parameter not modifiable"
    assert classify_refusal(text) is None
    assert str(RemoteDeviceError("modbus-rtu", 3, text)).startswith("modbus-rtu error 0x03")

"""The decoder against golden frames (CiA 301 layouts; TPDO1/RPDO1 of this plugin's design)."""

from __future__ import annotations

import pytest
from starterbus_canopen.decoder import annotate_frames, parse_candump

from starterbus.core import Annotation, DecodeError, get_profile


def one(frame: str, model: str | None = "example_canopen_starter") -> Annotation:
    (annotation,) = annotate_frames([frame], get_profile(model) if model else None)
    return annotation


def meanings(annotation: Annotation) -> list[str]:
    return [m for _, _, m in annotation.fields]


@pytest.mark.parametrize(
    ("frame", "title", "expected"),
    [
        ("000#0105", "NMT", ["start remote node (operational)", "node 5"]),
        ("000#8100", "NMT", ["reset node", "all nodes"]),
        ("080#", "SYNC", ["no counter"]),
        ("705#00", "heartbeat node 5", ["boot-up"]),
        ("705#05", "heartbeat node 5", ["operational"]),
        ("705#FF", "heartbeat node 5", ["pre-operational (node guarding, toggle bit set)"]),
        ("085#3081110000000000", "EMCY node 5", ["life guard error or heartbeat error", "generic, communication", ""]),
        ("605#4001200000000000", "SDO request", ["initiate upload", "status_word"]),
        (
            "585#4B0120000820_0000".replace("_", ""),
            "SDO response",
            ["upload response (expedited)", "status_word", "8200"],
        ),
        (
            "605#2B0021000401_0000".replace("_", ""),
            "SDO request",
            ["initiate download (expedited)", "motor_rated_current", "motor_rated_current = 260 A (raw 260)"],
        ),
        ("585#6000210000000000", "SDO response", ["download confirmed", "motor_rated_current"]),
        (
            "585#8000210000000206",
            "SDO response",
            ["abort transfer", "motor_rated_current", "object does not exist in the object dictionary"],
        ),
        (
            "585#8047210020000008",
            "SDO response",
            ["abort transfer", "parameter_modify", "data cannot be transferred or stored to the application"],
        ),
        ("205#0900", "RPDO1 node 5", ["start, bus control"]),
        ("185#0020E803", "TPDO1 node 5", ["ready", "100.0 A"]),
        ("185#0681_0000".replace("_", ""), "TPDO1 node 5", ["fault, fault 6: motor overload", "0.0 A"]),
    ],
)
def test_golden_frames(frame: str, title: str, expected: list[str]) -> None:
    annotation = one(frame)
    assert annotation.error is None, annotation.error
    assert title in annotation.title
    got = meanings(annotation)
    for want in expected:
        assert any(want in m for m in got), (want, got)


def test_expedited_value_decodes_through_the_profile() -> None:
    annotation = one("585#4B0021008601_0000".replace("_", ""))
    assert annotation.fields[-1] == ("data", "86 01", "motor_rated_current = 390 A (raw 390)")


def test_segmented_upload_is_followed_across_frames() -> None:
    frames = ["605#4008100000000000", "585#4108100009000000", "605#6000000000000000", "585#004558414D504C45",
              "605#7000000000000000", "585#1B20313200000000"]  # fmt: skip
    annotations = annotate_frames(frames, None)
    assert all(a.error is None for a in annotations), [a.error for a in annotations]
    assert annotations[1].fields[-1][2] == "9 bytes follow"
    assert annotations[-1].fields[-1] == ("0x1008:00", "45 58 41 4D 50 4C 45 20 31", "complete: EXAMPLE 1")


def test_pdo_without_a_profile_is_shown_raw() -> None:
    assert meanings(one("185#00A0E803", None)) == ["mapping unknown (give --model of a canopen profile)"]


@pytest.mark.parametrize(
    ("frame", "error"),
    [
        ("185#00A0", "TPDO1 has 2 bytes"),
        ("205#090000", "RPDO1 has 3 bytes"),
        ("605#4001", "SDO needs 8 bytes"),
        ("000#07", "NMT needs 2 bytes"),
        ("000#0705", "unknown NMT command 0x07"),
        ("085#3081", "EMCY needs 8 bytes"),
        ("180#0000", "node id 0"),
    ],
)
def test_bad_frames_give_an_error_never_a_value(frame: str, error: str) -> None:
    annotation = one(frame)
    assert annotation.error is not None and error in annotation.error


@pytest.mark.parametrize("text", ["", "xyz", "800#00", "123#001", "185#001122334455667788", "185 00"])
def test_candump_syntax_errors_are_typed(text: str) -> None:
    with pytest.raises(DecodeError):
        parse_candump(text)
    assert annotate_frames([text], None)[0].error


@pytest.mark.parametrize(
    "text", ["185#0020E803", " 185#00.20.E8.03 ", "185#00 20 E8 03", "(1700000000.5) can0 185#0020E803"]
)
def test_every_candump_form_the_devicenet_decoder_reads_is_read(text: str) -> None:
    """One parser for every CAN decoder: a ``candump -L`` log line decodes here as it does for DeviceNet."""
    assert parse_candump(text).text() == "185#0020E803"
    assert one(text).error is None


@pytest.mark.parametrize(
    ("text", "why"), [("705#R", "remote frame"), ("705##100", "CAN FD"), ("1ABCDEF0#00", "29-bit")]
)
def test_frames_the_decoder_does_not_read_are_named(text: str, why: str) -> None:
    (annotation,) = annotate_frames([text], None)
    assert annotation.error is not None and why in annotation.error and "the CANopen decoder" in annotation.error

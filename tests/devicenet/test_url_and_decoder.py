"""devicenet:// URLs and the `decode` annotator (stateful across frames: fragments, requests, selections)."""

from __future__ import annotations

import pytest

from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile
from starterbus.core.registry import get_transport
from starterbus.core.status import Command
from starterbus.core.url import DeviceUrl
from starterbus.transports.devicenet.decoder import annotate_frames
from starterbus.transports.devicenet.transport import DeviceNetTransport
from starterbus.transports.devicenet.url import parse_url


def test_url_defaults(jjr8000: Profile) -> None:
    scanner, link = parse_url(DeviceUrl.parse("devicenet://pcan/PCAN_USBBUS1?mac=5"), jjr8000)
    assert (scanner.interface, scanner.channel, scanner.master_mac, scanner.bitrate) == (
        "pcan",
        "PCAN_USBBUS1",
        0,
        500000,
    )
    assert (scanner.poll_period, scanner.dup_mac_wait, scanner.timeout) == (0.02, 1.0, 1.0)
    assert (link.mac, link.assemblies, link.epr_ms, link.settle, link.interval) == (5, "auto", 100, 2, 0.02)
    assert link.product == "JJR8000"  # from the profile, for messages
    scanner, _ = parse_url(DeviceUrl.parse("devicenet://remote/127.0.0.1:54701?mac=5"), jjr8000)
    assert (scanner.interface, scanner.channel) == ("remote", "127.0.0.1:54701")


@pytest.mark.parametrize(
    ("query", "interval", "epr"),
    [
        ("period=1", 1.0, 2000),  # a fleet polling every second: one poll a second, watchdog 8 s
        ("period=0.2", 0.2, 400),
        ("period=0.02", 0.02, 100),  # the floor of the expected packet rate
        ("period=0", 0.005, 100),  # the floor of the interval
        ("period=60", 1.0, 2000),  # the ceiling protects the watchdog: a slave never waits long for a poll
        ("period=1&epr=5000", 1.0, 5000),  # an explicit epr wins
        ("poll=50&epr=200", 0.05, 200),
    ],
)
def test_period_sets_interval_and_expected_packet_rate(jjr8000: Profile, query: str, interval: float, epr: int) -> None:
    _, link = parse_url(DeviceUrl.parse(f"devicenet://virtual/bus0?mac=5&{query}"), jjr8000)
    assert (link.interval, link.epr_ms) == (interval, epr)
    assert link.interval is not None and link.interval * 1000 <= link.epr_ms


def test_transport_declares_its_run_command_needs_the_connection() -> None:
    assert DeviceNetTransport.run_needs_connection is True


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("devicenet://virtual/bus0?mac=5&period=1&poll=20", "period .* or poll"),
        ("devicenet://virtual/bus0?mac=5&period=1&epr=500", "exceeds the expected packet rate"),
        ("devicenet://virtual/bus0", "mac: required"),
        ("devicenet://virtual/bus0?mac=0", "outside 1..63"),
        ("devicenet://virtual/bus0?mac=64", "outside 1..63"),
        ("devicenet://virtual?mac=5", "INTERFACE/CHANNEL"),
        ("devicenet://virtual/bus0?mac=5&master_mac=5", "both 5"),
        ("devicenet://virtual/bus0?mac=5&bitrate=1000000", "not one of 125000, 250000, 500000"),
        ("devicenet://virtual/bus0?mac=5&assemblies=big", "not one of auto, basic, extended"),
        ("devicenet://virtual/bus0?mac=5&epr=20&poll=50", "exceeds the expected packet rate"),
        ("devicenet://virtual/bus0?mac=5&unit=5", "unknown URL parameter"),
    ],
)
def test_url_errors(jjr8000: Profile, text: str, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message):
        parse_url(DeviceUrl.parse(text), jjr8000)


def test_plugin_and_preview(jjr8000: Profile) -> None:
    plugin = get_transport("devicenet")
    transport = plugin.open(DeviceUrl.parse("devicenet://virtual/x?mac=5"), jjr8000)
    assert isinstance(transport, DeviceNetTransport)
    assert transport.preview_command(Command.START) == ["42D#0101"]  # not open: extended guessed, status word
    assert transport.preview_command(Command.FAULT_RESET) == ["42D#0401", "42D#0001"]
    basic = plugin.open(DeviceUrl.parse("devicenet://virtual/x?mac=6&assemblies=basic"), jjr8000)
    assert basic.preview_command(Command.SOFT_STOP) == ["435#00"]
    with pytest.raises(Exception, match="parameter access"):
        basic.preview_write(jjr8000.point("p3"), 10)


FRAMES = [
    "42E#004B03010300",  # allocate
    "42B#00CB00",
    "999",  # garbage
    "42C#400E010107",  # get product name
    "3C6#2000000000 00",  # another slave's response, interleaved
    "42B#C0008E074A4A5238",  # first fragment
    "42C#C0C000",  # acknowledgement
    "42B#C081303030",  # last fragment
    "42D#0103",  # poll: start, select phase B current
    "3C5#2401600071 01",  # running, 96 A, selected 0x0171 = 369 -> 36.9 A
    "42E#074B03010307",
    "42B#07940C01",  # allocated to another master
    "42F#00330305011120",
    "7F0#00",
]


def test_decoder_annotates_a_conversation(jjr8000: Profile) -> None:
    notes = annotate_frames(FRAMES, jjr8000)
    assert len(notes) == len(FRAMES)
    by_title = {n.title.split()[0]: n for n in notes}

    def fields(key: str) -> dict[str, tuple[str, str]]:
        return {f: (raw, meaning) for f, raw, meaning in by_title[key].fields}

    allocate = fields("42E#004B03010300")
    assert allocate["service"][1].startswith("Allocate_Master/Slave_Connection_Set request")
    assert allocate["allocation choice"] == ("0x03", "explicit + polled")
    assert notes[2].error is not None and "candump" in notes[2].error
    last = fields("42B#C081303030")
    assert last["fragment"] == ("0x81", "last fragment, count 1")
    assert last["reassembled"][1] == "10 bytes from 2 fragments"
    assert last["data"] == ("07 4A 4A 52 38 30 30 30", "product name 'JJR8000'")
    assert fields("42C#C0C000")["fragment"][1] == "acknowledgement of fragment 0"
    poll = fields("42D#0103")
    assert poll["byte 0"] == ("0x01", "start")
    assert poll["byte 1"] == ("0x03", "status parameter 0x03 phase_b_current (m3)")
    response = fields("3C5#240160007101")
    assert response["byte 0"][1] == "running, network control"
    assert response["bytes 2-3"][1] == "L1 current 96 A (resolution 1 A)"
    assert response["bytes 4-5"][1] == "phase_b_current = 36.9 A (raw 369, address 0x03)"
    error = fields("42B#07940C01")
    assert error["general status"] == ("0x0C", "object state conflict")
    assert error["additional status"][1].startswith("the connection set is already allocated to another master")
    dup = fields("42F#00330305011120")
    assert dup["vendor id"][0] == "819" and dup["serial number"][0] == "0x20110105"
    assert notes[-1].error is not None and "invalid range" in notes[-1].error


def test_decoder_reports_broken_fragments_and_lengths(jjr8000: Profile) -> None:
    notes = annotate_frames(["42B#80813030", "3C5#2401", "42D#010203", "42B#0094"], jjr8000)
    assert [n.error is not None for n in notes] == [True, True, True, True]
    assert "without a first fragment" in (notes[0].error or "")
    assert "0x06 partial transfer" in (notes[0].error or "")
    assert "neither input assembly" in (notes[1].error or "")


def test_decoder_without_profile() -> None:
    notes = annotate_frames(["42D#0103", "3C5#240160007101", "42D#"])
    assert notes[1].fields[-1][2] == "status parameter 0x03 = 369"
    assert notes[2].fields[-1][2] == "zero-length poll command: master idle"

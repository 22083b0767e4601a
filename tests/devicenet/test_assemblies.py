"""JJR8000 assemblies 1/101 (inputs) and 2/102 (outputs) and their neutral status/commands (manual 3.2.4, 3.3.5)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core import CW_BUS_CONTROL, Command, ControlWordState, EncodeError, MotorState, Profile
from starterbus.transports.devicenet.codec.assemblies import (
    AssemblySet,
    InputAssembly,
    OutputAssembly,
    decode_input,
    decode_output,
    output_for_word,
)
from starterbus.transports.devicenet.codec.cip import FrameTooLongError, FrameTooShortError, UnexpectedFrameError

# (hex, assembly) - bit 0 fault, 1 warning, 2 running, 3 starting, 4 stopping, 5 network control, 7 at reference
INPUTS = [
    ("A4 00 60 00", InputAssembly(1, 0xA4, 96)),  # running, network control, at reference, L1 96 A
    ("28 00 C0 03", InputAssembly(1, 0x28, 960)),  # starting, network control, 960 A
    ("01 00 8A 00", InputAssembly(1, 0x01, 138)),  # fault (code not in assembly 1), 138 A
    ("21 06 8A 00 00 81", InputAssembly(101, 0x21, 138, 6, 0x8100)),  # fault 6 motor overload; status word 0x8100
    ("24 00 60 00 EB 00", InputAssembly(101, 0x24, 96, 0, 0x00EB)),  # running; selected value 235
    ("12 00 05 00 00 00", InputAssembly(101, 0x12, 5, 0, 0)),  # soft stopping with a warning
]
OUTPUTS = [
    ("01", OutputAssembly(2, 0x01)),  # start
    ("00", OutputAssembly(2, 0x00)),  # stop
    ("04", OutputAssembly(2, 0x04)),  # fault reset
    ("01 03", OutputAssembly(102, 0x01, 3)),  # start, report status parameter 3 (phase B current)
    ("04 10", OutputAssembly(102, 0x04, 0x10)),  # reset, report the last fault code
]


@pytest.mark.parametrize(("text", "assembly"), INPUTS)
def test_input_vectors(text: str, assembly: InputAssembly) -> None:
    data = bytes.fromhex(text)
    assert assembly.encode() == data
    assert decode_input(data) == assembly
    assert decode_input(data, assembly.instance) == assembly


@pytest.mark.parametrize(("text", "assembly"), OUTPUTS)
def test_output_vectors(text: str, assembly: OutputAssembly) -> None:
    data = bytes.fromhex(text)
    assert assembly.encode() == data
    assert decode_output(data) == assembly


def test_status_from_assembly_1(jjr8000: Profile) -> None:
    status = decode_input(bytes.fromhex("A4 00 60 00")).to_status(jjr8000, timestamp=5.0)
    assert status.state is MotorState.RUNNING
    assert (status.running, status.starting, status.stopping, status.fault) == (True, False, False, False)
    assert status.bus_control is True and status.at_reference is True and status.warning is False
    assert status.ready is None  # no assembly reports it
    current = status.currents["a"]
    assert (current.raw, current.value, current.resolution, current.point.key) == (96, 96, 1.0, "phase_a_current")
    assert current.text() == "96 A"
    assert status.raw["input_assembly"] == 1 and status.raw["current_l1"] == 96
    assert status.source == "devicenet" and status.timestamp == 5.0


def test_fault_without_code_from_assembly_1(jjr8000: Profile) -> None:
    status = decode_input(bytes.fromhex("01 00 8A 00")).to_status(jjr8000)
    assert status.fault and status.state is MotorState.FAULT
    assert status.fault_code is None
    assert status.fault_text == "fault (input assembly 1 does not report the code)"


def test_fault_code_from_assembly_101(jjr8000: Profile) -> None:
    status = decode_input(bytes.fromhex("21 06 8A 00 00 81")).to_status(jjr8000, selected_address=1)
    assert (status.fault_code, status.fault_text) == (6, "motor overload")
    assert status.at_reference is None  # bit 7 is reserved in 101
    assert status.raw["selected_address"] == 1 and status.raw["selected_value"] == 0x8100
    unknown = decode_input(bytes.fromhex("01 0E 00 00 00 00")).to_status(jjr8000)
    assert unknown.fault_text == "unknown fault 14"  # 14 is blank in appendix table 1


def test_reserved_bits_are_kept(jjr8000: Profile) -> None:
    assert decode_input(bytes.fromhex("40 00 00 00")).to_status(jjr8000).unknown_bits == 0x40
    assert decode_input(bytes.fromhex("C0 00 00 00 00 00")).to_status(jjr8000).unknown_bits == 0xC0
    assert decode_input(bytes.fromhex("80 00 00 00 00 00")).bit_names() == ["reserved bit 7"]


@pytest.mark.parametrize(
    ("text", "instance", "error"),
    [
        ("", None, FrameTooShortError),
        ("21 00 00", None, FrameTooShortError),
        ("21 00 00 00 00", None, FrameTooShortError),
        ("21 00 00 00 00 00 00", None, FrameTooLongError),
        ("21 00 00 00", 101, FrameTooShortError),
        ("21 00 00 00 00 00", 1, FrameTooLongError),
        ("21 00 00 00", 3, UnexpectedFrameError),
    ],
)
def test_input_length_errors(text: str, instance: int | None, error: type[Exception]) -> None:
    with pytest.raises(error):
        decode_input(bytes.fromhex(text), instance)


def test_output_length_errors() -> None:
    with pytest.raises(FrameTooShortError):
        decode_output(b"")
    with pytest.raises(FrameTooLongError):
        decode_output(b"\x01\x02\x03")
    with pytest.raises(FrameTooShortError):
        decode_output(b"\x01", 102)
    with pytest.raises(EncodeError):
        OutputAssembly(3, 0).encode()
    with pytest.raises(EncodeError):
        InputAssembly(1, 0, 70000).encode()


def test_commands_through_the_core_control_word_state() -> None:
    """Core ControlWordState drives the output byte: bit 0 start level, bit 2 reset pulse; bit 3 is implicit."""
    state = ControlWordState()
    assert [output_for_word(w, 2).encode() for w in state.apply(Command.START)] == [b"\x01"]
    assert [output_for_word(w, 102, 3).encode() for w in state.apply(Command.FAULT_RESET)] == [b"\x04\x03", b"\x00\x03"]
    assert [output_for_word(w, 2).encode() for w in state.apply(Command.SOFT_STOP)] == [b"\x00"]


def test_slave_side_control_word_sets_bus_control() -> None:
    """The slave applies start/reset with control word bit 3 set: the JJR8000 obeys commands only with it."""
    assert OutputAssembly(2, 0x01).control_word() == 0x01 | CW_BUS_CONTROL == 0x0009  # the manual's start word
    assert OutputAssembly(102, 0x04, 7).control_word() == 0x04 | CW_BUS_CONTROL
    assert OutputAssembly(2, 0xF2).control_word() == CW_BUS_CONTROL  # reserved bits are not passed on
    assert OutputAssembly(2, 0xF3).bit_names() == ["start", "reserved bits 0xF2"]


def test_assembly_sets() -> None:
    assert (AssemblySet.BASIC.input_instance, AssemblySet.BASIC.output_instance) == (1, 2)
    assert (AssemblySet.EXTENDED.input_size, AssemblySet.EXTENDED.output_size) == (6, 2)
    assert AssemblySet.for_sizes(4, 1) is AssemblySet.BASIC
    assert AssemblySet.for_sizes(6, 2) is AssemblySet.EXTENDED
    assert AssemblySet.for_sizes(6, 1) is None


@given(st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 255), st.integers(0, 0xFFFF))
def test_input_round_trip(bits: int, current: int, code: int, value: int) -> None:
    basic = InputAssembly(1, bits, current, reserved=code)
    extended = InputAssembly(101, bits, current, code, value)
    assert decode_input(basic.encode()) == basic
    assert decode_input(extended.encode()) == extended


@given(st.integers(0, 255), st.integers(0, 255))
def test_output_round_trip(bits: int, address: int) -> None:
    assert decode_output(OutputAssembly(2, bits).encode()) == OutputAssembly(2, bits)
    assert decode_output(OutputAssembly(102, bits, address).encode()) == OutputAssembly(102, bits, address)

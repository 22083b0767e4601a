"""A device is online only after a poll it answered: an error sample is never online (issue 26, item 6)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import pytest

from starterbus.core.device import Device
from starterbus.core.errors import ConfigurationError, DecodeError, RemoteDeviceError, StarterbusError
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.transport import PollResult
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import FleetConfig, parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.tests.stub_transport import StubTransport

FLEET = (
    "[poll]\nperiod = 0.01\nmax_backoff = 0.01\n"
    '[[bus]]\nname = "line"\nurl = "modbus-rtu+tcp://127.0.0.1:9?baudrate=19200"\n'
    '[[bus.device]]\nname = "m"\nmodel = "jjr5000"\naddress = 2\n'
)


class FailingTransport(StubTransport):
    """Answers every poll with ``error`` (None: a good answer)."""

    name = "failing"

    def __init__(self, profile: Profile, error: StarterbusError | None) -> None:
        super().__init__(DeviceUrl.parse("failing://line"), profile)
        self.error = error

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        if self.error is not None:
            raise self.error
        return PollResult(None, [Reading(p, 7) for p in points])


def _poll_rounds(config: FleetConfig, rounds: int, error: StarterbusError | None = None) -> list[Sample]:
    samples: list[Sample] = []
    poller = FleetPoller(config, samples.append, rounds=rounds, multiplex=False)
    if error is not None:  # else the device opens its URL
        profile = get_profile("jjr5000")
        poller.workers[0].devices[0].device = Device(FailingTransport(profile, error), profile).open()
    poller.start()
    poller.join(timeout=20)
    assert not poller.running
    return samples


def test_a_url_setting_the_model_cannot_speak_gives_offline_samples_naming_it() -> None:
    """The issue's case: ``baudrate=115200`` on a JJR5000 (2400-19200) written past the fleet file's checks
    (a hand-built config): every sample is offline and names the baud rate, never online with no values."""
    config = parse_fleet(FLEET)
    device = dataclasses.replace(config.devices[0], url=config.devices[0].url.replace("19200", "115200"))
    bus = dataclasses.replace(config.buses[0], devices=(device,))
    config = dataclasses.replace(config, buses=(bus,), devices_by_name={device.name: device})
    samples = _poll_rounds(config, rounds=3)
    assert len(samples) == 3
    for sample in samples:
        assert not sample.online and sample.status is None and sample.values == {}
        assert sample.error is not None and "baudrate" in sample.error and "115200" in sample.error
        assert sample.as_json()["online"] is False
    assert samples[-1].errors == 3


@pytest.mark.parametrize(
    "error",
    [
        RemoteDeviceError("modbus", 2, "illegal data address"),
        DecodeError("CRC mismatch", b"\x02\x03"),
        ConfigurationError("ppo: 3 is not offered"),
    ],
    ids=["exception-response", "garbage", "configuration"],
)
def test_any_error_sample_is_offline_and_counted(error: StarterbusError) -> None:
    samples = _poll_rounds(parse_fleet(FLEET), rounds=2, error=error)
    assert [s.online for s in samples] == [False, False]
    assert all(s.error == str(error) and s.values == {} and s.status is None for s in samples)
    assert samples[-1].errors == 2


def test_a_good_answer_is_online_with_its_values() -> None:
    """The same stub answering: online, with values (the test above can fail)."""
    config = parse_fleet(FLEET)
    samples: list[Sample] = []
    poller = FleetPoller(config, samples.append, rounds=2, multiplex=False)
    profile = get_profile("jjr5000")
    runtime = poller.workers[0].devices[0]
    runtime.device = Device(FailingTransport(profile, None), profile).open()
    poller.start()
    poller.join(timeout=20)
    assert [s.online for s in samples] == [True, True]
    assert all(s.error is None and s.values for s in samples)
    assert runtime.online is True and runtime.last_ok is not None

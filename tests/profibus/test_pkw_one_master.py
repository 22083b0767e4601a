"""One master per gateway station on a machine: a second program opening the station is refused in one line
naming the holder (its PKW tasks would get the other's answers: a measurement for a parameter of the same
number); channels of one process share the hold; the station is free again once its holder is gone."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import TransportError
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.profibus_pkw.driver.station_lock import LOCK_DIR_ENV
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

HOLDER = """
import sys
from starterbus.core.device import open_device
with open_device(sys.argv[1], "jjr5000") as device:
    device.status()
    print("held", flush=True)
    sys.stdin.read()
"""


@pytest.fixture
def gateway(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[ProfibusGatewaySimulator]:
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))
    sim = ProfibusGatewaySimulator([SimulatedStarter(get_profile("jjr5000"))], host="127.0.0.1", port=0, ppo=1)
    with sim.start() as running:
        yield running


def test_a_second_program_on_the_station_is_refused_until_the_first_is_gone(gateway: ProfibusGatewaySimulator) -> None:
    url = gateway.url(0)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, url], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=os.environ
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        with pytest.raises(TransportError) as refused, open_device(url, "jjr5000"):
            pass
        message = str(refused.value)
        assert f"gateway 127.0.0.1:{gateway.port} unit 1 out=0 is in use by another program" in message
        assert f"pid {holder.pid}" in message and "\n" not in message
    finally:
        holder.communicate("", timeout=30)
    with open_device(url, "jjr5000") as device:  # the holder is gone: free again
        assert device.status() is not None


def test_channels_of_one_process_share_the_station(gateway: ProfibusGatewaySimulator) -> None:
    url = gateway.url(0)
    with open_device(url, "jjr5000") as first, open_device(url, "jjr5000") as second:
        assert first.status() is not None and second.status() is not None
    with open_device(url, "jjr5000") as again:
        assert again.status() is not None

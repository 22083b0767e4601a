"""``polled``, the Sample a poller makes each poll without ``Sample.__init__``, is the Sample ``__init__`` makes."""

from __future__ import annotations

import dataclasses
import json
import pickle

import pytest

from starterbus.core.polling import TransportCounters
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.fleet.sample import Sample, polled


def test_polled_is_the_sample_init_makes() -> None:
    profile = get_profile("jjr5000")
    status = decode_status_word(0x2200, profile.faults)
    wire = TransportCounters(1, 1)
    made = polled("m1", "l1", "jjr5000", 1.5, True, status, {}, None, 2, ("x",), wire, False)
    expected = Sample("m1", "l1", "jjr5000", 1.5, True, status, {}, None, 2, ("x",), wire, False)
    assert type(made) is Sample and made == expected and repr(made) == repr(expected)
    assert json.dumps(made.as_json()) == json.dumps(expected.as_json())
    assert pickle.loads(pickle.dumps(made)) == made
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.online = False  # type: ignore[misc]
    assert [f.name for f in dataclasses.fields(Sample)] == list(Sample.__slots__)  # polled sets them all

"""The conformance kit fails on every deliberately broken Modbus RTU transport (tests/conformance/mutants.py) and
passes the sound one, in the same sub-runs (pytest's ``pytester``).

Each mutant is a test class of the kit (the Modbus RTU hooks of ``modbus_kit.py``, the plugin opening the
mutant). A class stops at its first failure (the kit has caught it; the rest would only cost time) and the
slowest checks run last. The mutants run in a few batches side by side, each its own pytest process: most of the
kit's time is waiting for timeouts, not CPU.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import pytest

from starterbus.tests.conformance.mutants import MUTANTS

pytest_plugins = ["pytester"]

BATCHES = 3
SOUND = "TestSound"

#: the sub-runs import the kit and the mutants as ``starterbus.tests...``, as tests/conftest.py arranges for the
#: suite; an installed (not editable) starterbus has no ``tests`` package, so the same arrangement goes first
IMPORTS = """
import importlib.util
import sys
import types

if importlib.util.find_spec("starterbus.tests") is None:
    package = types.ModuleType("starterbus.tests")
    package.__path__ = [{tests!r}]
    sys.modules["starterbus.tests"] = package
"""

CONFTEST = """
import pytest

#: the slow checks last: a mutant usually fails sooner
LAST = ("test_a_slow_device_is_waited_for", "test_a_silent_device", "test_a_late_answer_is_never_a_value",
        "test_reads_never_actuate")
failed = set()


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: (item.cls.__name__, item.originalname in LAST, LAST.index(item.originalname)
                                 if item.originalname in LAST else 0))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.failed:
        failed.add(item.cls.__name__)
    return report


def pytest_runtest_setup(item):
    if item.cls.__name__ in failed and item.cls.__name__ != "TestSound":
        pytest.skip("the kit has already failed this mutant")
"""

KIT = """
import contextlib

from starterbus.tests.conformance.modbus_kit import ModbusRtuKit
from starterbus.tests.conformance.mutants import MUTANTS, installed

NAMES = {NAMES}
WITH_SOUND = {WITH_SOUND}


class Mutated(ModbusRtuKit):
    mutant = None

    def installed(self):
        return installed(self.mutant) if self.mutant is not None else contextlib.nullcontext()

    @contextlib.contextmanager
    def serve(self, starter):
        with self.installed(), super().serve(starter) as url:
            yield url

    @contextlib.contextmanager
    def serve_units(self, starters):
        with self.installed(), super().serve_units(starters) as urls:
            yield urls


if WITH_SOUND:
    TestSound = type("TestSound", (Mutated,), {{}})

for _mutant in MUTANTS:
    if _mutant.name in NAMES:
        globals()["TestMutant_" + _mutant.name] = type("TestMutant_" + _mutant.name, (Mutated,), {{"mutant": _mutant}})
"""


def outcomes(junit: str) -> dict[str, dict[str, str]]:
    """class -> test -> "passed" | "failed" | "skipped"."""
    found: dict[str, dict[str, str]] = defaultdict(dict)
    for case in ET.parse(junit).getroot().iter("testcase"):
        outcome = "passed"
        if case.find("failure") is not None or case.find("error") is not None:
            outcome = "failed"
        elif case.find("skipped") is not None:
            outcome = "skipped"
        found[case.get("classname", "").rpartition(".")[2]][case.get("name", "")] = outcome
    return found


@pytest.mark.timeout(600)
def test_the_kit_fails_on_every_mutant_and_passes_the_sound_transport(pytester: pytest.Pytester) -> None:
    assert len(MUTANTS) >= 20 and len({m.name for m in MUTANTS}) == len(MUTANTS)
    pytester.makeconftest(IMPORTS.format(tests=str(Path(__file__).parents[1])) + CONFTEST)
    names = [m.name for m in MUTANTS]
    batches = [names[i::BATCHES] for i in range(BATCHES)]
    running = []
    for i, batch in enumerate(batches):
        kit = KIT.format(NAMES=repr(batch), WITH_SOUND=i == 0)  # the sound transport once, in the first batch
        pytester.makepyfile(**{f"test_batch{i}": textwrap.dedent(kit)})
        args = [sys.executable, "-m", "pytest", f"test_batch{i}.py", "-p", "no:randomly", "-p", "no:cacheprovider",
                "-q", f"--junitxml=batch{i}.xml", "-o", "timeout=120"]  # fmt: skip
        running.append(pytester.popen(args, stdin=subprocess.DEVNULL))
    logs = [process.communicate()[0] for process in running]
    found: dict[str, dict[str, str]] = {}
    for i in range(BATCHES):
        junit = pytester.path / f"batch{i}.xml"
        assert junit.exists(), logs[i]
        found.update(outcomes(str(junit)))
    sound = found.get(SOUND, {})
    assert sound and "failed" not in sound.values(), {k: v for k, v in sound.items() if v == "failed"}
    caught = {m.name: [t for t, o in found.get("TestMutant_" + m.name, {}).items() if o == "failed"] for m in MUTANTS}
    for name, tests in caught.items():
        print(f"{name}: caught by {', '.join(tests) or 'nothing'}")
    missed = [name for name, tests in caught.items() if not tests]
    assert not missed, f"the kit passed these broken transports: {missed}"
    rows = {m.row for m in MUTANTS}
    assert len(rows) >= 14, rows

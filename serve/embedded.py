"""A local mosquitto for trying ``serve --demo`` without a broker: a convenience, not a production broker.

Also the tests' broker. It listens on loopback only, on a free port, with a configuration of its own in a
temporary directory; ``extra`` adds configuration lines (TLS listener, password file).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from starterbus.core.errors import ConfigurationError, TransportError


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Mosquitto:
    port: int
    process: subprocess.Popen[bytes]
    directory: Path
    log: Path
    _tmp: tempfile.TemporaryDirectory[str] | None = field(default=None, repr=False)

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None


def mosquitto_binary() -> str | None:
    return shutil.which("mosquitto") or next(
        (p for p in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto") if Path(p).exists()), None
    )


def start_mosquitto(
    port: int | None = None, extra: str = "", *, listener: bool = True, wait: float = 10.0
) -> Mosquitto:
    """Start mosquitto on 127.0.0.1 and return once it accepts connections."""
    binary = mosquitto_binary()
    if binary is None:
        raise ConfigurationError("mosquitto is not installed (Debian/Ubuntu: apt-get install mosquitto)")
    port = port or free_port()
    tmp = tempfile.TemporaryDirectory(prefix="starterbus-mosquitto-")
    directory = Path(tmp.name)
    conf = directory / "mosquitto.conf"
    head = f"listener {port} 127.0.0.1\nallow_anonymous true\n" if listener else ""
    conf.write_text(f"per_listener_settings false\npersistence false\n{head}{extra}\n", encoding="utf-8")
    log = directory / "mosquitto.log"
    with log.open("wb") as out:
        process = subprocess.Popen([binary, "-c", str(conf), "-v"], stdout=out, stderr=subprocess.STDOUT)
    broker = Mosquitto(port, process, directory, log, tmp)
    deadline = time.monotonic() + wait
    while True:
        if process.poll() is not None:
            text = log.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-3:]
            broker.close()
            raise TransportError(f"mosquitto exited at start: {' | '.join(text)}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return broker
        except OSError:
            if time.monotonic() > deadline:
                broker.close()
                raise TransportError(f"mosquitto did not listen on 127.0.0.1:{port} within {wait:g} s") from None
            time.sleep(0.02)

"""The CLI's logging policy: the libraries under starterbus stay quiet unless asked (``starterbus -v ...``).

Without ``-v`` an error is the one typed line ``starterbus: error: ...``: pymodbus, asyncua, canopen, paho-mqtt,
python-can and python-can-remote log their own view of the same failure (pymodbus an ERROR for every refused
connection), which would only repeat it in other words, so their loggers are silenced. ``-v`` shows their
warnings and errors and starterbus's own INFO messages, each line prefixed with the logger's name; ``-vv``
shows everything at DEBUG. Plugins log under ``starterbus.plugins.NAME`` (or their package's name), add no
handler and never print (docs/plugins.md), so the same switch governs them.
"""

from __future__ import annotations

import logging
import sys

#: the loggers of the libraries starterbus drives
LIBRARY_LOGGERS = ("pymodbus", "asyncua", "canopen", "paho", "can", "can_remote")
#: above CRITICAL: nothing passes
SILENT = logging.CRITICAL + 10


def configure_logging(verbosity: int) -> None:
    """0: the libraries silent (starterbus's own warnings still reach stderr through Python's last resort);
    1: their warnings and starterbus's INFO on stderr; 2 or more: DEBUG."""
    if verbosity <= 0:
        for name in LIBRARY_LOGGERS:
            logging.getLogger(name).setLevel(SILENT)
        return
    level = logging.DEBUG if verbosity >= 2 else logging.INFO
    logging.basicConfig(level=level, format="%(name)s: %(levelname)s: %(message)s", stream=sys.stderr)
    for name in LIBRARY_LOGGERS:
        logging.getLogger(name).setLevel(logging.DEBUG if verbosity >= 2 else logging.WARNING)

"""CAN frames as the DeviceNet codec sees them: an 11-bit identifier and 0-8 data bytes, plus candump text.

:class:`CanFrame` (from ``core/canframe.py``, shared with every CAN protocol) is the codec's only frame type;
python-can's ``Message`` appears only in the drivers (scanner, simulator). Text form is candump's compact syntax
``ID#DATA`` (``41B#8000B2``), which the ``decode`` command and the transcript tests read and write.
"""

from __future__ import annotations

from starterbus.core import CanFrame
from starterbus.core import parse_candump as _parse_candump

__all__ = ["parse_candump"]


def parse_candump(text: str) -> CanFrame:
    """One frame in candump syntax: ``41B#8000B2``, ``41B#80.00.B2``, ``41B#80 00 B2``, ``41B#`` (no data), or a
    ``candump -L`` line (``(1.5) can0 41B#8000B2``). Extended (29-bit) identifiers, remote frames and CAN FD frames
    are not DeviceNet and are refused."""
    return _parse_candump(text, "the DeviceNet decoder")

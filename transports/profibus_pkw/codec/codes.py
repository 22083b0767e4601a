"""The codes of the vendor's Profibus DP telegrams: PPO types, directions, INDH task and response codes.

docs/manuals.md#3-profibus-dp-pkw-and-pzd-telegrams (tables 1.1 / 1.2 and 2.2 / 2.3). INDH values the manual
does not define decode to :class:`UnknownCode` (an ``int`` that says so), never an error. The telegrams built
from these are in ``telegram.py``.
"""

from __future__ import annotations

import enum

PROTOCOL = "profibus-pkw"


class Ppo(enum.IntEnum):
    """The two parameter-process-data object types the devices offer."""

    PPO1 = 1  # "type I": PKW (IND, PWE) + PZD (STW/ZSW, 0000/ACT)
    PPO3 = 3  # "type III": PZD only

    @property
    def words(self) -> int:
        return 4 if self is Ppo.PPO1 else 2

    @property
    def has_pkw(self) -> bool:
        return self is Ppo.PPO1


class Direction(str, enum.Enum):
    OUT = "out"  # master -> slave (the DP master's output area)
    IN = "in"  # slave -> master (the DP master's input area)


class Part(str, enum.Enum):
    """What a byte string holds: a whole telegram, or only the PKW or PZD half the manual prints."""

    ALL = "all"
    PKW = "pkw"
    PZD = "pzd"


class TaskCode(enum.IntEnum):
    """INDH master -> slave (table 1.1 / 2.2)."""

    NO_TASK = 0
    READ_PARAMETER = 1  # INDL = parameter address
    WRITE_PARAMETER = 2  # INDL = parameter address, PWE = value
    READ_MEASUREMENT = 3  # INDL = measurement ("status parameter") address


class ResponseCode(enum.IntEnum):
    """INDH slave -> master (table 1.2 / 2.3)."""

    NO_RESPONSE = 0
    VALUE = 1  # value in PWE
    NO_WRITE_PERMISSION = 2
    CANNOT_EXECUTE = 3  # error number in PWE (model's own table)


class UnknownCode(int):
    """An INDH value the manual does not define: kept as the raw number, flagged as unknown."""

    __slots__ = ()

    @property
    def name(self) -> str:
        return f"UNKNOWN_{int(self)}"

    @property
    def value(self) -> int:
        return int(self)

    def __repr__(self) -> str:
        return f"UnknownCode({int(self)})"

    def __str__(self) -> str:
        return f"unknown code {int(self)}"


#: INDH -> its task / response code (indexed directly where every call counts)
TASKS: tuple[TaskCode | UnknownCode, ...] = tuple(
    TaskCode(i) if i in TaskCode._value2member_map_ else UnknownCode(i) for i in range(256)
)
RESPONSES: tuple[ResponseCode | UnknownCode, ...] = tuple(
    ResponseCode(i) if i in ResponseCode._value2member_map_ else UnknownCode(i) for i in range(256)
)

TASK_TEXT = {
    TaskCode.NO_TASK: "no task",
    TaskCode.READ_PARAMETER: "read parameter",
    TaskCode.WRITE_PARAMETER: "write parameter",
    TaskCode.READ_MEASUREMENT: "read measurement",
}
RESPONSE_TEXT = {
    ResponseCode.NO_RESPONSE: "no response",
    ResponseCode.VALUE: "value in PWE",
    ResponseCode.NO_WRITE_PERMISSION: "no write permission",
    ResponseCode.CANNOT_EXECUTE: "task cannot be executed, error number in PWE",
}


def task_code(indh: int) -> TaskCode | UnknownCode:
    """INDH -> task code; values outside 0-3 give :class:`UnknownCode`."""
    return TASKS[indh & 0xFF]


def response_code(indh: int) -> ResponseCode | UnknownCode:
    """INDH -> response code; values outside 0-3 give :class:`UnknownCode`."""
    return RESPONSES[indh & 0xFF]

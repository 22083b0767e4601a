"""``starterbus decode profibus-pkw``: annotate PPO1/PPO3 telegrams (or the manual's PKW-only / PZD-only halves).

Each word is named and explained: task or response code, the INDL's parameter or measurement (with a model),
the PWE as an engineering value or as the model's error text, the control word bits, the status word bits and
the phase A current. A response does not say whether its INDL is a parameter or a measurement; without
``--kind`` both readings are shown.
"""

from __future__ import annotations

from collections.abc import Sequence

from starterbus.core import (
    Annotation,
    CodecError,
    DecodeError,
    FaultTable,
    Kind,
    PointDef,
    Profile,
    ValidationError,
    Value,
    decode_status_word,
    describe_control_word,
    parse_hex,
)
from starterbus.transports.profibus_pkw.codec.codes import (
    PROTOCOL,
    RESPONSE_TEXT,
    TASK_TEXT,
    Direction,
    Part,
    Ppo,
    ResponseCode,
    TaskCode,
)
from starterbus.transports.profibus_pkw.codec.telegram import (
    PkwRequest,
    PkwResponse,
    Ppo1In,
    Ppo1Out,
    PzdIn,
    PzdOut,
    decode_part,
    error_label,
    hex_text,
    telegram_type,
)
from starterbus.transports.profibus_pkw.settings import profibus_settings

ACT_SCALE = 0.1


def _w(word: int) -> str:
    return f"{word >> 8:02X} {word & 0xFF:02X}"


def _point_text(point: PointDef) -> str:
    return f"{point.address} {point.key} ({point.name_en})"


def _value_text(point: PointDef, raw: int) -> str:
    text = Value.from_raw(point, raw).text()
    try:
        point.check_raw(raw)
    except ValidationError:
        lo, hi = point.to_engineering(point.raw_min), point.to_engineering(point.raw_max)
        text += f" (outside {lo}..{hi} {point.unit})".replace(" )", ")")
    return text


def _candidates(profile: Profile | None, kinds: Sequence[Kind], index: int) -> list[tuple[Kind, PointDef | None]]:
    if profile is None:
        return [(k, None) for k in kinds]
    return [(k, profile.by_protocol_address(PROTOCOL, k, index)) for k in kinds]


def _indl_text(profile: Profile | None, kinds: Sequence[Kind], index: int) -> str:
    if not kinds:
        return "unused"
    parts = []
    for kind, point in _candidates(profile, kinds, index):
        if point is not None:
            parts.append(f"{kind.value} {_point_text(point)}")
        elif profile is not None:
            parts.append(f"no {kind.value} at INDL {index:#04x} in {profile.display_name}")
        else:
            parts.append(f"{kind.value} INDL {index:#04x} (give --model for its name)")
    return "; or ".join(parts)


def _pkw_out_fields(pkw: PkwRequest, profile: Profile | None) -> list[tuple[str, str, str]]:
    task = pkw.task
    index = pkw.indl
    if isinstance(task, TaskCode):
        task_text = f"task {int(task)}: {TASK_TEXT[task]}"
    else:
        task_text = f"unknown task code {int(task)} (the slave answers response 3)"
    kinds: list[Kind] = []
    if task in (TaskCode.READ_PARAMETER, TaskCode.WRITE_PARAMETER):
        kinds = [Kind.PARAMETER]
    elif task == TaskCode.READ_MEASUREMENT:
        kinds = [Kind.MEASUREMENT]
    indl_text = _indl_text(profile, kinds, index) if isinstance(task, TaskCode) else "address of an unknown task"
    if task == TaskCode.NO_TASK:
        indl_text = "unused" + (f" (nonzero: {index:#04x})" if index else "")
    fields = [("INDH", f"{pkw.ind >> 8:02X}", task_text), ("INDL", f"{index:02X}", indl_text)]
    if task == TaskCode.WRITE_PARAMETER:
        point = _candidates(profile, kinds, index)[0][1]
        meaning = f"value to write: {_value_text(point, pkw.pwe)}" if point else f"value to write: {pkw.pwe}"
    elif pkw.pwe:
        meaning = f"not used by this task (nonzero: {pkw.pwe})"
    else:
        meaning = "not used by this task"
    fields.append(("PWE", _w(pkw.pwe), meaning))
    return fields


def _pkw_in_fields(pkw: PkwResponse, profile: Profile | None, kind: Kind | None) -> list[tuple[str, str, str]]:
    response = pkw.response
    index = pkw.indl
    if isinstance(response, ResponseCode):
        response_text = f"response {int(response)}: {RESPONSE_TEXT[response]}"
    else:
        response_text = f"unknown response code {int(response)} (no value may be taken)"
    kinds: list[Kind] = []
    if response != ResponseCode.NO_RESPONSE:
        kinds = [kind] if kind is not None else [Kind.PARAMETER, Kind.MEASUREMENT]
    fields = [
        ("INDH", f"{pkw.ind >> 8:02X}", response_text),
        ("INDL", f"{index:02X}", _indl_text(profile, kinds, index)),
    ]
    if response == ResponseCode.VALUE:
        values = []
        for k, point in _candidates(profile, kinds, index):
            if point is not None:
                values.append(f"{k.value}: {_value_text(point, pkw.pwe)}")
        meaning = "; ".join(values) if values else f"value {pkw.pwe}"
    elif response == ResponseCode.CANNOT_EXECUTE:
        if profile is not None:
            label = error_label(profibus_settings(profile).errors, pkw.pwe)
            zh = f" / {label.zh}" if label.zh else ""
            meaning = f"error {pkw.pwe}: {label.en}{zh} ({profile.display_name} table)"
        else:
            meaning = f"error {pkw.pwe} (the tables differ per model: give --model)"
    else:
        meaning = "not used" + (f" (nonzero: {pkw.pwe})" if pkw.pwe else "")
    fields.append(("PWE", _w(pkw.pwe), meaning))
    return fields


def _pzd_out_fields(pzd: PzdOut) -> list[tuple[str, str, str]]:
    return [
        ("STW", _w(pzd.stw), "control word: " + ", ".join(describe_control_word(pzd.stw))),
        ("0000", _w(pzd.spare), "reserved" if pzd.spare == 0 else f"reserved word is not 0000 ({pzd.spare:#06x})"),
    ]


def _pzd_in_fields(pzd: PzdIn, profile: Profile | None) -> list[tuple[str, str, str]]:
    faults = profile.faults if profile is not None else FaultTable({})
    bit12 = profile.control.bit12_is_mains_voltage if profile is not None else False
    status = decode_status_word(pzd.zsw, faults, bit12_is_mains_voltage=bit12)
    bits: list[str] = [f"state {status.state.value}"]
    if status.fault:
        bits.append(f"fault {status.fault_code}: {status.fault_text}")
    for flag, name in (
        (status.starting, "soft starting"),
        (status.running, "running"),
        (status.stopping, "soft stopping"),
        (status.ready, "ready to start"),
        (status.bus_control, "commands from the bus"),
        (status.mains_voltage, "mains voltage present"),
    ):
        if flag:
            bits.append(name)
    if not status.fault and pzd.zsw & 0x3F:
        bits.append(f"fault code bits {pzd.zsw & 0x3F} without the fault bit")
    if status.unknown_bits:
        positions = [str(b) for b in range(16) if status.unknown_bits >> b & 1]
        bits.append(f"reserved bit{'s' if len(positions) > 1 else ''} {', '.join(positions)} set")
    act = pzd.act * ACT_SCALE
    return [
        ("ZSW", _w(pzd.zsw), "status word: " + "; ".join(dict.fromkeys(bits))),
        ("ACT", _w(pzd.act), f"phase A current {act:.1f} A"),
    ]


def annotate(
    data: bytes,
    ppo: Ppo,
    direction: Direction,
    part: Part = Part.ALL,
    profile: Profile | None = None,
    kind: Kind | None = None,
) -> Annotation:
    """One telegram (or half) -> an annotation; a bad one gives an annotation with ``error`` set."""
    arrow = "master -> slave" if direction is Direction.OUT else "slave -> master"
    what = "" if part is Part.ALL else f" {part.value.upper()} part"
    model = f" {profile.display_name}" if profile is not None else ""
    title = f"{ppo.name}{what} {arrow}{model}: {hex_text(data)}"
    try:
        telegram = decode_part(data, ppo, direction, part)
    except CodecError as exc:
        return Annotation(title, [], str(exc))
    fields: list[tuple[str, str, str]] = []
    if isinstance(telegram, Ppo1Out):
        fields = _pkw_out_fields(telegram.pkw, profile) + _pzd_out_fields(telegram.pzd)
    elif isinstance(telegram, Ppo1In):
        fields = _pkw_in_fields(telegram.pkw, profile, kind) + _pzd_in_fields(telegram.pzd, profile)
    elif isinstance(telegram, PkwRequest):
        fields = _pkw_out_fields(telegram, profile)
    elif isinstance(telegram, PkwResponse):
        fields = _pkw_in_fields(telegram, profile, kind)
    elif isinstance(telegram, PzdOut):
        fields = _pzd_out_fields(telegram)
    else:
        fields = _pzd_in_fields(telegram, profile)
    return Annotation(title, fields)


def annotate_hex(
    texts: Sequence[str],
    ppo: Ppo,
    direction: Direction,
    part: Part = Part.ALL,
    profile: Profile | None = None,
    kind: Kind | None = None,
) -> list[Annotation]:
    """Hex text (spaces allowed, the arguments joined) -> one annotation per telegram.

    Several telegrams back to back (a multiple of the telegram size) are annotated one by one.
    """
    joined = " ".join(texts)
    try:
        data = parse_hex(texts)
    except DecodeError as exc:
        return [Annotation(f"{PROTOCOL}: {joined!r}", [], str(exc))]
    try:
        size = 2 * len(telegram_type(ppo, direction, part)._fields)
    except CodecError as exc:
        return [Annotation(f"{PROTOCOL}: {joined}", [], str(exc))]
    if data and len(data) % size == 0 and len(data) > size:
        return [annotate(data[i : i + size], ppo, direction, part, profile, kind) for i in range(0, len(data), size)]
    return [annotate(data, ppo, direction, part, profile, kind)]

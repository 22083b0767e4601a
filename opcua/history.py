"""OPC UA HistoryRead over the recorder's SQLite history (``--record DB``): raw values and events, paged.

asyncua's history interface (:class:`asyncua.server.history.HistoryStorageInterface`) is implemented over the
same file the recorder writes (:class:`~starterbus.ops.history.HistoryStore`, its own read connection: SQLite's
WAL lets it read while the writer writes); nothing is stored twice and the server writes nothing. asyncua's
:class:`~asyncua.server.history.HistoryManager` is replaced by :class:`HistoryService` because its continuation
point is a timestamp (rows of one time would be lost or repeated), it ignores NumValuesPerNode's paging rules,
and it answers Good and empty for a node that keeps no history. Here (see :mod:`.history_query`):

- a variable the history can fill (:mod:`.history_values`) has ``Historizing`` true and the HistoryRead bit
  in AccessLevel and UserAccessLevel; a device object and the Server object have it in EventNotifier and
  return the history's events (:mod:`.history_events`): the device's, or every device's from the Server;
- any other node answers BadHistoryOperationUnsupported (an unknown one BadNodeIdUnknown), processed, at-time
  and modified reads BadHistoryOperationUnsupported, a domain without two of start, end and count
  BadInvalidTimestampArgument, a continuation point of another request BadContinuationPointInvalid,
  TimestampsToReturn Neither BadTimestampsToReturnInvalid and Server BadTimestampNotSupported (the history keeps
  the poll's time only: SourceTimestamp).
"""

from __future__ import annotations

import asyncio
import logging
import os
import sqlite3
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.common.events import Event
from asyncua.server.history import HistoryManager, HistoryStorageInterface
from asyncua.server.internal_server import InternalServer
from asyncua.server.monitored_item_service import WhereClauseEvaluator

from starterbus.core.errors import ConfigurationError
from starterbus.opcua.address_space import FleetNodes
from starterbus.opcua.alarms import SERVER, Alarms
from starterbus.opcua.history_events import HistoricalEvents
from starterbus.opcua.history_query import (
    Domain,
    InvalidContinuation,
    InvalidRange,
    Position,
    decode,
    domain,
    encode,
    last_sample_before,
    page,
    scope,
)
from starterbus.opcua.history_values import HistoricalVariable, historical_variables, row_time
from starterbus.ops.history import HistoryStore

log = logging.getLogger("starterbus.opcua")

#: values (or events) per HistoryRead response at most, whatever NumValuesPerNode asks
PAGE_MAX = 1000


class SqliteHistory(HistoryStorageInterface):
    """Reads the history file at ``path`` (opened when it exists, reopened when the writer replaced it)."""

    def __init__(self, path: Path, variables: Mapping[ua.NodeId, HistoricalVariable], events: HistoricalEvents,
                 notifiers: Mapping[ua.NodeId, str | None], page_max: int = PAGE_MAX) -> None:  # fmt: skip
        super().__init__(page_max)
        self.path = path
        self.variables = variables
        self.events = events
        self.notifiers = notifiers  # event notifier -> its device (None: every device)
        self.page_max = page_max
        self._store: HistoryStore | None = None
        self._identity: tuple[int, int] | None = None

    def store(self) -> HistoryStore | None:
        """The read connection, or None while the file does not exist yet (nothing recorded: empty pages)."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return None
        identity = (st.st_dev, st.st_ino)
        if self._store is not None and identity != self._identity:  # moved aside (corrupted): the new file
            self._store.close()
            self._store = None
        if self._store is None:
            self._store = HistoryStore(self.path)  # the schema too: the writer may not have written it yet
            self._identity = identity
        return self._store

    # -- reads (in a worker thread: SQLite blocks) --------------------------------------------------------------

    def values(
        self, node: ua.NodeId, span: Domain, after: Position | None
    ) -> tuple[list[ua.DataValue], Position | None]:
        variable = self.variables[node]
        store = self.store()
        if store is None:
            return [], None
        rows, more = page(store, "samples", variable.device, span, after)
        return [variable.extract(row, row_time(row)) for row in rows], more

    def event_page(
        self, node: ua.NodeId, span: Domain, after: Position | None, where: WhereClauseEvaluator
    ) -> tuple[list[Event], Position | None]:
        store = self.store()
        if store is None:
            return [], None
        built: dict[int, Event] = {}

        def before(device: str, moment: float) -> Mapping[str, Any] | None:
            return last_sample_before(store, device, moment)

        def accept(row: dict[str, Any]) -> bool:
            event = built[row["id"]] = self.events.event(row, before)
            return bool(where.eval(event))

        rows, more = page(store, "events", self.notifiers[node], span, after, accept)
        return [built[row["id"]] for row in rows], more

    # -- asyncua's interface ------------------------------------------------------------------------------------

    async def init(self) -> None:
        await asyncio.to_thread(self.store)  # refuses, one line, a file that is not a history

    async def new_historized_node(self, node_id: ua.NodeId, period: Any, count: int = 0) -> None:
        raise ua.UaError("the history is written by the recorder (--record), not through the OPC UA server")

    async def save_node_value(self, node_id: ua.NodeId, datavalue: ua.DataValue) -> None:
        raise ua.UaError("the history is written by the recorder (--record), not through the OPC UA server")

    async def new_historized_event(self, source_id: ua.NodeId, evtypes: Any, period: Any, count: int = 0) -> None:
        raise ua.UaError("the history is written by the recorder (--record), not through the OPC UA server")

    async def save_event(self, event: Any) -> None:
        raise ua.UaError("the history is written by the recorder (--record), not through the OPC UA server")

    async def read_node_history(
        self, node_id: ua.NodeId, start: datetime | None, end: datetime | None, nb_values: int
    ) -> tuple[list[ua.DataValue], datetime | None]:
        """The interface's form: the first page and the time it ended at (:class:`HistoryService` pages exactly)."""
        values, more = await asyncio.to_thread(self.values, node_id, domain(start, end, nb_values, self.page_max), None)
        return values, _moment(more)

    async def read_event_history(
        self, source_id: ua.NodeId, start: datetime | None, end: datetime | None, nb_values: int, evfilter: Any
    ) -> tuple[list[Event], datetime | None]:
        where = WhereClauseEvaluator(log, None, evfilter.WhereClause)
        span = domain(start, end, nb_values, self.page_max)
        events, more = await asyncio.to_thread(self.event_page, source_id, span, None, where)
        return events, _moment(more)

    async def stop(self) -> None:
        if self._store is not None:
            self._store.close()
            self._store = None


def _moment(position: Position | None) -> datetime | None:
    return datetime.fromtimestamp(position.time, timezone.utc) if position is not None else None


def _result(code: int) -> ua.HistoryReadResult:
    return ua.HistoryReadResult(StatusCode=ua.StatusCode(code))


class HistoryService(HistoryManager):
    """HistoryRead as the module says; ``storage`` None (no ``--record``): no node has history."""

    def __init__(self, iserver: InternalServer, storage: SqliteHistory | None = None) -> None:
        super().__init__(iserver)
        self.history = storage
        if storage is not None:
            self.set_storage(storage)

    async def init(self) -> None:
        if self.history is not None:
            await self.history.init()

    async def stop(self) -> None:
        if self.history is not None:
            await self.history.stop()

    async def read_history(self, params: ua.HistoryReadParameters) -> list[ua.HistoryReadResult]:
        if params.ReleaseContinuationPoints:  # they hold no state here: nothing to release
            return [ua.HistoryReadResult() for _ in params.NodesToRead]
        stamps = params.TimestampsToReturn
        if stamps not in (ua.TimestampsToReturn.Source, ua.TimestampsToReturn.Both):
            code = ua.StatusCodes.BadTimestampNotSupported
            if stamps != ua.TimestampsToReturn.Server:
                code = ua.StatusCodes.BadTimestampsToReturnInvalid
            return [_result(code) for _ in params.NodesToRead]
        return [await self._read_one(params.HistoryReadDetails, item) for item in params.NodesToRead]

    async def _read_one(self, details: Any, item: ua.HistoryReadValueId) -> ua.HistoryReadResult:
        node = item.NodeId
        if node not in self.iserver.aspace:
            return _result(ua.StatusCodes.BadNodeIdUnknown)
        history = self.history
        unsupported = _result(ua.StatusCodes.BadHistoryOperationUnsupported)
        if isinstance(details, ua.ReadRawModifiedDetails):
            if details.IsReadModified or history is None or node not in history.variables:
                return unsupported  # modified values: the history is never modified
            kind = "values"
        elif isinstance(details, ua.ReadEventDetails):
            if history is None or node not in history.notifiers:
                return unsupported
            kind = "events"
        else:  # processed (aggregates), at time, annotations
            return unsupported
        checksum = scope(kind, node.to_string(), details.StartTime, details.EndTime, details.NumValuesPerNode)
        try:
            span = domain(details.StartTime, details.EndTime, details.NumValuesPerNode, history.page_max)
            after = decode(item.ContinuationPoint, checksum) if item.ContinuationPoint else None
        except InvalidRange:
            return _result(ua.StatusCodes.BadInvalidTimestampArgument)
        except InvalidContinuation:
            return _result(ua.StatusCodes.BadContinuationPointInvalid)
        result = ua.HistoryReadResult()
        try:
            if kind == "values":
                values, more = await asyncio.to_thread(history.values, node, span, after)
                result.HistoryData = ua.HistoryData(DataValues=[_source_only(dv) for dv in values])
            else:
                where = WhereClauseEvaluator(log, self.iserver.aspace, details.Filter.WhereClause)
                events, more = await asyncio.to_thread(history.event_page, node, span, after, where)
                fields = [ua.HistoryEventFieldList(EventFields=e.to_event_fields(details.Filter.SelectClauses))
                          for e in events]  # fmt: skip
                result.HistoryData = ua.HistoryEvent(Events=fields)
        except (ConfigurationError, sqlite3.Error) as exc:  # the file became something that is not a history
            log.error("HistoryRead %s: %s: %s", node.to_string(), history.path, exc)
            return _result(ua.StatusCodes.BadInternalError)
        result.ContinuationPoint = encode(more, checksum) if more is not None else None
        return result


def _source_only(dv: ua.DataValue) -> ua.DataValue:
    return ua.DataValue(dv.Value, StatusCode=dv.StatusCode, SourceTimestamp=dv.SourceTimestamp)


def install(server: Server, storage: SqliteHistory | None) -> HistoryService:
    """Replace asyncua's history manager (after ``server.init()``, before ``start()``)."""
    service = HistoryService(server.iserver, storage)
    server.iserver.history_manager = service
    return service


async def enable(server: Server, nodes: FleetNodes, alarms: Alarms, path: Path | str, locale: str) -> SqliteHistory:
    """Mark what the history at ``path`` can serve (Historizing, AccessLevel and EventNotifier bits, the
    server's HistoryServerCapabilities) and build its storage. After the alarms are built (they reset the
    Server object's EventNotifier)."""
    events = HistoricalEvents(server, nodes.namespace_index, nodes.devices, locale)
    await events.build(alarms.fault_type)
    variables: dict[ua.NodeId, HistoricalVariable] = {}
    notifiers: dict[ua.NodeId, str | None] = {SERVER: None}
    for name, device in nodes.devices.items():
        variables.update(historical_variables(device, locale))
        notifiers[device.node] = name
    aspace = server.iserver.aspace
    for node in variables:
        await server.write_attribute_value(node, ua.DataValue(ua.Variant(True)), ua.AttributeIds.Historizing)
        for attribute in (ua.AttributeIds.AccessLevel, ua.AttributeIds.UserAccessLevel):
            level = aspace.read_attribute_value(node, attribute).Value.Value or 0
            value = ua.Variant(level | ua.AccessLevel.HistoryRead.mask, ua.VariantType.Byte)
            await server.write_attribute_value(node, ua.DataValue(value), attribute)
    for node in notifiers:
        notifier = aspace.read_attribute_value(node, ua.AttributeIds.EventNotifier).Value.Value or 0
        value = ua.Variant(notifier | ua.EventNotifier.HistoryRead.mask, ua.VariantType.Byte)
        await server.write_attribute_value(node, ua.DataValue(value), ua.AttributeIds.EventNotifier)
    for capability, variant in (
        (ua.ObjectIds.HistoryServerCapabilities_AccessHistoryDataCapability, ua.Variant(True)),
        (ua.ObjectIds.HistoryServerCapabilities_AccessHistoryEventsCapability, ua.Variant(True)),
        (ua.ObjectIds.HistoryServerCapabilities_MaxReturnDataValues, ua.Variant(PAGE_MAX, ua.VariantType.UInt32)),
        (ua.ObjectIds.HistoryServerCapabilities_MaxReturnEventValues, ua.Variant(PAGE_MAX, ua.VariantType.UInt32)),
    ):
        await server.write_attribute_value(ua.NodeId(capability), ua.DataValue(variant))
    return SqliteHistory(Path(path), variables, events, notifiers)

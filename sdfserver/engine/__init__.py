"""The engine: the one owner of the device (see ``core.py`` for the step)."""

from sdfserver.engine.commands import EngineLimits, ReadResult, StepReport
from sdfserver.engine.core import Engine, new_world_id, world_config_dict
from sdfserver.engine.journal import Journal
from sdfserver.engine.mailbox import Mailbox, Subscription, Update
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.publish import check_subscription_region
from sdfserver.engine.query import QueryResult

__all__ = [
    "Engine", "EngineLimits", "EngineMetrics", "Journal", "Mailbox", "QueryResult", "ReadResult",
    "StepReport", "Subscription", "Update", "check_subscription_region", "new_world_id",
    "world_config_dict",
]

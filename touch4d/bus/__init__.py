"""The topic bus: broker, node runtime, launcher and introspection (see docs/contracts.md)."""
from touch4d.bus.broker import Broker
from touch4d.bus.config import BusConfig, CurveKeys, load_bus_config, resolve_bus_config
from touch4d.bus.executor import Executor, Timer
from touch4d.bus.node import Node, Publisher, RawPublisher, Subscription
from touch4d.bus.params import Param
from touch4d.bus.process import run_node

__all__ = [
    "Broker", "BusConfig", "CurveKeys", "Executor", "Node", "Param", "Publisher", "RawPublisher", "Subscription", "Timer",
    "load_bus_config", "resolve_bus_config", "run_node",
]

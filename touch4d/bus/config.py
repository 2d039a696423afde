"""Bus endpoints and CurveZMQ keys, read from a bus config file (default `config/bus.yaml`).

The broker binds two ports: publishers connect to its XSUB port (`pub_port`), subscribers to its
XPUB port (`sub_port`). Binding is loopback-only unless the file names another address; then a
`curve` section is required, so that every peer is authenticated by its key.
"""
from __future__ import annotations

import ipaddress
import json
import os
from dataclasses import asdict, dataclass, field, replace

import zmq
import zmq.auth

from touch4d.configfile import COMMAND_LINE, PathNotFound, read_yaml, resolve_path
from touch4d.errors import ConfigError, Touch4dError

# The launcher hands its node processes the bus (endpoints, client keys) as JSON in ENV_VAR; a user
# names a bus config file in USER_ENV_VAR. Two variables, so neither is mistaken for the other.
ENV_VAR = "TOUCH4D_LAUNCH_BUS"
USER_ENV_VAR = "TOUCH4D_BUS"
DEFAULT_NAME = "config/bus.yaml"


class BusUnreachable(Touch4dError):
    """No broker answered at the configured endpoints."""


@dataclass(frozen=True)
class CurveKeys:
    """Z85-encoded CurveZMQ keys. The broker needs the server secret and the allow-list; a client
    needs the server public key and its own key pair."""

    server_public: str
    server_secret: str | None = None
    client_public: str | None = None
    client_secret: str | None = None
    authorized: tuple[str, ...] = ()


@dataclass(frozen=True)
class BusConfig:
    """Where the broker binds and where nodes find it. Port 0 means "any free port" (broker side)."""

    bind_host: str = "127.0.0.1"
    connect_host: str = "127.0.0.1"
    pub_port: int = 7710
    sub_port: int = 7711
    hwm: int = 10000
    curve: CurveKeys | None = None
    source: str = field(default="<defaults>", compare=False)

    @property
    def pub_endpoint(self) -> str:
        """Where publishers connect (the broker's XSUB)."""
        return f"tcp://{_host(self.connect_host)}:{self.pub_port}"

    @property
    def sub_endpoint(self) -> str:
        """Where subscribers connect (the broker's XPUB)."""
        return f"tcp://{_host(self.connect_host)}:{self.sub_port}"

    def bind_endpoint(self, port: int) -> str:
        return f"tcp://{_host(self.bind_host)}:{port if port else '*'}"

    def with_ports(self, pub_port: int, sub_port: int) -> "BusConfig":
        return replace(self, pub_port=pub_port, sub_port=sub_port)

    def for_clients(self) -> "BusConfig":
        """This config without the broker's secrets, to hand to node processes."""
        if self.curve is None:
            return self
        return replace(self, curve=replace(self.curve, server_secret=None, authorized=()))

    def to_json(self) -> str:
        data = asdict(self)
        return json.dumps(data)

    @classmethod
    def from_json(cls, text: str) -> "BusConfig":
        data = json.loads(text)
        curve = data.pop("curve", None)
        if curve is not None:
            curve = CurveKeys(**{**curve, "authorized": tuple(curve.get("authorized", ()))})
        return cls(**data, curve=curve)


def _host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


_TOP_KEYS = {"broker", "connect", "hwm", "curve"}
_BROKER_KEYS = {"bind", "pub_port", "sub_port"}
_CURVE_KEYS = {"server_public", "server_secret", "client_secret", "authorized"}


def load_bus_config(path: str | os.PathLike | None = None, named_in=COMMAND_LINE, key: str = "--bus") -> BusConfig:
    """Read a bus config file, found by `resolve_path` (`named_in` and `key` say where it was named);
    without one, config/bus.yaml (yours, else the packaged one), else the loopback defaults."""
    if path is None:
        try:
            path = resolve_path(DEFAULT_NAME, what="bus config file")
        except PathNotFound:
            return BusConfig()
    else:
        path = resolve_path(path, named_in, key=key, what="bus config file")
    return parse_bus_config(read_yaml(path, "bus config file") or {}, path)


def parse_bus_config(data, path) -> BusConfig:
    """Check and convert the mapping of a bus config file; its key files are found by `resolve_path`
    (the current directory first, then the folder of `path`)."""
    _mapping(data, path, "(top level)", _TOP_KEYS)
    broker = data.get("broker") or {}
    _mapping(broker, path, "broker", _BROKER_KEYS)
    bind = _typed(broker.get("bind", "127.0.0.1"), str, path, "broker.bind", "a host address")
    connect = _typed(data.get("connect", "127.0.0.1"), str, path, "connect", "the broker's host address")
    pub_port = _port(broker.get("pub_port", 7710), path, "broker.pub_port")
    sub_port = _port(broker.get("sub_port", 7711), path, "broker.sub_port")
    hwm = _typed(data.get("hwm", 10000), int, path, "hwm", "a positive int (messages queued per peer)")
    if hwm <= 0:
        raise ConfigError(path, "hwm", "a positive int", got=hwm)
    curve = None
    if data.get("curve") is not None:
        curve = _curve(data["curve"], path)
    elif not is_loopback(bind):
        raise ConfigError(path, "curve", f"CurveZMQ keys, because broker.bind {bind!r} is not loopback")
    elif not is_loopback(connect):
        raise ConfigError(path, "curve", f"CurveZMQ keys, because the broker at {connect!r} is on another machine")
    return BusConfig(bind, connect, pub_port, sub_port, hwm, curve, source=str(path))


def _curve(data, path) -> CurveKeys:
    _mapping(data, path, "curve", _CURVE_KEYS)
    if not zmq.has("curve"):
        raise ConfigError(path, "curve", "a libzmq built with CURVE support")
    if "server_public" not in data:
        raise ConfigError(path, "curve.server_public", "the broker's public key file")
    server_public, _ = _read_cert(data["server_public"], path, "curve.server_public", secret=False)
    server_secret = client_public = client_secret = None
    if data.get("server_secret") is not None:
        _, server_secret = _read_cert(data["server_secret"], path, "curve.server_secret", secret=True)
    if data.get("client_secret") is not None:
        client_public, client_secret = _read_cert(data["client_secret"], path, "curve.client_secret", secret=True)
    authorized: list[str] = []
    entries = data.get("authorized") or []
    if isinstance(entries, str):
        entries = [entries]
    if not isinstance(entries, list):
        raise ConfigError(path, "curve.authorized", "a list of public key files or folders", got=entries)
    for i, entry in enumerate(entries):
        key = f"curve.authorized[{i}]"
        target = resolve_path(_typed(entry, str, path, key, "a key file or folder"), path, key=key,
                              what="public key file or folder")
        files = sorted(target.glob("*.key")) if target.is_dir() else [target]
        for file in files:
            authorized.append(_read_cert(str(file), path, key, secret=False)[0])
    if server_secret is not None and not authorized:
        raise ConfigError(path, "curve.authorized", "at least one client public key allowed to connect")
    return CurveKeys(server_public, server_secret, client_public, client_secret, tuple(authorized))


def _read_cert(name, path, key: str, secret: bool) -> tuple[str, str | None]:
    file = resolve_path(_typed(name, str, path, key, "a key file path"), path, key=key, what="key file")
    try:
        public, private = zmq.auth.load_certificate(file)
    except (OSError, ValueError) as exc:
        raise ConfigError(path, key, "a CurveZMQ certificate file (touch4d bus keygen)", got=str(exc)) from None
    if secret and private is None:
        raise ConfigError(path, key, "a secret key file (*.key_secret)", got=str(file))
    return public.decode(), private.decode() if private else None


def _mapping(value, path, key: str, allowed: set[str]) -> None:
    if not isinstance(value, dict):
        raise ConfigError(path, key, "a mapping", got=value)
    for name in value:
        if name not in allowed:
            where = name if key == "(top level)" else f"{key}.{name}"
            raise ConfigError(path, where, f"one of {sorted(allowed)}", got=name)


def _typed(value, kind, path, key: str, expected: str):
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ConfigError(path, key, expected, got=value)
    return value


def _port(value, path, key: str) -> int:
    value = _typed(value, int, path, key, "a TCP port (0..65535; 0 = any free port)")
    if not 0 <= value <= 65535:
        raise ConfigError(path, key, "a TCP port (0..65535)", got=value)
    return value


def user_bus_config(path: str | os.PathLike | None = None) -> BusConfig:
    """The bus a user means: an explicit file (`--bus`), else the file named by $TOUCH4D_BUS, else
    config/bus.yaml, else the loopback defaults. What the launcher and a lone broker bind."""
    if path is not None:
        return load_bus_config(path)
    user = os.environ.get(USER_ENV_VAR)
    if user:
        return load_bus_config(user, f"${USER_ENV_VAR}", "(value)")
    return load_bus_config(None)


def resolve_bus_config(path: str | os.PathLike | None = None) -> BusConfig:
    """The bus a process should use: an explicit file, else the launcher's handover (in a node it
    started), else `user_bus_config`."""
    text = os.environ.get(ENV_VAR) if path is None else None
    if text:
        try:
            return BusConfig.from_json(text)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"${ENV_VAR}", "(value)", "a bus config as JSON (set by touch4d launch)",
                              got=str(exc)) from None
    return user_bus_config(path)

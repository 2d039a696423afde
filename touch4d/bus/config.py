"""Bus endpoints and CurveZMQ keys, read from a bus config file (default `config/bus.yaml`).

The broker binds two ports: publishers connect to its XSUB port (`pub_port`), subscribers to its
XPUB port (`sub_port`). Binding is loopback-only unless the file names another address; then a
`curve` section is required, so that every peer is authenticated by its key.
"""
from __future__ import annotations

import ipaddress
import os
from dataclasses import dataclass, field, replace
from typing import Annotated

import msgspec
import zmq
import zmq.auth

from touch4d import schema
from touch4d.configfile import COMMAND_LINE, PathNotFound, resolve_path
from touch4d.errors import ConfigError, Touch4dError

# The launcher hands its node processes the bus (endpoints, client keys) as JSON in ENV_VAR; a user
# names a bus config file in USER_ENV_VAR. Two variables, so neither is mistaken for the other.
ENV_VAR = "TOUCH4D_LAUNCH_BUS"
USER_ENV_VAR = "TOUCH4D_BUS"
DEFAULT_NAME = "config/bus.yaml"


class BusUnreachable(Touch4dError):
    """No broker answered at the configured endpoints."""


Port = Annotated[int, msgspec.Meta(ge=0, le=65535, description="a TCP port (0..65535; 0 = any free port)")]


class BrokerSection(msgspec.Struct, forbid_unknown_fields=True):
    bind: str = "127.0.0.1"        # address the broker binds (loopback only unless `curve` is given)
    pub_port: Port = 7710          # publishers connect here (the broker's XSUB)
    sub_port: Port = 7711          # subscribers connect here (the broker's XPUB)


class CurveSection(msgspec.Struct, forbid_unknown_fields=True):
    """Key files (made by `touch4d bus keygen`), found relative to the bus config file."""

    server_public: str | None = None       # every machine
    server_secret: str | None = None       # the broker's machine only
    client_secret: str | None = None       # this machine's own key pair
    authorized: str | list[str] = []       # the broker's machine: public key files or folders allowed to connect


class BusFile(msgspec.Struct, forbid_unknown_fields=True):
    """A bus config file (config/bus.yaml); every default of the bus is here."""

    broker: BrokerSection = msgspec.field(default_factory=BrokerSection)
    connect: str = "127.0.0.1"     # the broker's address as seen from this machine
    hwm: Annotated[int, msgspec.Meta(gt=0, description="a positive integer (messages queued per peer)")] = 10000
    curve: CurveSection | None = None


_DEFAULT = BusFile()


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

    bind_host: str = _DEFAULT.broker.bind
    connect_host: str = _DEFAULT.connect
    pub_port: int = _DEFAULT.broker.pub_port
    sub_port: int = _DEFAULT.broker.sub_port
    hwm: int = _DEFAULT.hwm
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
        """This config as the JSON the launcher hands its nodes (`from_json` reads it back)."""
        return msgspec.json.encode(self).decode()

    @classmethod
    def from_json(cls, text: str) -> "BusConfig":
        """A config from `to_json`'s text; a ConfigError naming $TOUCH4D_LAUNCH_BUS if it is not one."""
        try:
            return msgspec.json.decode(text, type=cls)
        except msgspec.DecodeError as exc:   # a ValidationError too
            raise ConfigError(f"${ENV_VAR}", "(value)", "a bus config as JSON (set by touch4d launch)",
                              got=str(exc)) from None


def _host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


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
    return parse_bus_config(schema.read_yaml(path, "bus config file"), path)


def parse_bus_config(data, path) -> BusConfig:
    """Check and convert the mapping of a bus config file; its key files are found by `resolve_path`
    (the current directory first, then the folder of `path`)."""
    spec = schema.convert({} if data is None else data, BusFile, path)
    bind, connect = spec.broker.bind, spec.connect
    curve = None
    if spec.curve is not None:
        curve = _curve(spec.curve, path)
    elif not is_loopback(bind):
        schema.fail(path, "curve", f"CurveZMQ keys, because broker.bind {bind!r} is not loopback")
    elif not is_loopback(connect):
        schema.fail(path, "curve", f"CurveZMQ keys, because the broker at {connect!r} is on another machine")
    return BusConfig(bind, connect, spec.broker.pub_port, spec.broker.sub_port, spec.hwm, curve, source=str(path))


def _curve(spec: CurveSection, path) -> CurveKeys:
    if not zmq.has("curve"):
        schema.fail(path, "curve", "a libzmq built with CURVE support")
    if spec.server_public is None:
        schema.fail(path, "curve.server_public", "the broker's public key file")
    server_public, _ = _read_cert(spec.server_public, path, "curve.server_public", secret=False)
    server_secret = client_public = client_secret = None
    if spec.server_secret is not None:
        _, server_secret = _read_cert(spec.server_secret, path, "curve.server_secret", secret=True)
    if spec.client_secret is not None:
        client_public, client_secret = _read_cert(spec.client_secret, path, "curve.client_secret", secret=True)
    authorized: list[str] = []
    entries = [spec.authorized] if isinstance(spec.authorized, str) else spec.authorized
    for i, entry in enumerate(entries):
        key = f"curve.authorized[{i}]"
        target = resolve_path(entry, path, key=key, what="public key file or folder")
        files = sorted(target.glob("*.key")) if target.is_dir() else [target]
        for file in files:
            authorized.append(_read_cert(str(file), path, key, secret=False)[0])
    if server_secret is not None and not authorized:
        schema.fail(path, "curve.authorized", "at least one client public key allowed to connect")
    return CurveKeys(server_public, server_secret, client_public, client_secret, tuple(authorized))


def _read_cert(name: str, path, key: str, secret: bool) -> tuple[str, str | None]:
    file = resolve_path(name, path, key=key, what="key file")
    try:
        public, private = zmq.auth.load_certificate(file)
    except (OSError, ValueError) as exc:
        raise ConfigError(path, key, "a CurveZMQ certificate file (touch4d bus keygen)", got=str(exc)) from None
    if secret and private is None:
        raise ConfigError(path, key, "a secret key file (*.key_secret)", got=str(file))
    return public.decode(), private.decode() if private else None


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
        return BusConfig.from_json(text)
    return user_bus_config(path)

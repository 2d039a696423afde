"""Bus config: endpoints, the loopback-only default, CURVE keys from files, clear errors."""
import pytest

from touch4d.bus.config import BusConfig, load_bus_config, parse_bus_config, resolve_bus_config
from touch4d.bus.keys import keygen
from touch4d.errors import ConfigError


def test_project_config_binds_loopback_without_keys():
    cfg = load_bus_config()
    assert cfg.bind_host == "127.0.0.1" and cfg.curve is None
    assert cfg.pub_endpoint == "tcp://127.0.0.1:7710" and cfg.sub_endpoint == "tcp://127.0.0.1:7711"


def test_non_loopback_bind_requires_curve(tmp_path):
    path = tmp_path / "bus.yaml"
    path.write_text("broker: {bind: 0.0.0.0}\n")
    with pytest.raises(ConfigError) as err:
        load_bus_config(path)
    assert str(path) in str(err.value) and "'curve'" in str(err.value) and "0.0.0.0" in str(err.value)


@pytest.mark.parametrize("text, key", [
    ("broker: {bnd: 127.0.0.1}", "broker.bnd"),
    ("broker: {pub_port: 70000}", "broker.pub_port"),
    ("broker: {sub_port: '7711'}", "broker.sub_port"),
    ("hwm: 0", "hwm"),
    ("conect: 127.0.0.1", "conect"),
    ("broker: [1, 2]", "broker"),
])
def test_bad_keys_and_values_are_named(tmp_path, text, key):
    path = tmp_path / "bus.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError) as err:
        load_bus_config(path)
    assert err.value.key == key and err.value.file == str(path)


def test_curve_keys_load_from_files_relative_to_the_config(tmp_path):
    keys = tmp_path / "keys"
    server_pub, server_sec = keygen(keys, "broker")
    pc_pub, pc_sec = keygen(keys / "clients", "pc")
    pi_pub, _ = keygen(keys / "clients", "pi")
    assert (server_sec.stat().st_mode & 0o077) == 0
    path = tmp_path / "bus.yaml"
    path.write_text(
        "broker: {bind: 0.0.0.0, pub_port: 7000, sub_port: 7001}\nconnect: 192.0.2.10\n"
        "curve:\n  server_public: keys/broker.key\n  server_secret: keys/broker.key_secret\n"
        "  client_secret: keys/clients/pc.key_secret\n  authorized: [keys/clients]\n"
    )
    cfg = load_bus_config(path)
    public = lambda p: p.read_text().split('public-key = "')[1].split('"')[0]  # noqa: E731
    assert cfg.curve.server_public == public(server_pub)
    assert cfg.curve.client_public == public(pc_pub)
    assert sorted(cfg.curve.authorized) == sorted([public(pc_pub), public(pi_pub)])
    assert cfg.pub_endpoint == "tcp://192.0.2.10:7000"
    assert BusConfig.from_json(cfg.to_json()) == cfg


def test_curve_errors_name_the_key(tmp_path):
    keygen(tmp_path, "broker")
    with pytest.raises(ConfigError) as err:
        parse_bus_config({"curve": {"server_public": "broker.key", "server_secret": "broker.key_secret"}}, tmp_path / "b.yaml")
    assert err.value.key == "curve.authorized"
    with pytest.raises(ConfigError) as err:
        parse_bus_config({"curve": {"server_public": "nope.key"}}, tmp_path / "b.yaml")
    assert err.value.key == "curve.server_public"
    with pytest.raises(ConfigError) as err:
        parse_bus_config({"curve": {"server_public": "broker.key", "client_secret": "broker.key"}}, tmp_path / "b.yaml")
    assert err.value.key == "curve.client_secret" and "secret" in str(err.value)


def test_the_launchers_handover_wins_over_the_users_file(monkeypatch, tmp_path):
    from touch4d.bus.config import ENV_VAR

    assert ENV_VAR != "TOUCH4D_BUS"     # the launcher's JSON never shares the user's variable
    user = tmp_path / "bus.yaml"
    user.write_text("broker: {pub_port: 7000, sub_port: 7001}\n")
    monkeypatch.setenv("TOUCH4D_BUS", str(user))
    cfg = BusConfig(pub_port=1234, sub_port=1235)
    monkeypatch.setenv(ENV_VAR, cfg.to_json())
    assert resolve_bus_config() == cfg
    monkeypatch.setenv(ENV_VAR, "{not json")
    with pytest.raises(ConfigError, match=ENV_VAR):
        resolve_bus_config()


def test_touch4d_bus_names_a_bus_config_file(monkeypatch, tmp_path):
    from touch4d.bus.config import ENV_VAR

    monkeypatch.delenv(ENV_VAR, raising=False)
    (tmp_path / "lab").mkdir()
    path = tmp_path / "lab" / "bus.yaml"
    path.write_text("broker: {pub_port: 7100, sub_port: 7101}\n")
    monkeypatch.setenv("TOUCH4D_BUS", str(path))
    assert (resolve_bus_config().pub_port, resolve_bus_config().sub_port) == (7100, 7101)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TOUCH4D_BUS", "lab/bus.yaml")                 # relative: from the current directory
    assert resolve_bus_config().source == str(path)
    monkeypatch.setenv("TOUCH4D_BUS", "lab/nope.yaml")
    with pytest.raises(ConfigError) as err:
        resolve_bus_config()
    assert err.value.file == "$TOUCH4D_BUS" and str(tmp_path / "lab" / "nope.yaml") in str(err.value)


def test_a_relative_bus_path_finds_the_keys_of_an_authorized_folder(monkeypatch, tmp_path):
    # The PC of the README's two-machine set-up, run from the folder that holds config/.
    keys = tmp_path / "config" / "keys"
    for name in ("broker", "pc", "pi"):
        keygen(keys, name)
    (keys / "clients").mkdir()
    for name in ("pc", "pi"):
        (keys / "clients" / f"{name}.key").write_bytes((keys / f"{name}.key").read_bytes())
    (tmp_path / "config" / "bus-pc.yaml").write_text(
        "broker: {bind: 127.0.0.1}\n"
        "curve: {server_public: keys/broker.key, server_secret: keys/broker.key_secret,\n"
        "        client_secret: keys/pc.key_secret, authorized: [keys/clients]}\n")
    monkeypatch.chdir(tmp_path)
    relative = load_bus_config("config/bus-pc.yaml")
    absolute = load_bus_config(tmp_path / "config" / "bus-pc.yaml")
    assert len(relative.curve.authorized) == 2 and relative.curve == absolute.curve


def test_a_remote_broker_requires_curve(tmp_path):
    path = tmp_path / "pi.yaml"
    path.write_text("connect: 192.0.2.10\n")
    with pytest.raises(ConfigError, match="another machine") as err:
        load_bus_config(path)
    assert err.value.key == "curve"


def test_node_processes_get_no_broker_secrets():
    from touch4d.bus.config import CurveKeys

    cfg = BusConfig(curve=CurveKeys("S" * 40, "s" * 40, "C" * 40, "c" * 40, ("C" * 40,)))
    client = cfg.for_clients()
    assert client.curve.server_secret is None and client.curve.authorized == ()
    assert (client.curve.server_public, client.curve.client_secret) == ("S" * 40, "c" * 40)

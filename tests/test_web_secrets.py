"""The page's secrets: the TLS key written so that nobody else can read it and no planted symlink
can redirect it, a key left readable by others never reused; the node's token from a file or the
environment (128 bits at least, never a parameter's value on the command line), and plain http
refused beyond loopback."""
import os
import time
import stat

import pytest

from touch4d.bus.testing import free_port, node_process, running_broker
from touch4d.web.tls import ensure_certificate

pytestmark = pytest.mark.timeout(90)


def mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def test_the_key_is_private_from_its_first_byte_in_a_private_directory(tmp_path):
    directory = tmp_path / "tls"
    cert, key, _ = ensure_certificate(directory, ["127.0.0.1"])
    assert mode(directory) == 0o700 and mode(key) == 0o600 and mode(cert) == 0o644
    assert sorted(p.name for p in directory.iterdir()) == ["cert.pem", "key.pem"]     # no temporary left


def test_a_symlinked_key_never_writes_the_file_it_points_to(tmp_path):
    directory = tmp_path / "tls"
    directory.mkdir(mode=0o700)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    os.symlink(victim, directory / "key.pem")
    cert, key, _ = ensure_certificate(directory, ["127.0.0.1"])
    assert victim.read_text() == "precious\n"                       # untouched
    assert not os.path.islink(key) and mode(key) == 0o600 and b"PRIVATE KEY" in key.read_bytes()


def test_a_key_readable_by_others_is_not_reused_and_a_wide_directory_is_narrowed(tmp_path):
    directory = tmp_path / "tls"
    cert, key, fingerprint = ensure_certificate(directory, ["127.0.0.1"])
    assert ensure_certificate(directory, ["127.0.0.1"])[2] == fingerprint   # reused while private
    os.chmod(directory, 0o755)
    os.chmod(key, 0o644)                                                     # someone may have read it
    _, key, renewed = ensure_certificate(directory, ["127.0.0.1"])
    assert renewed != fingerprint and mode(key) == 0o600 and mode(directory) == 0o700


def start_error(params: dict, env: dict | None = None) -> str:
    """The output of a webxr node that must refuse to start with `params`."""
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    try:
        with running_broker() as bus, node_process("webxr", bus, params={"port": free_port(), **params},
                                                   start_timeout=60) as proc:
            assert not proc.started
            proc.join(10)
            return proc.text
    finally:
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)


def test_a_token_is_never_a_parameter_value_and_carries_128_bits(tmp_path):
    out = start_error({"token": "s3cret-on-the-command-line"})
    assert "token" in out and "auto" in out and "env" in out and "file" in out
    short = tmp_path / "token"
    short.write_text("s3cret\n")
    out = start_error({"token": "file", "token_file": str(short)})
    assert str(short) in out and "128 bits" in out
    out = start_error({"token": "env"}, env={"TOUCH4D_WEBXR_TOKEN": "abc"})
    assert "TOUCH4D_WEBXR_TOKEN" in out and "128 bits" in out


def test_plain_http_is_refused_beyond_loopback(tmp_path):
    out = start_error({"host": "0.0.0.0", "tls": "off", "cert_dir": str(tmp_path)})
    assert "tls" in out and "in clear" in out


def test_a_token_from_a_file_opens_the_page(tmp_path):
    import asyncio

    import aiohttp

    token = "Q" * 11 + "x_-" + "7" * 8
    path = tmp_path / "token"
    path.write_text(token + "\n")
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "port": port, "token": "file", "token_file": str(path), "save_calibration": False}) as proc:
        line = proc.wait_for_line("WebXR page", timeout=30)
        assert token in line

        async def go():
            async with aiohttp.ClientSession() as session:
                async with session.get(f"http://127.0.0.1:{port}/") as r:
                    refused = r.status
                async with session.get(f"http://127.0.0.1:{port}/?token={token}") as r:
                    return refused, r.status
        assert asyncio.run(go()) == (403, 200)
        assert token not in " ".join(open(f"/proc/{proc.proc.pid}/cmdline").read().split("\0"))


def test_a_page_node_behind_a_proxy_advertises_no_address_of_its_own(tmp_path):
    """With the proxy's secret (a study server's participant), its log names no link and no `adb
    reverse` to its loopback port: participants come through the proxy's links only."""
    secret = tmp_path / "secret"
    secret.write_text("S" * 22 + "\n")
    with running_broker() as bus:
        with node_process("webxr", bus, params={"port": free_port(), "save_calibration": False,
                                                "secret_file": str(secret)}) as proc:
            line = proc.wait_for_line("WebXR page", timeout=30)
            time.sleep(0.5)
            said = proc.text
        assert "proxy" in line and "http://" not in said and "adb reverse" not in said
        with node_process("webxr", bus, params={"port": free_port(), "save_calibration": False}) as proc:
            proc.wait_for_line("adb reverse", timeout=30)    # on its own, on loopback: the USB way in

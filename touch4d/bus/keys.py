"""CurveZMQ key pairs for a bus spanning two machines (`touch4d bus keygen`)."""
from __future__ import annotations

from pathlib import Path

import zmq
import zmq.auth


def keygen(folder: str | Path, name: str) -> tuple[Path, Path]:
    """Write `name.key` (public, to share) and `name.key_secret` (keep on its machine) in `folder`."""
    if not zmq.has("curve"):
        raise RuntimeError("this libzmq has no CURVE support")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    public, secret = zmq.auth.create_certificates(folder, name)
    Path(secret).chmod(0o600)
    return Path(public), Path(secret)


HOWTO = """\
Wrote {public} (public: copy it where peers need it) and {secret} (secret: keep it on this machine,
never commit it). Key paths in a bus file are found beside it (after the current directory), e.g.
in config/bus.yaml on the broker machine:
  curve: {{server_public: keys/broker.key, server_secret: keys/broker.key_secret,
          client_secret: keys/pc.key_secret, authorized: [keys/clients]}}
and on another machine:
  curve: {{server_public: keys/broker.key, client_secret: keys/pi.key_secret}}
See docs/bus.md, "Two machines".
"""

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
Wrote {public} (public: copy it where peers need it) and {secret} (secret: keep it on this machine).
In config/bus.yaml:
  broker machine:  curve: {{server_public: broker.key, server_secret: broker.key_secret,
                           client_secret: <this machine>.key_secret, authorized: [<folder of client .key files>]}}
  other machines:  curve: {{server_public: broker.key, client_secret: <this machine>.key_secret}}
"""

"""Writes all_types.mcap from all_types.py: each message made and published as a node does.

    .venv/bin/python tests/data/logs/make_all_types.py tests/data/logs/all_types.mcap

The committed log was made by the message code of its day; it is not remade by the tests.
"""
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).parent))
from all_types import MESSAGES, value  # noqa: E402

from touch4d.log.writer import LogWriter  # noqa: E402
from touch4d.messages import TYPES  # noqa: E402




with LogWriter(sys.argv[1]) as log:
    for topic, log_time, type_name, fields in MESSAGES:
        fields = {k: value(v) for k, v in fields.items()}
        seq = fields.pop("seq")
        msg = TYPES[type_name](**fields)
        log.write(topic, msg.publish_payload(seq), log_time)

"""A log recorded by an earlier version of the message code still reads, and replays, as it was made:
every message type, decoded by today's code, against its values written out by hand."""
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from touch4d.log.reader import LogReader
from touch4d.log.replay import Plan, Replayer, ReplayOptions
from touch4d.messages import TOPIC_TYPES, TYPES, decode, decoder

DATA = Path(__file__).parent / "data" / "logs"
sys.path.insert(0, str(DATA))
from all_types import MESSAGES, value  # noqa: E402

LOG = DATA / "all_types.mcap"


def assert_same(got, want, where: str) -> None:
    """`got` (a decoded value) equals `want` (all_types.py's literal form), type for type."""
    if isinstance(want, tuple):   # an array: (dtype, shape, values)
        dtype, shape, values = want
        assert isinstance(got, np.ndarray), where
        assert got.dtype == np.dtype(dtype) and got.shape == shape, (where, got.dtype, got.shape)
        assert not got.flags.writeable, where
        flat_got, flat_want = got.ravel().tolist(), np.ravel(values).tolist()
        assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(flat_got, flat_want, strict=True)), where
    elif isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), (where, got.keys(), want.keys())
        for key in want:
            assert_same(got[key], want[key], f"{where}.{key}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (a, b) in enumerate(zip(got, want)):
            assert_same(a, b, f"{where}[{i}]")
    else:
        assert type(got) is type(want) and got == want, (where, got, want)


def test_the_log_holds_every_topic_type_of_its_time():
    """The log was recorded before the study, physics, other-hand and served-page topics existed; it holds
    every other one."""
    later = {"study/trial", "study/response", "study/command", "physics/contacts", "physics/journal",
             "hand/joints/other", "hand/poses", "tactile/played"}
    assert {topic for topic, *_ in MESSAGES} == set(TOPIC_TYPES) - later


def test_every_message_of_the_old_log_decodes_to_its_values():
    recorded = list(LogReader(LOG).messages())
    assert len(recorded) == len(MESSAGES)
    for rec, (topic, log_time, type_name, fields) in zip(recorded, MESSAGES, strict=True):
        assert (rec.topic, rec.log_time, rec.type) == (topic, log_time, type_name)
        cls = TYPES[type_name]
        for msg in (decode(rec.data), decode(rec.data, cls), decoder(cls)(rec.data)):
            assert type(msg) is cls and TOPIC_TYPES[topic] is cls
            assert set(cls.field_docs()) == set(fields)
            for name, want in fields.items():
                assert_same(getattr(msg, name), want, f"{topic}.{name}")


def test_the_old_log_replays_with_its_values_and_new_stamps():
    opts = ReplayOptions(realtime=False)
    reader = LogReader(LOG)
    sent = []
    before = time.time()
    Replayer(reader, Plan(reader, opts), opts, lambda topic, data: sent.append((topic, data)),
             clock=time.perf_counter, sleep=time.sleep).run()
    assert [topic for topic, _ in sent] == [m[0] for m in MESSAGES]
    seqs: dict[str, int] = {}
    for (topic, data), (_, _, type_name, fields) in zip(sent, MESSAGES, strict=True):
        msg = decode(data, TYPES[type_name])
        assert before <= msg.stamp <= time.time()
        # re-stamped now, the source moved with it; the first recording's stamp kept
        assert msg.source_stamp == pytest.approx(msg.stamp - (fields["stamp"] - fields["source_stamp"]), abs=1e-6)
        assert msg.recorded_stamp == (fields["recorded_stamp"] or fields["stamp"])
        assert msg.seq == seqs.setdefault(topic, 0)
        seqs[topic] += 1
        for name, want in fields.items():
            if name not in ("stamp", "seq", "source_stamp", "recorded_stamp"):
                assert_same(getattr(msg, name), want, f"{topic}.{name}")




def test_the_same_messages_published_today_are_the_same_bytes():
    recorded = list(LogReader(LOG).messages())
    for rec, (topic, _, type_name, fields) in zip(recorded, MESSAGES, strict=True):
        fields = {k: value(v) for k, v in fields.items()}
        seq = fields.pop("seq")
        assert TYPES[type_name](**fields).publish_payload(seq) == rec.data, topic

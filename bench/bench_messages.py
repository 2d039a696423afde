"""Message codec benchmark: the cost of one message's construction, `publish_payload(seq)` (check,
stamp, encode) and decoding by a subscription's `decoder(type)`, in microseconds, beside plain
msgpack of the same fields (arrays as raw bytes: no checks, no dtype or shape), measured in the
same run. Messages: a HandPose (the 1 kHz stream), a HandJoints of WebXR's 25 joints (25 unit
quaternions checked), a 30-motor MotorCommand and a 256-sample TactileField. Each figure is CPU time (process_time: what the machine's other load takes from the
run is not counted), the best of a few repeats.

    .venv/bin/python bench/bench_messages.py [--number 20000] [--repeat 5]
"""
from __future__ import annotations

import argparse
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import msgpack
import numpy as np


def best(fn, number: int, repeat: int) -> float:
    """Least mean CPU time of `fn()` over `repeat` runs of `number` calls, microseconds."""
    out = []
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(number):
            fn()
        out.append((time.process_time() - t0) / number * 1e6)
    return min(out)


def cases(messages):
    """(name, make() -> message, the same fields as plain data) for the messages benchmarked."""
    rng = np.random.default_rng(1)
    pos, quat = np.array([0.1, -0.2, 0.3]), np.array([0.0, 0.0, 0.6, 0.8])
    names, intensity = [f"m{i}" for i in range(30)], rng.random(30)
    n = 256
    samples, l, s, h = rng.random((n, 3)), rng.random(n), rng.random(n), rng.random(n)
    joint_names = [f"joint-{i}" for i in range(25)]
    joint_q = np.tile(quat, (25, 1))
    joints = {"handedness": "left", "names": joint_names, "positions": rng.random((25, 3)), "orientations": joint_q,
              "radii": np.full(25, 0.01), "valid": True}
    return [
        ("HandPose", lambda: messages.HandPose(position=pos, orientation=quat, valid=True),
         {"position": pos, "orientation": quat, "valid": True}),
        ("HandJoints x25", lambda: messages.HandJoints(**joints), joints),
        ("MotorCommand x30", lambda: messages.MotorCommand(names=names, intensity=intensity),
         {"names": names, "intensity": intensity}),
        ("TactileField x256", lambda: messages.TactileField(positions=samples, l=l, s=s, h=h, alpha=1.0, beta=0.5,
                                                            gamma=1.0),
         {"positions": samples, "l": l, "s": s, "h": h, "alpha": 1.0, "beta": 0.5, "gamma": 1.0}),
    ]


def raw_pack(type_name: str, fields: dict, seq: int) -> bytes:
    now = time.time()
    return msgpack.packb({"type": type_name, "stamp": now, "seq": seq, "source_stamp": now,
                          **{k: v.tobytes() if isinstance(v, np.ndarray) else v for k, v in fields.items()}})


def raw_unpack(payload: bytes, arrays: list[str]) -> dict:
    d = msgpack.unpackb(payload)
    for k in arrays:
        d[k] = np.frombuffer(d[k], dtype=np.float64)
    return d


def measure(messages, number: int, repeat: int) -> dict[str, dict[str, float]]:
    """{message: {construct, publish, decode, raw_pack, raw_unpack}} in microseconds."""
    out = {}
    for name, make, fields in cases(messages):
        msg = make()
        type_name = type(msg).TYPE
        payload = msg.publish_payload(0)
        decode = messages.decoder(type(msg))
        arrays = [k for k, v in fields.items() if isinstance(v, np.ndarray)]
        raw = raw_pack(type_name, fields, 0)
        out[name] = {
            "construct": best(make, number, repeat),
            "publish": best(lambda: msg.publish_payload(7), number, repeat),
            "decode": best(lambda: decode(payload), number, repeat),
            "raw_pack": best(lambda: raw_pack(type_name, fields, 7), number, repeat),
            "raw_unpack": best(lambda: raw_unpack(raw, arrays), number, repeat),
        }
    return out


def report(results: dict[str, dict[str, float]], label: str = "") -> None:
    for name, r in results.items():
        print(f"{label}{name:>18}: construct {r['construct']:5.2f} us  publish_payload {r['publish']:5.2f} us "
              f"({r['publish'] / r['raw_pack']:.2f}x raw pack {r['raw_pack']:.2f} us)  "
              f"decode {r['decode']:5.2f} us ({r['decode'] / r['raw_unpack']:.2f}x raw unpack "
              f"{r['raw_unpack']:.2f} us)", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--number", type=int, default=20000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    from touch4d import messages

    report(measure(messages, args.number, args.repeat))


if __name__ == "__main__":
    main()

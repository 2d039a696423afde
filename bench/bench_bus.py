"""Bus benchmark: HandPose one-way latency (p50, p99) and throughput through the touch4d broker,
beside raw pyzmq + msgpack PUB/SUB through one zmq.proxy hop, measured in the same run.

A middle row runs the touch4d broker and Node runtime with the baseline's own payloads, to
separate the runtime's cost from the message codec's. Each setup runs the publisher, the proxy/broker and the subscriber as three processes on loopback.
Latency: 1 kHz for a few seconds, receive time minus the publisher's `time.time()` stamp.
Throughput: the publisher sends as fast as it can; rate = messages handled by the subscriber per
second of receiving. Targets: latency within 1.5x of raw, throughput >= 50k messages/s.

    .venv/bin/python bench/bench_bus.py [--latency-count 3000] [--throughput-count 100000]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import time

import touch4d  # noqa: F401  first: it caps BLAS thread pools before numpy loads
import numpy as np

TOPIC = b"hand/pose"


# ---- raw baseline: PUB -> zmq.proxy (XSUB/XPUB) -> SUB, msgpack of the same fields ----------------


def raw_latency(payload: bytes) -> float:
    """Decode a raw baseline pose (plain msgpack, arrays as bytes) and return its one-way latency, s."""
    import msgpack

    now = time.time()
    d = msgpack.unpackb(payload)
    np.frombuffer(d["position"], dtype=np.float64)
    np.frombuffer(d["orientation"], dtype=np.float64)
    return now - d["stamp"]



def spin_until_end(node, done: list, lat: list, times: list, results) -> None:
    """Spin a subscriber node until the publisher's end marker (or 120 s), then report and close."""
    deadline = time.monotonic() + 120
    while not done and time.monotonic() < deadline:
        node.spin_once(0.1)
    results.put((lat, times[0] if times else None, times[-1] if times else None))
    node.shutdown()

def raw_proxy(ports, ready, stop):
    import threading

    import zmq

    ctx = zmq.Context()
    xsub, xpub = ctx.socket(zmq.XSUB), ctx.socket(zmq.XPUB)
    for s in (xsub, xpub):
        s.sndhwm = s.rcvhwm = 10000
    ports.append(xsub.bind_to_random_port("tcp://127.0.0.1"))
    ports.append(xpub.bind_to_random_port("tcp://127.0.0.1"))
    threading.Thread(target=lambda: _proxy(zmq, xsub, xpub), daemon=True).start()
    ready.set()
    stop.wait()


def _proxy(zmq, xsub, xpub):
    try:
        zmq.proxy(xsub, xpub)
    except zmq.ZMQError:
        pass


def raw_pack(msgpack, seq, pos, quat):
    now = time.time()
    return msgpack.packb({"type": "HandPose", "stamp": now, "seq": seq, "source_stamp": now,
                          "position": pos.tobytes(), "orientation": quat.tobytes(), "valid": True})


def raw_publisher(ports, sub_ready, count, rate):
    import msgpack
    import zmq

    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.sndhwm = 10000
    pub.connect(f"tcp://127.0.0.1:{ports[0]}")
    sub_ready.wait()
    time.sleep(0.5)  # raw PUB has no way to know the proxy's subscription has arrived
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    _paced(lambda i: pub.send_multipart((TOPIC, raw_pack(msgpack, i, pos, quat))), count, rate)
    pub.send_multipart((b"end", b""))
    time.sleep(0.5)
    pub.close(linger=1000)
    ctx.term()


def raw_subscriber(ports, sub_ready, results, count):
    import msgpack
    import zmq

    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.rcvhwm = 10000
    sub.connect(f"tcp://127.0.0.1:{ports[1]}")
    sub.subscribe(TOPIC)
    sub.subscribe(b"end")
    time.sleep(0.3)
    sub_ready.set()
    lat, first, last = [], None, None
    while sub.poll(10000):
        topic, payload = sub.recv_multipart()
        if topic == b"end":
            break
        lat.append(raw_latency(payload))
        first = first or time.perf_counter()
        last = time.perf_counter()
    results.put((lat, first, last))
    ctx.destroy(linger=0)


# ---- touch4d: publisher Node -> Broker -> subscriber Node -------------------------------------------

def bus_broker(ports, ready, stop):
    from touch4d.bus import Broker, BusConfig

    broker = Broker(BusConfig(pub_port=0, sub_port=0))
    endpoints = broker.start()
    ports.extend([endpoints.pub_port, endpoints.sub_port])
    ready.set()
    stop.wait()
    broker.stop()


def bus_publisher(ports, sub_ready, count, rate):
    from touch4d.bus import BusConfig, Node
    from touch4d.messages import HandPose

    node = Node("bench_pub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    pub = node.create_publisher("hand/pose", HandPose)
    end = node.create_publisher("end", HandPose)
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    sub_ready.wait()
    _paced(lambda i: pub.publish(HandPose(position=pos, orientation=quat, valid=True)), count, rate)
    end.publish(HandPose(position=pos, orientation=quat, valid=True))
    time.sleep(0.5)
    node.shutdown()


def bus_subscriber(ports, sub_ready, results, count):
    from touch4d.bus import BusConfig, Node
    from touch4d.messages import HandPose

    node = Node("bench_sub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    lat, times = [], []
    done = []

    def on_pose(msg):
        now = time.time()
        lat.append(now - msg.stamp)
        times.append(time.perf_counter())

    node.create_subscription("hand/pose", HandPose, on_pose)
    node.create_subscription("end", HandPose, lambda m: done.append(1))
    sub_ready.set()
    spin_until_end(node, done, lat, times, results)


# ---- touch4d runtime with the raw baseline's payloads: the bus without the message codec ---------

def runtime_publisher(ports, sub_ready, count, rate):
    import msgpack

    from touch4d.bus import BusConfig, Node

    node = Node("bench_pub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    pub, end = node.create_raw_publisher("hand/pose"), node.create_raw_publisher("end")
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    sub_ready.wait()
    _paced(lambda i: pub.publish(raw_pack(msgpack, i, pos, quat)), count, rate)
    end.publish(b"")
    time.sleep(0.5)
    node.shutdown()


def runtime_subscriber(ports, sub_ready, results, count):
    import msgpack

    from touch4d.bus import BusConfig, Node

    node = Node("bench_sub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    lat, times, done = [], [], []

    def on_any(topic, payload):
        if topic == "end":
            done.append(1)
            return
        lat.append(raw_latency(payload))
        times.append(time.perf_counter())

    node.create_raw_subscription("hand/pose", on_any)
    node.create_raw_subscription("end", on_any)
    sub_ready.set()
    spin_until_end(node, done, lat, times, results)


# ---- harness --------------------------------------------------------------------------------------

def _paced(send, count, rate):
    if rate is None:
        for i in range(count):
            send(i)
        return
    start = time.perf_counter()
    for i in range(count):
        wait = start + i / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        send(i)


def run(kind, count, rate):
    ctx = mp.get_context("spawn")
    manager = ctx.Manager()
    ports = manager.list()
    ready, stop, sub_ready = ctx.Event(), ctx.Event(), ctx.Event()
    results = ctx.Queue()
    proxy_fn, pub_fn, sub_fn = {
        "raw": (raw_proxy, raw_publisher, raw_subscriber),
        "runtime": (bus_broker, runtime_publisher, runtime_subscriber),
        "touch4d": (bus_broker, bus_publisher, bus_subscriber),
    }[kind]
    proxy = ctx.Process(target=proxy_fn, args=(ports, ready, stop))
    proxy.start()
    ready.wait(30)
    ports = list(ports)
    sub = ctx.Process(target=sub_fn, args=(ports, sub_ready, results, count))
    pub = ctx.Process(target=pub_fn, args=(ports, sub_ready, count, rate))
    sub.start()
    pub.start()
    lat, first, last = results.get(timeout=180)
    for p in (pub, sub):
        p.join(30)
    stop.set()
    proxy.join(10)
    for p in (pub, sub, proxy):
        if p.is_alive():
            p.kill()
    manager.shutdown()
    lat = np.array(lat) * 1e6
    received = len(lat)
    rate_out = (received - 1) / (last - first) if received > 1 and last > first else float("nan")
    return {"received": received, "p50": float(np.percentile(lat, 50)) if received else float("nan"),
            "p99": float(np.percentile(lat, 99)) if received else float("nan"), "rate": rate_out}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency-count", type=int, default=2000)
    parser.add_argument("--latency-rate", type=float, default=1000.0)
    parser.add_argument("--throughput-count", type=int, default=60000)
    parser.add_argument("--rounds", type=int, default=3, help="runs of each setup, interleaved; medians reported")
    args = parser.parse_args()

    kinds = ("raw", "runtime", "touch4d")
    print(f"HandPose through one proxy hop, 3 processes on loopback; latency at {args.latency_rate:g} Hz x "
          f"{args.latency_count}, throughput {args.throughput_count} as fast as possible; "
          f"median of {args.rounds} interleaved rounds")
    print("raw: PUB/SUB + zmq.proxy + msgpack; runtime: touch4d broker and Node with the raw payloads "
          "(no message codec); touch4d: HandPose published and decoded by the Node API")
    rounds = {k: [] for k in kinds}
    for _ in range(args.rounds):  # interleaved, so a burst of load on the machine hits every setup alike
        for k in kinds:
            lat = run(k, args.latency_count, args.latency_rate)
            thr = run(k, args.throughput_count, None)
            rounds[k].append({"p50": lat["p50"], "p99": lat["p99"], "rate": thr["rate"],
                              "lost": args.latency_count - lat["received"]})
    res = {k: {m: float(np.median([r[m] for r in rounds[k]])) for m in ("p50", "p99", "rate", "lost")} for k in kinds}
    for k in kinds:
        r = res[k]
        print(f"{k:>8}: latency p50 {r['p50']:7.1f} us  p99 {r['p99']:8.1f} us  throughput {r['rate']:8.0f} msg/s"
              f"   (p50 per round: {', '.join(str(round(x['p50'])) for x in rounds[k])} us)")
    for k in ("runtime", "touch4d"):
        print(f"   ratio {k}/raw: latency p50 {res[k]['p50'] / res['raw']['p50']:.2f}x  "
              f"p99 {res[k]['p99'] / res['raw']['p99']:.2f}x (target <= 1.5x)   "
              f"throughput {res[k]['rate'] / res['raw']['rate']:.2f}x ({res[k]['rate']:.0f} msg/s, target >= 50000)")


if __name__ == "__main__":
    main()

"""Bus benchmark: HandPose one-way latency (p50, p99) and throughput through the touch4d broker,
beside raw pyzmq + msgpack PUB/SUB through one zmq.proxy hop, measured in the same run.

A middle row runs the touch4d broker and Node runtime with the baseline's own payloads, to
separate the runtime's cost from the message codec's. Each setup runs the publisher, the
proxy/broker and the subscriber as three processes on loopback, started with `spawn` and driven
through pipes only (no multiprocessing locks, so no resource tracker and nothing left behind).
Latency: 1 kHz for a few seconds, receive time minus the publisher's `time.time()` stamp; these
runs use SCHED_FIFO when permitted (`--no-realtime`: not), so the other load of a shared machine
does not decide the percentiles (the throughput runs, which keep both cores busy, never do).
Throughput: the publisher sends as fast as it can; rate = messages handled by the subscriber per
second of receiving. On a shared machine that rate follows the other load, so each setup also gets
a CPU rate: messages handled per CPU second of its busiest process (publisher: those it sent;
subscriber: those it received), the rate it sustains with a core per process; the CPU per message of publisher and subscriber (their
ZeroMQ I/O threads included) shows where it goes. Targets: latency within 1.5x of raw, throughput
>= 0.8x raw.

    .venv/bin/python bench/bench_bus.py [--latency-count 2000] [--throughput-count 60000] [--rounds 5]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
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


def raw_proxy(conn, realtime):
    import threading

    import zmq

    _priority(realtime)
    ctx = zmq.Context()
    xsub, xpub = ctx.socket(zmq.XSUB), ctx.socket(zmq.XPUB)
    for s in (xsub, xpub):
        s.sndhwm = s.rcvhwm = 10000
        s.linger = 0
    ports = (xsub.bind_to_random_port("tcp://127.0.0.1"), xpub.bind_to_random_port("tcp://127.0.0.1"))
    threading.Thread(target=_proxy, args=(zmq, xsub, xpub), daemon=True).start()
    conn.send(ports)
    conn.recv()   # stop
    os._exit(0)   # the proxy thread holds the sockets: leave without waiting for it


def _proxy(zmq, xsub, xpub):
    try:
        zmq.proxy(xsub, xpub)
    except zmq.ZMQError:
        pass


def raw_pack(msgpack, seq, pos, quat):
    now = time.time()
    return msgpack.packb({"type": "HandPose", "stamp": now, "seq": seq, "source_stamp": now,
                          "position": pos.tobytes(), "orientation": quat.tobytes(), "valid": True})


def raw_publisher(ports, conn, count, rate, realtime):
    import msgpack
    import zmq

    _priority(realtime)
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.sndhwm = 10000
    pub.connect(f"tcp://127.0.0.1:{ports[0]}")
    conn.recv()   # the subscriber is ready
    time.sleep(0.5)  # raw PUB has no way to know the proxy's subscription has arrived
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    cpu = _paced(lambda i: pub.send_multipart((TOPIC, raw_pack(msgpack, i, pos, quat))), count, rate)
    pub.send_multipart((b"end", b""))
    conn.send(cpu)
    time.sleep(0.5)
    pub.close(linger=1000)
    ctx.term()


def raw_subscriber(ports, conn, count, realtime):
    import msgpack  # noqa: F401  imported before timing starts
    import zmq

    _priority(realtime)
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.rcvhwm = 10000
    sub.connect(f"tcp://127.0.0.1:{ports[1]}")
    sub.subscribe(TOPIC)
    sub.subscribe(b"end")
    time.sleep(0.3)
    conn.send("ready")
    lat, first, last, cpu0 = [], None, None, None
    while sub.poll(10000):
        topic, payload = sub.recv_multipart()
        if topic == b"end":
            break
        lat.append(raw_latency(payload))
        if first is None:
            first, cpu0 = time.perf_counter(), time.process_time()
        last = time.perf_counter()
    conn.send((lat, first, last, time.process_time() - cpu0 if cpu0 is not None else float("nan")))
    ctx.destroy(linger=0)


# ---- touch4d: publisher Node -> Broker -> subscriber Node -------------------------------------------

def bus_broker(conn, realtime):
    from touch4d.bus import Broker, BusConfig

    broker = Broker(BusConfig(pub_port=0, sub_port=0), realtime=realtime)
    endpoints = broker.start()
    conn.send((endpoints.pub_port, endpoints.sub_port))
    conn.recv()   # stop
    broker.stop()


def bus_publisher(ports, conn, count, rate, realtime):
    from touch4d.bus import BusConfig, Node
    from touch4d.messages import HandPose

    _priority(realtime)
    node = Node("bench_pub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    pub = node.create_publisher("hand/pose", HandPose)
    end = node.create_publisher("end", HandPose)
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    conn.recv()
    cpu = _paced(lambda i: pub.publish(HandPose(position=pos, orientation=quat, valid=True)), count, rate)
    end.publish(HandPose(position=pos, orientation=quat, valid=True))
    conn.send(cpu)
    time.sleep(0.5)
    node.shutdown()


def bus_subscriber(ports, conn, count, realtime):
    from touch4d.bus import BusConfig, Node
    from touch4d.messages import HandPose

    _priority(realtime)
    node = Node("bench_sub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    lat, times, cpu = [], [], []
    done = []

    def on_pose(msg):
        now = time.time()
        lat.append(now - msg.stamp)
        if not times:
            cpu.append(time.process_time())
        times.append(time.perf_counter())

    node.create_subscription("hand/pose", HandPose, on_pose)
    node.create_subscription("end", HandPose, lambda m: done.append(1))
    conn.send("ready")
    spin_until_end(node, done, lat, times, cpu, conn)


def spin_until_end(node, done: list, lat: list, times: list, cpu: list, conn) -> None:
    """Spin a subscriber node until the publisher's end marker (or 120 s), then report and close."""
    deadline = time.monotonic() + 120
    while not done and time.monotonic() < deadline:
        node.spin_once(0.1)
    conn.send((lat, times[0] if times else None, times[-1] if times else None,
               time.process_time() - cpu[0] if cpu else float("nan")))
    node.shutdown()


# ---- touch4d runtime with the raw baseline's payloads: the bus without the message codec ---------

def runtime_publisher(ports, conn, count, rate, realtime):
    import msgpack

    from touch4d.bus import BusConfig, Node

    _priority(realtime)
    node = Node("bench_pub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    pub, end = node.create_raw_publisher("hand/pose"), node.create_raw_publisher("end")
    pos, quat = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0])
    conn.recv()
    cpu = _paced(lambda i: pub.publish(raw_pack(msgpack, i, pos, quat)), count, rate)
    end.publish(b"")
    conn.send(cpu)
    time.sleep(0.5)
    node.shutdown()


def runtime_subscriber(ports, conn, count, realtime):
    import msgpack  # noqa: F401  imported before timing starts

    from touch4d.bus import BusConfig, Node

    _priority(realtime)
    node = Node("bench_sub", bus=BusConfig(pub_port=ports[0], sub_port=ports[1]), heartbeat=False)
    lat, times, done, cpu = [], [], [], []

    def on_any(topic, payload):
        if topic == "end":
            done.append(1)
            return
        lat.append(raw_latency(payload))
        if not times:
            cpu.append(time.process_time())
        times.append(time.perf_counter())

    node.create_raw_subscription("hand/pose", on_any)
    node.create_raw_subscription("end", on_any)
    conn.send("ready")
    spin_until_end(node, done, lat, times, cpu, conn)


# ---- harness --------------------------------------------------------------------------------------

def _priority(realtime: bool) -> None:
    """SCHED_FIFO for this process's threads (and the ZeroMQ threads it starts next), if asked."""
    if realtime:
        from touch4d.bus.realtime import raise_thread_priority

        raise_thread_priority()


def _paced(send, count, rate) -> float:
    """Call send(i) for i < count, at `rate` per second (None: as fast as possible); CPU seconds used."""
    cpu = time.process_time()
    if rate is None:
        for i in range(count):
            send(i)
        return time.process_time() - cpu
    start = time.perf_counter()
    for i in range(count):
        wait = start + i / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        send(i)
    return time.process_time() - cpu


SETUPS = {
    "raw": (raw_proxy, raw_publisher, raw_subscriber),
    "runtime": (bus_broker, runtime_publisher, runtime_subscriber),
    "touch4d": (bus_broker, bus_publisher, bus_subscriber),
}


def run(kind, count, rate, realtime=False):
    ctx = mp.get_context("spawn")
    proxy_fn, pub_fn, sub_fn = SETUPS[kind]
    proxy_end, proxy_conn = ctx.Pipe()
    sub_end, sub_conn = ctx.Pipe()
    pub_end, pub_conn = ctx.Pipe()
    proxy = ctx.Process(target=proxy_fn, args=(proxy_conn, realtime))
    procs = [proxy]
    try:
        proxy.start()
        if not proxy_end.poll(30):
            raise SystemExit(f"{kind}: the proxy did not start")
        ports = proxy_end.recv()
        sub = ctx.Process(target=sub_fn, args=(ports, sub_conn, count, realtime))
        pub = ctx.Process(target=pub_fn, args=(ports, pub_conn, count, rate, realtime))
        procs += [sub, pub]
        sub.start()
        pub.start()
        if not sub_end.poll(60):
            raise SystemExit(f"{kind}: the subscriber did not start")
        sub_end.recv()
        pub_end.send("go")
        if not sub_end.poll(180):
            raise SystemExit(f"{kind}: no result within 180 s")
        lat, first, last, sub_cpu = sub_end.recv()
        pub_cpu = pub_end.recv() if pub_end.poll(30) else float("nan")
        for p in (pub, sub):
            p.join(30)
        proxy_end.send("stop")
        proxy.join(10)
    finally:
        for p in procs:
            if p.is_alive():
                p.kill()
                p.join(5)
        for c in (proxy_end, proxy_conn, sub_end, sub_conn, pub_end, pub_conn):
            c.close()
    lat = np.array(lat) * 1e6
    received = len(lat)
    rate_out = (received - 1) / (last - first) if received > 1 and last > first else float("nan")
    # each process's CPU per message over the messages it handled: the publisher's over those it sent, the
    # subscriber's over those it received (a message dropped at a full queue under load costs the publisher
    # but is not received: counting it against the publisher's received rate made the ratio follow the load)
    pub_us = pub_cpu / count * 1e6
    sub_us = sub_cpu / (received - 1) * 1e6 if received > 1 else float("nan")
    return {"received": received, "p50": float(np.percentile(lat, 50)) if received else float("nan"),
            "p99": float(np.percentile(lat, 99)) if received else float("nan"), "rate": rate_out,
            "cpu_rate": 1e6 / max(pub_us, sub_us), "pub_us": pub_us, "sub_us": sub_us}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency-count", type=int, default=2000)
    parser.add_argument("--latency-rate", type=float, default=1000.0)
    parser.add_argument("--throughput-count", type=int, default=60000)
    parser.add_argument("--rounds", type=int, default=7, help="runs of each setup, interleaved; medians reported")
    parser.add_argument("--no-realtime", dest="realtime", action="store_false",
                        help="latency runs at normal priority (by default SCHED_FIFO when permitted, so the "
                             "figures show the software, not the other load of a shared machine)")
    args = parser.parse_args()
    from touch4d.bus.realtime import realtime_permitted

    realtime = args.realtime and realtime_permitted()

    kinds = ("raw", "runtime", "touch4d")
    load = os.getloadavg()
    print(f"HandPose through one proxy hop, 3 processes on loopback; latency at {args.latency_rate:g} Hz x "
          f"{args.latency_count}, throughput {args.throughput_count} as fast as possible; "
          f"median of {args.rounds} interleaved rounds; load average {load[0]:.2f} ({os.cpu_count()} cores); "
          f"latency runs at {'real-time (SCHED_FIFO)' if realtime else 'normal'} priority")
    print("raw: PUB/SUB + zmq.proxy + msgpack; runtime: touch4d broker and Node with the raw payloads "
          "(no message codec); touch4d: HandPose published and decoded by the Node API")
    rounds = {k: [] for k in kinds}
    for _ in range(args.rounds):  # interleaved, so a burst of load on the machine hits every setup alike
        for k in kinds:
            lat = run(k, args.latency_count, args.latency_rate, realtime)
            thr = run(k, args.throughput_count, None)
            rounds[k].append({"p50": lat["p50"], "p99": lat["p99"], "lost": args.latency_count - lat["received"],
                              "dropped": args.throughput_count - thr["received"],
                              **{m: thr[m] for m in ("rate", "cpu_rate", "pub_us", "sub_us")}})
    res = {k: {m: float(np.median([r[m] for r in rounds[k]])) for m in rounds[k][0]} for k in kinds}
    for k in kinds:
        r = res[k]
        print(f"{k:>8}: latency p50 {r['p50']:7.1f} us  p99 {r['p99']:8.1f} us  throughput {r['rate']:8.0f} msg/s  "
              f"CPU rate {r['cpu_rate']:8.0f} msg/s (CPU per message: publisher {r['pub_us']:.1f} us, "
              f"subscriber {r['sub_us']:.1f} us; as fast as possible, dropped at full queues: "
              f"{', '.join(str(x['dropped']) for x in rounds[k])})   (p99 per round: "
              f"{', '.join(str(round(x['p99'])) for x in rounds[k])}; p50: "
              f"{', '.join(str(round(x['p50'])) for x in rounds[k])} us)")
    for k in ("runtime", "touch4d"):
        print(f"   ratio {k}/raw: latency p50 {res[k]['p50'] / res['raw']['p50']:.2f}x  "
              f"p99 {res[k]['p99'] / res['raw']['p99']:.2f}x (target <= 1.5x)   "
              f"throughput {res[k]['rate'] / res['raw']['rate']:.2f}x, CPU rate "
              f"{res[k]['cpu_rate'] / res['raw']['cpu_rate']:.2f}x (target >= 0.8x)")
    for k in ("runtime", "touch4d"):   # round by round: how steady the ratio is on this machine
        print(f"   throughput ratio {k}/raw per round: " + ", ".join(
            f"{a['rate'] / b['rate']:.2f}" for a, b in zip(rounds[k], rounds["raw"])) + "; CPU rate: " + ", ".join(
            f"{a['cpu_rate'] / b['cpu_rate']:.2f}" for a, b in zip(rounds[k], rounds["raw"])))
    # the verdict: each round's ratio pairs runs made moments apart (so they share the machine's load), and the
    # median of those ratios is what one loaded moment cannot move; the spread shows how much the moments differ
    for k in ("runtime", "touch4d"):
        ratios = np.array([a["cpu_rate"] / b["cpu_rate"] for a, b in zip(rounds[k], rounds["raw"])])
        q1, med, q3 = np.percentile(ratios, [25, 50, 75])
        print(f"   {k}/raw CPU rate, median of {len(ratios)} paired rounds: {med:.2f}x (quartiles {q1:.2f}-{q3:.2f}, "
              f"range {ratios.min():.2f}-{ratios.max():.2f}; target >= 0.8x: {'met' if med >= 0.8 else 'NOT met'})")
    load = os.getloadavg()
    print(f"load average at the end {load[0]:.2f}")


if __name__ == "__main__":
    main()

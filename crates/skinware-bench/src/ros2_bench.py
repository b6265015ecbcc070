"""skin bench ros2's ROS 2 side: stock nodes in their own processes.

    listen WINDOW TOPIC...            rclpy (Fast DDS, default settings): subscribes with each
                                      publisher's offered QoS, prints "counting" when its window
                                      starts, then one JSON line of what it received per topic
    talk HZ SECONDS SIZE...           rclpy: the baseline publisher, one PointCloud2 topic per
                                      SIZE (bytes of data), /baseline/cloud_<i>, reliable (rclpy's
                                      default), frame_id "seq <n>", stamped when published
    zlisten ENDPOINT WINDOW KEYEXPR   eclipse-zenoh: the rmw_zenoh keys under KEYEXPR, their ages
                                      from the attachment's source timestamp

An age is the wall time of the callback minus the message's stamp: a cloud's
stamp is its frame's acquisition, the baseline's its publication.
"""

import json
import sys
import time


def stats(ages_ms):
    if not ages_ms:
        return {"p50_ms": None, "p99_ms": None}
    ordered = sorted(ages_ms)
    n = len(ordered)
    return {"p50_ms": ordered[n // 2], "p99_ms": ordered[min(n - 1, (n * 99) // 100)]}


def listen(window, topics):
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node("skin_bench_listener")
    offered = {}
    deadline = time.monotonic() + 30.0
    while len(offered) < len(topics) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        for topic in topics:
            infos = node.get_publishers_info_by_topic(topic)
            if infos:
                offered[topic] = infos[0]
    received = {topic: {"count": 0, "bytes": 0, "ages_ms": [], "seqs": []} for topic in topics}
    counting = [False]
    subscriptions = []
    for topic, info in offered.items():
        package, _, kind = info.topic_type.split("/")
        cls = getattr(__import__(f"{package}.msg", fromlist=[kind]), kind)
        qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy(info.qos_profile.reliability),
                         durability=DurabilityPolicy(info.qos_profile.durability))

        def callback(msg, topic=topic):
            if not counting[0]:
                return
            now = time.time_ns()
            header = msg.markers[0].header if hasattr(msg, "markers") else msg.header
            entry = received[topic]
            entry["count"] += 1
            entry["bytes"] += len(msg.data) if hasattr(msg, "data") else 0
            entry["ages_ms"].append((now - (header.stamp.sec * 1_000_000_000 + header.stamp.nanosec)) / 1e6)
            if header.frame_id.startswith("seq "):
                entry["seqs"].append(int(header.frame_id[4:]))

        subscriptions.append(node.create_subscription(cls, topic, callback, qos))
    end = time.monotonic() + 1.0  # matching and the first messages
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    counting[0] = True
    print("counting", flush=True)
    end = time.monotonic() + window
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    counting[0] = False
    print("stopped", flush=True)
    out = {}
    for topic, entry in received.items():
        seqs = entry.pop("seqs")
        ages = entry.pop("ages_ms")
        entry.update(stats(ages))
        entry["matched"] = topic in offered
        if seqs:
            entry["sent_by_seq"] = max(seqs) - min(seqs) + 1
        out[topic] = entry
    print(json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def talk(hz, seconds, sizes):
    import rclpy
    from sensor_msgs.msg import PointCloud2, PointField

    rclpy.init()
    node = rclpy.create_node("skin_bench_talker")
    publishers = [node.create_publisher(PointCloud2, f"/baseline/cloud_{i}", 10) for i in range(len(sizes))]
    messages = []
    for size in sizes:
        msg = PointCloud2()
        points = max(1, size // 16)
        msg.height, msg.width = 1, points
        msg.fields = [PointField(name=n, offset=4 * i, datatype=7, count=1)
                      for i, n in enumerate(("x", "y", "z", "response"))]
        msg.point_step, msg.row_step = 16, 16 * points
        msg.data = bytes(16 * points)
        msg.is_dense = True
        messages.append(msg)
    period = 1.0 / hz
    next_at = time.monotonic()
    end = next_at + seconds
    n = 0
    while time.monotonic() < end:
        for publisher, msg in zip(publishers, messages):
            stamp = time.time_ns()
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp // 1_000_000_000, stamp % 1_000_000_000
            msg.header.frame_id = f"seq {n}"
            publisher.publish(msg)
        n += 1
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))
    print(json.dumps({"sent": n}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


def zlisten(endpoint, window, keyexpr):
    import struct

    import zenoh

    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    received = {}
    counting = [False]

    def callback(sample):
        if not counting[0] or sample.attachment is None:
            return
        now = time.time_ns()
        raw = sample.attachment.to_bytes()
        if len(raw) < 16:
            return
        _, stamp = struct.unpack_from("<qq", raw)
        key = str(sample.key_expr)
        entry = received.setdefault(key, {"count": 0, "bytes": 0, "ages_ms": []})
        entry["count"] += 1
        entry["bytes"] += len(sample.payload.to_bytes())
        entry["ages_ms"].append((now - stamp) / 1e6)

    subscriber = session.declare_subscriber(keyexpr, callback)
    time.sleep(1.5)
    counting[0] = True
    print("counting", flush=True)
    time.sleep(window)
    counting[0] = False
    print("stopped", flush=True)
    out = {}
    for key, entry in received.items():
        ages = entry.pop("ages_ms")
        entry.update(stats(ages))
        out[key] = entry
    print(json.dumps(out), flush=True)
    subscriber.undeclare()
    session.close()


if __name__ == "__main__":
    mode = sys.argv[1]
    if mode == "listen":
        listen(float(sys.argv[2]), sys.argv[3:])
    elif mode == "talk":
        talk(float(sys.argv[2]), float(sys.argv[3]), [int(s) for s in sys.argv[4:]])
    else:
        zlisten(sys.argv[2], float(sys.argv[3]), sys.argv[4])

"""A stock ROS 2 node (rclpy, Fast DDS, default settings) on the other end of
skinware's DDS side, in its own process.

    rclpy_peer.py subscribe SECONDS TOPIC...   prints what it received, and the graph, as JSON
    rclpy_peer.py publish TOPIC TYPE HZ PLAN   publishes a layer's frames (PLAN: on,off,on seconds)

`subscribe` takes every topic with the QoS its publisher offers (rclpy's
graph says which), the way `ros2 topic echo` does, and decodes each message
with ROS's own type support. `publish` sends, per message n, the responses
(n * 7 + k) % 65536 for k in 0..SENSORS as a PointCloud2 (field `response`),
a UInt16MultiArray or a Float32MultiArray (full scale 0..1).
"""

import json
import sys
import time

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

TYPES = {}


def message_type(name):
    """The Python class of a full ROS type name, such as sensor_msgs/msg/PointCloud2."""
    if name not in TYPES:
        package, _, kind = name.split("/")
        module = __import__(f"{package}.msg", fromlist=[kind])
        TYPES[name] = getattr(module, kind)
    return TYPES[name]


def qos_json(qos):
    return {
        "reliability": qos.reliability.name,
        "durability": qos.durability.name,
        "history": qos.history.name,
        "depth": qos.depth,
    }


def cloud_json(msg):
    import struct

    fields = [(f.name, f.offset, f.datatype) for f in msg.fields]
    offset = {name: off for name, off, _ in fields}
    data = bytes(msg.data)
    points = []
    for p in range(msg.width * msg.height):
        base = p * msg.point_step
        point = [struct.unpack_from("<f", data, base + offset[n])[0] for n in ("x", "y", "z", "response")]
        points.append(point)
    return {"frame_id": msg.header.frame_id, "fields": fields, "points": points, "is_dense": msg.is_dense}


def diagnostics_json(msg):
    return [
        {"name": s.name, "level": int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level),
         "message": s.message, "hardware_id": s.hardware_id, "values": {kv.key: kv.value for kv in s.values}}
        for s in msg.status
    ]


def subscribe(seconds, topics):
    rclpy.init()
    node = rclpy.create_node("skinware_test_listener")
    graph = {}
    received = {topic: [] for topic in topics}
    deadline = time.monotonic() + 20.0
    # Wait for every topic's publisher: its type and QoS are the graph's.
    while len(graph) < len(topics) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        for topic in topics:
            infos = node.get_publishers_info_by_topic(topic)
            if infos and topic not in graph:
                graph[topic] = [
                    {"node": i.node_name, "namespace": i.node_namespace, "type": i.topic_type,
                     "qos": qos_json(i.qos_profile)}
                    for i in infos
                ]
    subscriptions = []
    for topic, infos in graph.items():
        offered = infos[0]
        kind = offered["type"]
        if kind == "tf2_msgs/msg/TFMessage":
            continue  # no pip wheel of tf2_msgs: the graph is all we check
        qos = QoSProfile(
            depth=10,
            history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy[offered["qos"]["reliability"]],
            durability=DurabilityPolicy[offered["qos"]["durability"]],
        )

        def callback(msg, topic=topic, kind=kind):
            header = msg.markers[0].header if kind == "visualization_msgs/msg/MarkerArray" else msg.header
            entry = {"stamp_ns": header.stamp.sec * 1_000_000_000 + header.stamp.nanosec,
                     "received_ns": time.time_ns()}
            if kind == "sensor_msgs/msg/PointCloud2":
                entry.update(cloud_json(msg))
            elif kind == "diagnostic_msgs/msg/DiagnosticArray":
                entry["status"] = diagnostics_json(msg)
            elif kind == "visualization_msgs/msg/MarkerArray":
                entry["markers"] = [{"action": m.action, "type": m.type, "frame_id": m.header.frame_id,
                                     "points": [[p.x, p.y, p.z] for p in m.points]} for m in msg.markers]
            elif kind == "sensor_msgs/msg/Image":
                entry.update({"width": msg.width, "height": msg.height, "encoding": msg.encoding,
                              "bytes": len(msg.data), "frame_id": msg.header.frame_id})
            received[topic].append(entry)

        subscriptions.append(node.create_subscription(message_type(kind), topic, callback, qos))
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    names = node.get_node_names_and_namespaces()
    print(json.dumps({"graph": graph, "received": received, "nodes": [list(n) for n in names]}))
    node.destroy_node()
    rclpy.shutdown()


def publish(topic, kind, hz, plan, sensors):
    import struct

    from std_msgs.msg import Float32MultiArray, UInt16MultiArray
    from sensor_msgs.msg import PointCloud2, PointField

    rclpy.init()
    node = rclpy.create_node("skinware_test_talker")
    classes = {"PointCloud2": PointCloud2, "UInt16MultiArray": UInt16MultiArray,
               "Float32MultiArray": Float32MultiArray}
    publisher = node.create_publisher(classes[kind], topic, 10)
    # Nothing is sent before the layer's subscription is matched: the test
    # counts every message.
    deadline = time.monotonic() + 20.0
    while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.2)
    n = 0
    for phase, seconds in enumerate(plan):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if phase % 2 == 0:
                values = [(n * 7 + k) % 65536 for k in range(sensors)]
                if kind == "PointCloud2":
                    msg = PointCloud2()
                    msg.header.frame_id = "sensor"
                    msg.height, msg.width = 1, sensors
                    msg.fields = [PointField(name=name, offset=4 * i, datatype=7, count=1)
                                  for i, name in enumerate(("x", "y", "z", "response"))]
                    msg.point_step, msg.row_step = 16, 16 * sensors
                    msg.data = b"".join(struct.pack("<ffff", k * 0.01, 0.0, 0.0, float(v))
                                        for k, v in enumerate(values))
                    msg.is_dense = True
                elif kind == "UInt16MultiArray":
                    msg = UInt16MultiArray(data=values)
                else:
                    msg = Float32MultiArray(data=[v / 65535.0 for v in values])
                publisher.publish(msg)
                n += 1
            time.sleep(1.0 / hz)
        print(json.dumps({"phase": phase, "published": n}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    try:
        if sys.argv[1] == "subscribe":
            subscribe(float(sys.argv[2]), sys.argv[3:])
        else:
            topic, kind, hz, plan, sensors = sys.argv[2:7]
            publish(topic, kind, float(hz), [float(s) for s in plan.split(",")], int(sensors))
    except KeyboardInterrupt:
        pass  # stopped by the test (SIGINT), as a node is

"""What a ROS 2 node on rmw_zenoh would get from `skin bridge`, checked
without ROS: Python's `eclipse-zenoh` subscribes to the exact keys rmw_zenoh
declares (no wildcard, so the type hash must match), `rosbags` computes the
type hashes and decodes the CDR, and zenoh's own deserializer reads the
attachment.

Usage: bridge_ros2_oracle.py ENDPOINT SKIN LAYER SENSORS CONTACT_SERVICE LINK
(LINK: the one robot link the layer covers, whose cloud holds all its SENSORS.)
Prints one JSON line with what it decoded; exits non-zero on any mismatch.
"""

import json
import struct
import sys
import time

import xxhash
import zenoh
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from zenoh.ext import Int64, z_deserialize

endpoint, skin, layer, sensors, contact_service, link = sys.argv[1:7]
sensors = int(sensors)

store = get_typestore(Stores.ROS2_JAZZY)
# tactile_msgs as published by ubi-agni/tactile_toolbox.
extra = {}
extra.update(get_types_from_msg("std_msgs/Header header\nsensor_msgs/ChannelFloat32[] sensors\n", "tactile_msgs/msg/TactileState"))
extra.update(
    get_types_from_msg(
        "std_msgs/Header header\nstring name\ngeometry_msgs/Point position\ngeometry_msgs/Vector3 normal\n"
        "geometry_msgs/Wrench wrench\n",
        "tactile_msgs/msg/TactileContact",
    )
)
extra.update(get_types_from_msg("tactile_msgs/TactileContact[] contacts\n", "tactile_msgs/msg/TactileContacts"))
store.register(extra)


def ros_name(name):
    out = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
    return "_" + out if out[:1].isdigit() else out


def dds(type_name):
    package, _, short = type_name.rpartition("/")
    return package.replace("/", "::") + "::dds_::" + short + "_"


def key(topic, type_name):
    return f"0/{topic.strip('/')}/{dds(type_name)}/{store.hash_rihs01(type_name)}"


def fail(message):
    print(json.dumps({"ok": False, "error": message}))
    sys.exit(1)


config = zenoh.Config()
config.insert_json5("mode", '"peer"')
config.insert_json5("connect/endpoints", json.dumps([endpoint]))
config.insert_json5("listen/endpoints", "[]")
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)

topics = {
    "state": (f"/skin/{ros_name(skin)}/{ros_name(layer)}/state", "tactile_msgs/msg/TactileState"),
    "map": (f"/skin/{ros_name(skin)}/map", "sensor_msgs/msg/Image"),
    "contacts": (f"/skin/{ros_name(skin)}/{ros_name(contact_service)}/contacts", "tactile_msgs/msg/TactileContacts"),
    # The standard topics, as ROS tools draw them.
    "cloud": (f"/skin/{ros_name(skin)}/{ros_name(layer)}/cloud/{ros_name(link)}", "sensor_msgs/msg/PointCloud2"),
    "markers": (f"/skin/{ros_name(skin)}/{ros_name(contact_service)}/markers", "visualization_msgs/msg/MarkerArray"),
    "diagnostics": ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
}
subscribers = {
    name: session.declare_subscriber(key(topic, type_name), zenoh.handlers.FifoChannel(256))
    for name, (topic, type_name) in topics.items()
}
wanted = {"state": 10, "map": 2, "contacts": 5, "cloud": 3, "markers": 3, "diagnostics": 2}
samples = {name: [] for name in topics}
deadline = time.time() + 30
while time.time() < deadline and any(len(samples[n]) < wanted[n] for n in topics):
    for name, subscriber in subscribers.items():
        sample = subscriber.try_recv()
        if sample is not None:
            samples[name].append(sample)
    time.sleep(0.002)
for name in topics:
    if len(samples[name]) < wanted[name]:
        fail(f"{name}: {len(samples[name])} samples on {key(*topics[name])} in 30 s, wanted {wanted[name]}")

report = {"ok": True, "keys": {name: key(*topics[name]) for name in topics}}

# The graph: the node and one publisher token per topic, as `ros2 topic list` reads them.
tokens = [str(reply.ok.key_expr) for reply in session.liveliness().get("@ros2_lv/**", timeout=5) if reply.ok]
report["tokens"] = len(tokens)
if not any("/NN/" in t and t.endswith("skin_bridge_" + ros_name(skin).lstrip("_")) for t in tokens):
    fail(f"no node token among {tokens}")
gids = {}
for name, (topic, type_name) in topics.items():
    mangled = topic.replace("/", "%")
    matching = [t for t in tokens if "/MP/" in t and f"/{mangled}/{dds(type_name)}/{store.hash_rihs01(type_name)}/" in t]
    if len(matching) != 1:
        fail(f"{name}: publisher tokens for {topic}: {matching} (all: {tokens})")
    gids[name] = xxhash.xxh3_128(matching[0].encode()).intdigest().to_bytes(16, "little")

for name, received in samples.items():
    previous = None
    for sample in received:
        if sample.attachment is None:
            fail(f"{name}: a sample without the attachment rmw_zenoh requires")
        raw = sample.attachment.to_bytes()
        if len(raw) != 33:
            fail(f"{name}: attachment of {len(raw)} bytes, not 33")
        seq, stamp, gid_len, gid = struct.unpack("<qqB16s", raw)
        # zenoh's own deserializer reads the same three fields.
        z_seq, z_stamp, z_gid = z_deserialize(tuple[Int64, Int64, bytes], sample.attachment)
        if (z_seq, z_stamp, z_gid) != (seq, stamp, gid) or gid_len != 16:
            fail(f"{name}: zenoh-ext reads {(z_seq, z_stamp, z_gid)}, the layout says {(seq, stamp, gid)}")
        if gid != gids[name]:
            fail(f"{name}: GID {gid.hex()} is not XXH3-128 of its liveliness token ({gids[name].hex()})")
        if previous is not None and seq <= previous:
            fail(f"{name}: sequence numbers {previous} then {seq}")
        if abs(stamp / 1e9 - time.time()) > 60:
            fail(f"{name}: source timestamp {stamp} is not now")
        previous = seq
    payload = received[-1].payload.to_bytes()
    if payload[:4] != b"\x00\x01\x00\x00":
        fail(f"{name}: CDR header {payload[:4].hex()}, not little-endian plain CDR")

state = store.deserialize_cdr(samples["state"][-1].payload.to_bytes(), "tactile_msgs/msg/TactileState")
values = [v for channel in state.sensors for v in channel.values]
if state.header.frame_id != layer or len(values) != sensors:
    fail(f"TactileState: frame {state.header.frame_id}, {len(values)} values; wanted {layer}, {sensors}")
if not all(0.0 <= v <= 1.0 for v in values) or not all(c.name.startswith(layer + "/patch") for c in state.sensors):
    fail("TactileState: values outside 0..1 or arrays not named <layer>/patch<id>")
report["state"] = {"arrays": len(state.sensors), "values": len(values), "first": state.sensors[0].name,
                   "stamp": [state.header.stamp.sec, state.header.stamp.nanosec],
                   "raw_head": [round(v * 65535) for v in values[:5]]}

image = store.deserialize_cdr(samples["map"][-1].payload.to_bytes(), "sensor_msgs/msg/Image")
if image.encoding != "rgb8" or image.step != 3 * image.width or len(image.data) != image.step * image.height:
    fail(f"Image: {image.encoding} {image.width}x{image.height} step {image.step}, {len(image.data)} bytes")
report["map"] = {"width": image.width, "height": image.height, "bytes": len(image.data)}

contacts = [store.deserialize_cdr(s.payload.to_bytes(), "tactile_msgs/msg/TactileContacts") for s in samples["contacts"]]
report["contacts"] = {"messages": len(contacts), "contacts": sum(len(c.contacts) for c in contacts)}
cloud = store.deserialize_cdr(samples["cloud"][-1].payload.to_bytes(), "sensor_msgs/msg/PointCloud2")
fields = [(f.name, f.offset, f.datatype) for f in cloud.fields]
if fields != [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("response", 12, 7)] or cloud.header.frame_id != link:
    fail(f"PointCloud2: fields {fields}, frame {cloud.header.frame_id}")
if cloud.width * cloud.height != sensors or len(cloud.data) != 16 * sensors:
    fail(f"PointCloud2: {cloud.width}x{cloud.height} points, {len(cloud.data)} bytes, for {sensors} taxels")
responses = [struct.unpack_from("<f", bytes(cloud.data), 16 * p + 12)[0] for p in range(sensors)]
if not all(0.0 <= r <= 65535.0 and r == int(r) for r in responses):
    fail("PointCloud2: responses that are not raw responses")
report["cloud"] = {"points": cloud.width * cloud.height, "frame": cloud.header.frame_id, "max": max(responses)}
markers = store.deserialize_cdr(samples["markers"][-1].payload.to_bytes(), "visualization_msgs/msg/MarkerArray")
if not markers.markers or markers.markers[0].action != 3:
    fail("MarkerArray: not a DELETEALL first")
report["markers"] = {"markers": len(markers.markers)}
health = store.deserialize_cdr(samples["diagnostics"][-1].payload.to_bytes(), "diagnostic_msgs/msg/DiagnosticArray")
names = [status.name for status in health.status]
if f"skin/{skin}/{layer}" not in names:
    fail(f"DiagnosticArray: no status of the layer among {names}")
report["diagnostics"] = {"status": names}
report["hashes"] = {t: store.hash_rihs01(t) for _, t in topics.values()}
print(json.dumps(report))
session.close()

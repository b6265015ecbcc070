"""The independent oracle: reads a skinware recording with Python's `mcap`
and `mcap-ros2-support` packages (which parse the embedded ros2msg schemas
and decode CDR themselves) and prints, as JSON, what it decoded.

Every message is reduced to a digest of all its decoded fields (see
`canonical` below; the Rust test builds the same bytes from its own decoder),
so the test compares the two decoders message by message: every taxel of
every frame, every pixel of every image, every statistic and gap.

Usage: read_recording.py FILE.mcap
"""

import array
import hashlib
import json
import struct
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

# The map's background colour: pixels that show no taxel.
BACKGROUND = b"\x0b\x0c\x0f"


class Canonical:
    """Fields appended in a fixed binary form: integers as 8 bytes little
    endian, floats as their IEEE 754 bits, strings and arrays prefixed by
    their length."""

    def __init__(self):
        self.parts = []

    def int(self, value):
        self.parts.append(struct.pack("<q" if value < 0 else "<Q", value))
        return self

    def float(self, value):
        self.parts.append(struct.pack("<d", value))
        return self

    def time(self, t):
        return self.int(t.sec).int(t.nanosec)

    def text(self, value):
        data = value.encode("utf-8")
        return self.int(len(data)).raw(data)

    def u16s(self, values):
        data = array.array("H", values)
        if sys.byteorder != "little":
            data.byteswap()
        return self.int(len(data)).raw(data.tobytes())

    def u8s(self, values):
        data = bytes(values)
        return self.int(len(data)).raw(data)

    def raw(self, data):
        self.parts.append(data)
        return self

    def digest(self):
        return hashlib.sha256(b"".join(self.parts)).hexdigest()[:16]


def canonical(schema, m):
    c = Canonical()
    if schema == "skinware_msgs/msg/SkinFrame":
        c.time(m.stamp).time(m.published).int(m.seq).int(m.status).int(m.skipped)
        c.u16s(m.responses).u8s(m.payload)
    elif schema == "sensor_msgs/msg/Image":
        c.time(m.header.stamp).text(m.header.frame_id).int(m.height).int(m.width).text(m.encoding)
        c.int(m.is_bigendian).int(m.step).u8s(m.data)
    elif schema == "skinware_msgs/msg/LayerStats":
        c.time(m.stamp).text(m.channel).text(m.state).int(m.frames).int(m.lost).int(m.faulted)
        c.float(m.rate_hz).float(m.latency_ms).int(m.min_response).int(m.max_response).float(m.mean_response)
    elif schema == "skinware_msgs/msg/Gap":
        c.time(m.stamp).text(m.channel).int(m.first_seq).int(m.count)
    elif schema == "sensor_msgs/msg/PointCloud2":
        c.time(m.header.stamp).text(m.header.frame_id).int(m.height).int(m.width).int(len(m.fields))
        for f in m.fields:
            c.text(f.name).int(f.offset).int(f.datatype).int(f.count)
        c.int(m.is_bigendian).int(m.point_step).int(m.row_step).u8s(m.data).int(m.is_dense)
    elif schema == "visualization_msgs/msg/MarkerArray":
        c.int(len(m.markers))
        for k in m.markers:
            c.time(k.header.stamp).text(k.header.frame_id).text(k.ns).int(k.id).int(k.type).int(k.action)
            c.int(k.lifetime.sec).int(k.lifetime.nanosec).int(len(k.points))
            for p in k.points:
                c.float(p.x).float(p.y).float(p.z)
    elif schema == "diagnostic_msgs/msg/DiagnosticArray":
        c.time(m.header.stamp).text(m.header.frame_id).int(len(m.status))
        for s in m.status:
            # `byte` decodes as an int or as a one-byte bytes, by version.
            level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else s.level
            c.int(level).text(s.name).text(s.message).text(s.hardware_id).int(len(s.values))
            for kv in s.values:
                c.text(kv.key).text(kv.value)
    elif schema == "tf2_msgs/msg/TFMessage":
        c.int(len(m.transforms))
        for t in m.transforms:
            c.time(t.header.stamp).text(t.header.frame_id).text(t.child_frame_id)
            v, q = t.transform.translation, t.transform.rotation
            c.float(v.x).float(v.y).float(v.z).float(q.x).float(q.y).float(q.z).float(q.w)
    else:
        raise SystemExit(f"unexpected schema {schema}")
    return c.digest()


def main(path):
    topics = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: len(a.data) for a in reader.iter_attachments()}
        # In file order, as skinware's reader reads: by default the package
        # sorts by log time, and gaps of different channels are written in
        # the order they were found, not by the acquisition time they carry.
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            t = topics.setdefault(channel.topic, {
                "schema": schema.name,
                "messages": 0,
                "channel": channel.metadata.get("skinware.channel"),
                "digests": [],
            })
            t["messages"] += 1
            t["digests"].append(canonical(schema.name, decoded))
            if schema.name == "skinware_msgs/msg/SkinFrame":
                stamp_ns = decoded.stamp.sec * 1_000_000_000 + decoded.stamp.nanosec
                if stamp_ns != message.log_time:
                    raise SystemExit(f"{channel.topic}: stamp {stamp_ns} is not log_time {message.log_time}")
                t.setdefault("seqs", []).append(decoded.seq)
            elif schema.name == "sensor_msgs/msg/Image":
                if decoded.encoding != "rgb8" or len(decoded.data) != decoded.height * decoded.step \
                        or decoded.step != 3 * decoded.width:
                    raise SystemExit(f"{channel.topic}: image {decoded.width}x{decoded.height} "
                                     f"{decoded.encoding} step {decoded.step} with {len(decoded.data)} bytes")
                data = bytes(decoded.data)
                t["size"] = [decoded.width, decoded.height]
                t["lit_pixels"] = t.get("lit_pixels", 0) + sum(
                    1 for i in range(0, len(data), 3) if data[i:i + 3] != BACKGROUND)
            elif schema.name == "skinware_msgs/msg/Gap":
                t["missing"] = t.get("missing", 0) + decoded.count
    for t in topics.values():
        if "seqs" in t:
            seqs = t.pop("seqs")
            t["seq_increasing"] = all(b > a for a, b in zip(seqs, seqs[1:]))
    print(json.dumps({
        "profile": header.profile,
        "library": header.library,
        "has_summary": summary is not None,
        "metadata": metadata,
        "attachments": attachments,
        "topics": topics,
    }, indent=1, sort_keys=True))


if __name__ == "__main__":
    main(sys.argv[1])

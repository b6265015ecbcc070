"""The independent oracle: reads a skinware recording with Python's `mcap`
and `mcap-ros2-support` packages (which parse the embedded ros2msg schemas
and decode CDR themselves) and prints, as JSON, what it decoded.

Usage: read_recording.py FILE.mcap
The Rust tests compare this with what skinware wrote.
"""

import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def main(path):
    topics = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: len(a.data) for a in reader.iter_attachments()}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            t = topics.setdefault(channel.topic, {
                "schema": schema.name,
                "messages": 0,
                "channel": channel.metadata.get("skinware.channel"),
            })
            t["messages"] += 1
            if schema.name == "skinware_msgs/msg/SkinFrame":
                stamp_ns = decoded.stamp.sec * 1_000_000_000 + decoded.stamp.nanosec
                if stamp_ns != message.log_time:
                    raise SystemExit(f"{channel.topic}: stamp {stamp_ns} is not log_time {message.log_time}")
                responses = list(decoded.responses)
                payload = bytes(decoded.payload)
                t.setdefault("lengths", set()).add(len(responses) or len(payload))
                # Sums and per-frame checks an encoder mistake would break.
                t["response_sum"] = t.get("response_sum", 0) + sum(responses)
                t["payload_sum"] = t.get("payload_sum", 0) + sum(payload)
                t["skipped"] = t.get("skipped", 0) + decoded.skipped
                t.setdefault("seqs", []).append(decoded.seq)
                t["faulted"] = t.get("faulted", 0) + (decoded.status & 1)
            elif schema.name == "sensor_msgs/msg/Image":
                if decoded.encoding != "rgb8" or len(decoded.data) != decoded.height * decoded.step \
                        or decoded.step != 3 * decoded.width:
                    raise SystemExit(f"{channel.topic}: image {decoded.width}x{decoded.height} "
                                     f"{decoded.encoding} step {decoded.step} with {len(decoded.data)} bytes")
                t["size"] = [decoded.width, decoded.height]
                t["lit_pixels"] = t.get("lit_pixels", 0) + sum(1 for i in range(0, len(decoded.data), 3)
                                                               if decoded.data[i:i + 3] != b"\x0b\x0c\x0f")
            elif schema.name == "skinware_msgs/msg/LayerStats":
                t["last_frames"] = decoded.frames
                t["state"] = decoded.state
            elif schema.name == "skinware_msgs/msg/Gap":
                t["missing"] = t.get("missing", 0) + decoded.count
    for t in topics.values():
        if "lengths" in t:
            t["lengths"] = sorted(t["lengths"])
            seqs = t.pop("seqs")
            t["first_seq"], t["last_seq"] = seqs[0], seqs[-1]
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

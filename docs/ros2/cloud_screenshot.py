"""The skin's clouds as a stock ROS 2 node receives them, drawn to a PNG.

    python cloud_screenshot.py OUT.png [SKIN]

An rclpy node (Fast DDS) subscribes to every `/skin/<SKIN>/*/cloud/*` topic
that `skin bridge --ros2 dds` publishes, takes the newest cloud of each, and
draws every point at its position, coloured by its `response` field, with
matplotlib. It is what docs/bench/ros2-cloud.png shows: no rviz2 or Foxglove
can run on the machine it was made on (no ROS installation, no display).
Needs rclpy, sensor_msgs and matplotlib in the Python that runs it.
"""

import struct
import sys
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import rclpy  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402


def main(out, skin):
    rclpy.init()
    node = rclpy.create_node("skin_cloud_screenshot")
    newest = {}
    deadline = time.monotonic() + 10.0
    topics = []
    while not topics and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.2)
        topics = [name for name, types in node.get_topic_names_and_types()
                  if name.startswith(f"/skin/{skin}/") and "/cloud/" in name]
    subscriptions = [
        node.create_subscription(PointCloud2, topic,
                                 lambda msg, topic=topic: newest.__setitem__(topic, msg),
                                 qos_profile_sensor_data)
        for topic in topics
    ]
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    xs, ys, zs, cs = [], [], [], []
    for msg in newest.values():
        offsets = {f.name: f.offset for f in msg.fields}
        data = bytes(msg.data)
        for p in range(msg.width * msg.height):
            base = p * msg.point_step
            x, y, z, r = (struct.unpack_from("<f", data, base + offsets[n])[0] for n in ("x", "y", "z", "response"))
            xs.append(x), ys.append(y), zs.append(z), cs.append(r)
    figure = plt.figure(figsize=(8, 9), dpi=100)
    axes = figure.add_subplot(projection="3d")
    drawn = axes.scatter(xs, ys, zs, c=cs, cmap="turbo", s=1.5, vmin=0, vmax=max(cs + [1]))
    axes.set_title(f"skin {skin}: {len(xs)} taxels from {len(newest)} PointCloud2 topics (rclpy, Fast DDS)")
    axes.set_xlabel("x (m)"), axes.set_ylabel("y (m)"), axes.set_zlabel("z (m)")
    axes.set_box_aspect((max(xs) - min(xs), max(ys) - min(ys), max(zs) - min(zs)))
    axes.view_init(elev=15, azim=-60)
    figure.colorbar(drawn, shrink=0.5, label="response")
    figure.savefig(out, bbox_inches="tight")
    print(f"{out}: {len(xs)} points from {sorted(newest)}")
    del subscriptions
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "default")

"""The independent decoder: ROS 2's own type support (rclpy, from the pip
wheels of ros-python-wheels) decodes the CDR files skinware wrote, and the
type hashes the ROS packages ship are read from their share/ directories.

Usage: rclpy_oracle.py DIR TYPE...
  DIR holds <package>__<Type>.cdr files; each is decoded with the class
  <package>.msg.<Type>. TYPE... are full type names whose published hash is
  looked up (share/<package>/msg/<Type>.json). Prints one JSON object:
  {"distro": ..., "messages": {type: fields}, "hashes": {type: hash or null}}.
"""

import array
import importlib
import json
import os
import sys

from rclpy.serialization import deserialize_message


def plain(value):
    """A message as JSON-ready Python values, field by field."""
    if hasattr(value, "get_fields_and_field_types"):
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, (list, tuple, array.array)) or type(value).__name__ == "ndarray":
        return [plain(v) for v in value]
    return value


def published_hash(full_name):
    package, _, short = full_name.split("/")
    path = os.path.join(sys.prefix, "share", package, "msg", short + ".json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        hashes = json.load(f)["type_hashes"]
    return next(h["hash_string"] for h in hashes if h["type_name"] == full_name)


def main():
    directory, names = sys.argv[1], sys.argv[2:]
    messages = {}
    for file in sorted(os.listdir(directory)):
        if not file.endswith(".cdr"):
            continue
        package, short = file[: -len(".cdr")].split("__")
        cls = getattr(importlib.import_module(package + ".msg"), short)
        with open(os.path.join(directory, file), "rb") as f:
            messages[f"{package}/msg/{short}"] = plain(deserialize_message(f.read(), cls))
    print(json.dumps({
        "distro": os.environ.get("ROS_DISTRO") or os.path.basename(sys.prefix),
        "messages": messages,
        "hashes": {name: published_hash(name) for name in names},
    }))


main()

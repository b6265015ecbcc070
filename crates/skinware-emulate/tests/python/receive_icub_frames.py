"""python-can as the host of emulated MTB boards: configures board 1
(period 20 ms, no-load 240), starts it, and prints what it received as JSON:
per (board, triangle), the number of head and tail frames and the last
12 raw values. Usage: receive_icub_frames.py SERIAL_PATH SECONDS
"""
import json
import sys
import time

import can

path, seconds = sys.argv[1], float(sys.argv[2])
bus = can.Bus(interface="slcan", channel=path, bitrate=1000000, sleep_after_open=0.05)
for data in ([0x4D, 0, 20, 240], [0x50, 0, 15, 0, 1, 0x00, 0x22], [0x07, 0]):
    bus.send(can.Message(arbitration_id=0x201, data=data, is_extended_id=False))
seen = {}
end = time.monotonic() + seconds
while time.monotonic() < end:
    message = bus.recv(0.05)
    if message is None or message.arbitration_id >> 8 != 4:
        continue
    board, triangle = (message.arbitration_id >> 4) & 0xF, message.arbitration_id & 0xF
    entry = seen.setdefault(f"{board}.{triangle}", {"heads": 0, "tails": 0, "raw": [0] * 12})
    if message.data[0] & 0x80:
        entry["tails"] += 1
        entry["raw"][7:12] = list(message.data[1:6])
    else:
        entry["heads"] += 1
        entry["raw"][0:7] = list(message.data[1:8])
bus.send(can.Message(arbitration_id=0x201, data=[0x07, 1], is_extended_id=False))
bus.shutdown()
print(json.dumps(seen))

"""An independent sender of iCub MTB frames: python-can's own SLCAN
interface, with the frames built here from the protocol's description, not
by skinware. Usage: send_icub_frames.py SERIAL_PATH BOARD TRIANGLES SECONDS

Taxel k of triangle t reads 240 - (12 * t + k) on the wire (no-load 240,
pressure lowers the value), so skinware must publish 15 + 12 * t + k.
"""
import sys
import time

import can

path, board, triangles, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
bus = can.Bus(interface="slcan", channel=path, bitrate=1000000)
end = time.monotonic() + seconds
sent = 0
while time.monotonic() < end:
    for t in range(triangles):
        raw = [240 - (12 * t + k) for k in range(12)]
        can_id = (4 << 8) | (board << 4) | t
        head = bytes([0x40] + raw[:7])
        tail = bytes([0xC0] + raw[7:] + [0x00, 0x00])
        bus.send(can.Message(arbitration_id=can_id, data=head, is_extended_id=False))
        bus.send(can.Message(arbitration_id=can_id, data=tail, is_extended_id=False))
        sent += 2
    time.sleep(0.02)
bus.shutdown()
print(f"sent {sent} frames")

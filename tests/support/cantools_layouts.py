"""The peer of tests/python_can.rs's layout test: cantools decodes random frames of
every message of a DBC file and prints, per frame, the bytes and its decoding as a JSON
line (a float that is not finite as null), for adrive's decoding to be compared with."""

import json
import math
import random
import sys

import cantools

db = cantools.database.load_file(sys.argv[1])
rng = random.Random(int(sys.argv[2]))
for message in db.messages:
    for _ in range(int(sys.argv[3])):
        data = bytes(rng.randrange(256) for _ in range(message.length))
        if message.name == "MUXED":
            data = bytes([data[0] & 0xF1]) + data[1:]  # selector 0 or 1 (bits 1-3 zero)
        decoded = message.decode(data, decode_choices=False, scaling=True)
        print(
            json.dumps(
                {
                    "id": message.frame_id,
                    "extended": message.is_extended_frame,
                    "data": data.hex(),
                    "signals": {
                        k: (float(v) if math.isfinite(float(v)) else None)
                        for k, v in decoded.items()
                    },
                }
            ),
            flush=True,
        )
print("DONE", flush=True)

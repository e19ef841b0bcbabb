"""The peer of tests/python_can.rs: python-can's slcan interface opens the simulated
adapter's pseudo-terminal, and cantools encodes and decodes every frame from the same
DBC file. It prints each frame it receives as a JSON line (identifier, bytes, cantools'
decoding) for the Rust side to compare with adrive's, then the milestones it reached:
ENABLED (a throttle report says enabled after THROTTLE_ENABLE and a command), DISABLED
(after THROTTLE_DISABLE), DONE. It exits non-zero, with the reason, when a milestone is
not reached in time."""

import json
import sys
import time

import can
import cantools

path, dbc_path = sys.argv[1], sys.argv[2]
db = cantools.database.load_file(dbc_path)
bus = can.Bus(interface="slcan", channel=path, bitrate=500000, sleep_after_open=0)


def send(name, **values):
    message = db.get_message_by_name(name)
    full = {"magic_0": 5, "magic_1": 204}
    full.update(values)
    data = message.encode(full)
    bus.send(
        can.Message(
            arbitration_id=message.frame_id,
            data=data,
            is_extended_id=message.is_extended_frame,
        )
    )


def collect(seconds, until=None):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        msg = bus.recv(0.05)
        if msg is None:
            continue
        message = db.get_message_by_frame_id(msg.arbitration_id)
        decoded = message.decode(msg.data, decode_choices=False)
        print(
            json.dumps(
                {
                    "id": msg.arbitration_id,
                    "extended": msg.is_extended_id,
                    "data": bytes(msg.data).hex(),
                    "name": message.name,
                    "signals": {k: float(v) for k, v in decoded.items()},
                }
            ),
            flush=True,
        )
        if until is not None and until(message.name, decoded):
            return True
    return False


def throttle_enabled(want):
    return lambda name, s: name == "THROTTLE_REPORT" and s["enabled"] == want


try:
    collect(0.3)
    send("THROTTLE_ENABLE")
    send("THROTTLE_COMMAND", torque_request=0.25)
    if not collect(5.0, throttle_enabled(1)):
        sys.exit("no THROTTLE_REPORT with enabled = 1 within 5 s of THROTTLE_ENABLE")
    print("ENABLED", flush=True)
    for _ in range(4):
        send("THROTTLE_COMMAND", torque_request=0.25)
        collect(0.05)
    send("THROTTLE_DISABLE")
    if not collect(5.0, throttle_enabled(0)):
        sys.exit("no THROTTLE_REPORT with enabled = 0 within 5 s of THROTTLE_DISABLE")
    print("DISABLED", flush=True)
finally:
    bus.shutdown()
print("DONE", flush=True)

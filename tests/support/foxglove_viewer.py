"""A third-party Foxglove WebSocket client (the `websockets` package) against adrive's
live view: connect with one subprotocol name, read serverInfo and the advertisement,
subscribe to /snapshot, one device channel and /gate, decode the binary message data
and validate every message against the JSON Schema its channel advertised
(`jsonschema`). Prints one JSON line with what it saw; exits non-zero on any mismatch.

usage: foxglove_viewer.py URL SUBPROTOCOL DEVICE_TOPIC COUNT
"""

import json
import struct
import sys
import time

import jsonschema
from websockets.sync.client import connect


def main():
    url, subprotocol, device_topic, count = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
    with connect(url, subprotocols=[subprotocol], max_size=None, open_timeout=10) as ws:
        assert ws.subprotocol == subprotocol, f"answered {ws.subprotocol!r}, asked {subprotocol!r}"
        info = json.loads(ws.recv(timeout=10))
        assert info["op"] == "serverInfo", info
        for cap in ("clientPublish", "services", "parameters", "parametersSubscribe"):
            assert cap not in info["capabilities"], info
        adv = json.loads(ws.recv(timeout=10))
        assert adv["op"] == "advertise", adv
        channels = {c["topic"]: c for c in adv["channels"]}
        validators = {}
        for c in adv["channels"]:
            assert c["encoding"] == "json", c
            assert c["schemaEncoding"] == "jsonschema", c
            schema = json.loads(c["schema"])
            jsonschema.Draft7Validator.check_schema(schema)
            validators[c["id"]] = jsonschema.Draft7Validator(schema)
        wanted = ["/snapshot", device_topic, "/gate"]
        subs = {}
        for i, topic in enumerate(wanted):
            assert topic in channels, f"{topic} not advertised: {sorted(channels)}"
            subs[100 + i] = channels[topic]
        ws.send(json.dumps({
            "op": "subscribe",
            "subscriptions": [{"id": s, "channelId": c["id"]} for s, c in subs.items()],
        }))
        subscribed = time.monotonic()
        seen = {c["topic"]: 0 for c in subs.values()}
        first = {}
        last = {}
        now_ns = time.time_ns()
        deadline = time.monotonic() + 20
        while min(seen[t] for t in ("/snapshot", device_topic)) < count or seen["/gate"] < 1:
            assert time.monotonic() < deadline, f"messages seen by the deadline: {seen}"
            m = ws.recv(timeout=20)
            if isinstance(m, str):
                op = json.loads(m)
                assert op["op"] != "status" or op["level"] == 0, op
                continue
            opcode, sub, log_time = struct.unpack_from("<BIQ", m, 0)
            assert opcode == 1, opcode
            assert sub in subs, f"unknown subscription {sub}"
            assert abs(log_time - now_ns) < 120e9, f"log time {log_time} is not near now {now_ns}"
            payload = json.loads(m[13:])
            errors = [f"{e.message} at {list(e.absolute_path)}"
                      for e in validators[subs[sub]["id"]].iter_errors(payload)]
            assert not errors, f"{subs[sub]['topic']}: {errors}"
            topic = subs[sub]["topic"]
            seen[topic] += 1
            first.setdefault(topic, time.monotonic() - subscribed)
            last[topic] = payload
        print(json.dumps({
            "subprotocol": ws.subprotocol,
            "server": info["name"],
            "channels": sorted(channels),
            "seen": seen,
            "first_s": first,
            "gate": last["/gate"],
            "device": last[device_topic],
        }), flush=True)


if __name__ == "__main__":
    main()

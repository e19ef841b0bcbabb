"""A third-party ROS 2 peer for adrive's tests: Eclipse Zenoh's Python API speaking
ROS 2 the way rmw_zenoh does, with rosbags for CDR and RIHS01 type hashes, from the
official message definitions below (comments dropped, fields and constants as
published in autoware_msgs, tier4_autoware_msgs and ROS 2's service_msgs).

    ros2_peer.py interfaces            < request.json   hashes and CDR bytes
    ros2_peer.py drive ENDPOINT NS TIRE                 drive one vehicle; watchdog, emergency, stale stream
    ros2_peer.py two EP_A NS_A EP_B NS_B TIRE           drive B, and A never moves

TIRE is the vehicle's radians of tire angle per unit of steering (its [ros2]).

Progress goes to standard output, one line each; the last line is PASS or FAIL: why.
"""

import json
import os
import sys
import threading
import time

import xxhash
import zenoh
import zenoh.ext as ze
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

DEFINITIONS = {
    "autoware_vehicle_msgs/msg/SteeringReport": """
builtin_interfaces/Time stamp
float32 steering_tire_angle
""",
    "autoware_vehicle_msgs/msg/VelocityReport": """
std_msgs/Header header
float32 longitudinal_velocity
float32 lateral_velocity
float32 heading_rate
""",
    "autoware_vehicle_msgs/msg/GearCommand": """
uint8 NONE = 0
uint8 NEUTRAL = 1
uint8 DRIVE = 2
uint8 REVERSE = 20
uint8 PARK = 22
uint8 LOW = 23
builtin_interfaces/Time stamp
uint8 command
""",
    "autoware_vehicle_msgs/msg/GearReport": """
uint8 NONE = 0
uint8 NEUTRAL = 1
uint8 DRIVE = 2
uint8 REVERSE = 20
uint8 PARK = 22
builtin_interfaces/Time stamp
uint8 report
""",
    "autoware_vehicle_msgs/msg/ControlModeReport": """
uint8 NO_COMMAND = 0
uint8 AUTONOMOUS = 1
uint8 AUTONOMOUS_STEER_ONLY = 2
uint8 AUTONOMOUS_VELOCITY_ONLY = 3
uint8 MANUAL = 4
uint8 DISENGAGED = 5
uint8 NOT_READY = 6
builtin_interfaces/Time stamp
uint8 mode
""",
    "autoware_vehicle_msgs/msg/TurnIndicatorsCommand": """
uint8 NO_COMMAND = 0
uint8 DISABLE = 1
uint8 ENABLE_LEFT = 2
uint8 ENABLE_RIGHT = 3
builtin_interfaces/Time stamp
uint8 command
""",
    "autoware_vehicle_msgs/msg/TurnIndicatorsReport": """
uint8 DISABLE = 1
uint8 ENABLE_LEFT = 2
uint8 ENABLE_RIGHT = 3
builtin_interfaces/Time stamp
uint8 report
""",
    "autoware_vehicle_msgs/msg/HazardLightsCommand": """
uint8 NO_COMMAND = 0
uint8 DISABLE = 1
uint8 ENABLE = 2
builtin_interfaces/Time stamp
uint8 command
""",
    "autoware_vehicle_msgs/msg/HazardLightsReport": """
uint8 DISABLE = 1
uint8 ENABLE = 2
builtin_interfaces/Time stamp
uint8 report
""",
    "tier4_vehicle_msgs/msg/ActuationCommand": """
float64 accel_cmd
float64 brake_cmd
float64 steer_cmd
""",
    "tier4_vehicle_msgs/msg/ActuationCommandStamped": """
std_msgs/Header header
tier4_vehicle_msgs/ActuationCommand actuation
""",
    "tier4_vehicle_msgs/msg/ActuationStatus": """
float64 accel_status
float64 brake_status
float64 steer_status
""",
    "tier4_vehicle_msgs/msg/ActuationStatusStamped": """
std_msgs/Header header
tier4_vehicle_msgs/ActuationStatus status
""",
    "tier4_vehicle_msgs/msg/VehicleEmergencyStamped": """
builtin_interfaces/Time stamp
bool emergency
""",
}

# Services: request, response. A service's type description holds its request, its
# response and its event message (service_msgs/ServiceEventInfo and at most one of
# each), as rosidl generates it.
SERVICES = {
    "autoware_vehicle_msgs/srv/ControlModeCommand": (
        """
uint8 NO_COMMAND = 0
uint8 AUTONOMOUS = 1
uint8 AUTONOMOUS_STEER_ONLY = 2
uint8 AUTONOMOUS_VELOCITY_ONLY = 3
uint8 MANUAL = 4
builtin_interfaces/Time stamp
uint8 mode
""",
        "bool success",
    ),
    # A control: rmw_zenoh's design document gives this service's hash.
    "example_interfaces/srv/AddTwoInts": ("int64 a\nint64 b", "int64 sum"),
}

# service_msgs/msg/ServiceEventInfo as rosidl sees it: its `char[16]` is uint8 in IDL
# (rosbags' bundled copy keeps `char`, which hashes differently).
SERVICE_EVENT_INFO = """
uint8 event_type
builtin_interfaces/Time stamp
uint8[16] client_gid
int64 sequence_number
"""


def _fix(x):
    """rosbags files `pkg/srv/Name` under `pkg/srv/msg/Name`; put it back."""
    if isinstance(x, str):
        return x.replace("/srv/msg/", "/srv/")
    if isinstance(x, (tuple, list)):
        return type(x)(_fix(i) for i in x)
    return x


def typestores():
    """The message store (ROS 2 Jazzy plus the definitions above) and the service
    store (built from scratch, with the IDL ServiceEventInfo)."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    for name, text in DEFINITIONS.items():
        ts.register(get_types_from_msg(text, name))
    srv = get_typestore(Stores.EMPTY)

    def reg(name, text):
        srv.register({_fix(k): _fix(v) for k, v in get_types_from_msg(text, name).items()})

    reg("builtin_interfaces/msg/Time", "int32 sec\nuint32 nanosec")
    reg("service_msgs/msg/ServiceEventInfo", SERVICE_EVENT_INFO)
    for name, (req, resp) in SERVICES.items():
        reg(name + "_Request", req)
        reg(name + "_Response", resp)
        reg(
            name + "_Event",
            f"service_msgs/ServiceEventInfo info\n{name}_Request[<=1] request\n{name}_Response[<=1] response",
        )
        reg(
            name,
            f"{name}_Request request_message\n{name}_Response response_message\n{name}_Event event_message",
        )
    return ts, srv


TS, SRV = typestores()


def build(ts, typename, value):
    """A rosbags message of `typename` from plain JSON values."""
    cls = ts.types[typename]
    fields = ts.fielddefs[typename][1]
    args = {}
    for fname, desc in fields:
        v = value[fname]
        kind, rest = desc
        if kind == 2:  # a nested message
            args[fname] = build(ts, rest, v)
        elif kind == 4 and rest[0][0] == 2:  # a sequence of messages
            args[fname] = [build(ts, rest[0][1], i) for i in v]
        else:
            args[fname] = v
    return cls(**args)


def plain(ts, msg):
    """A rosbags message as plain values (its fields, not its constants)."""
    if hasattr(msg, "__msgtype__"):
        names = [f for f, _ in ts.fielddefs[msg.__msgtype__][1]]
        return {k: plain(ts, getattr(msg, k)) for k in names}
    if isinstance(msg, list):
        return [plain(ts, i) for i in msg]
    return msg


# rmw_zenoh's names, written from its design document.
def dds_name(typename):
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def topic_key(domain, fqn, typename, typehash):
    return f"{domain}/{fqn.strip('/')}/{dds_name(typename)}/{typehash}"


def mangle(name):
    return name.replace("/", "%")


def token(domain, zid, nid, eid, kind, ns, node, topic=None, typename=None, typehash=None):
    t = f"@ros2_lv/{domain}/{zid}/{nid}/{eid}/{kind}/%/{mangle(ns)}/{node}"
    if topic is not None:
        t += f"/{mangle(topic)}/{dds_name(typename)}/{typehash}/::,:,:,:,,"
    return t


def gid(token_key):
    """XXH3-128 of the token, low 64 bits then high, little-endian."""
    return xxhash.xxh3_128_digest(token_key.encode())[::-1]


def attachment(seq, stamp_ns, g):
    return ze.z_serialize((ze.Int64(seq), ze.Int64(stamp_ns), bytes(g)))


def interfaces():
    req = json.load(sys.stdin)
    out = {"messages": {}, "services": {}}
    for m in req["messages"]:
        name = m["type"]
        ts = SRV if name in SERVICES or "/srv/" in name else TS
        entry = {"hash": ts.hash_rihs01(name)}
        if "value" in m:
            entry["cdr"] = bytes(ts.serialize_cdr(build(ts, name, m["value"]), name)).hex()
            entry["decoded"] = plain(ts, ts.deserialize_cdr(bytes.fromhex(m["cdr"]), name))
        out["messages"][name] = entry
    for name in SERVICES:
        out["services"][name] = SRV.hash_rihs01(name)
    for name in ["ControlModeCommand_Request", "ControlModeCommand_Response"]:
        full = "autoware_vehicle_msgs/srv/" + name
        v = req["service_values"][name]
        out["messages"][full] = {
            "cdr": bytes(SRV.serialize_cdr(build(SRV, full, v), full)).hex()
        }
    a = req["attachment"]
    out["attachment"] = attachment(a["seq"], a["stamp"], bytes.fromhex(a["gid"])).to_bytes().hex()
    out["gid"] = gid(req["token"]).hex()
    out["keys"] = {
        k["topic"]: topic_key(k["domain"], k["topic"], k["type"], TS.hash_rihs01(k["type"]))
        for k in req["keys"]
    }
    json.dump(out, sys.stdout)


class Peer:
    """A ROS 2 node on Zenoh: its session, its tokens, what it hears."""

    def __init__(self, endpoints, node="planner", domain=0):
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps(endpoints))
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.s = zenoh.open(conf)
        self.zid = str(self.s.zid())
        self.domain = domain
        self.node = node
        self.eid = 0
        self.keep = []
        self.lock = threading.Lock()
        self.latest = {}
        self.keep.append(self.s.liveliness().declare_token(token(domain, self.zid, 0, 0, "NN", "/", node)))

    def _announce(self, kind, topic, typename, typehash):
        self.eid += 1
        t = token(self.domain, self.zid, 0, self.eid, kind, "/", self.node, topic, typename, typehash)
        self.keep.append(self.s.liveliness().declare_token(t))
        return topic_key(self.domain, topic, typename, typehash), gid(t)

    def subscribe(self, topic, typename):
        key, _ = self._announce("MS", topic, typename, TS.hash_rihs01(typename))

        def heard(sample):
            msg = TS.deserialize_cdr(sample.payload.to_bytes(), typename)
            with self.lock:
                self.latest[topic] = msg

        self.keep.append(self.s.declare_subscriber(key, heard))

    def get(self, topic):
        with self.lock:
            return self.latest.get(topic)

    def publisher(self, topic, typename):
        key, g = self._announce("MP", topic, typename, TS.hash_rihs01(typename))
        pub = self.s.declare_publisher(key)
        self.keep.append(pub)
        state = {"seq": 0}

        def put(msg):
            state["seq"] += 1
            pub.put(
                bytes(TS.serialize_cdr(msg, typename)),
                attachment=attachment(state["seq"], time.time_ns(), g),
            )

        return put

    def call_control_mode(self, ns, mode):
        name = "autoware_vehicle_msgs/srv/ControlModeCommand"
        key, g = self._announce("SC", f"{ns}/control/control_mode_request", name, SRV.hash_rihs01(name))
        req = SRV.types[name + "_Request"](stamp=stamp(), mode=mode)
        payload = bytes(SRV.serialize_cdr(req, name + "_Request"))
        for reply in self.s.get(
            key,
            payload=payload,
            attachment=attachment(1, time.time_ns(), g),
            target=zenoh.QueryTarget.ALL_COMPLETE,
            timeout=5.0,
        ):
            if reply.ok is None:
                continue
            att = reply.ok.attachment.to_bytes()
            assert att[17:] == g, "the reply carries the client's GID"
            return SRV.deserialize_cdr(reply.ok.payload.to_bytes(), name + "_Response").success
        return None


def stamp():
    ns = time.time_ns()
    return TS.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def say(*words):
    print(*words, flush=True)


def wait_for(what, cond, deadline=30.0):
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        if cond():
            say("ok", what)
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


REPORTS = {
    "vehicle/status/steering_status": "autoware_vehicle_msgs/msg/SteeringReport",
    "vehicle/status/velocity_status": "autoware_vehicle_msgs/msg/VelocityReport",
    "vehicle/status/gear_status": "autoware_vehicle_msgs/msg/GearReport",
    "vehicle/status/control_mode": "autoware_vehicle_msgs/msg/ControlModeReport",
}
AUTONOMOUS, MANUAL = 1, 4
DRIVE = 2


class Driver:
    """Publishes actuation and gear commands for one vehicle at 20 Hz while on."""

    def __init__(self, peer, ns):
        self.actuation = peer.publisher(f"{ns}/control/command/actuation_cmd", "tier4_vehicle_msgs/msg/ActuationCommandStamped")
        self.gear = peer.publisher(f"{ns}/control/command/gear_cmd", "autoware_vehicle_msgs/msg/GearCommand")
        self.on = threading.Event()
        self.cmd = (0.0, 1.0, 0.0)
        # A stamp to repeat, as a planner that hangs but keeps publishing would.
        self.frozen = None
        threading.Thread(target=self._run, daemon=True).start()

    def send(self, cmd):
        """One actuation command and the gear command."""
        T = TS.types
        accel, brake, steer = cmd
        self.actuation(
            T["tier4_vehicle_msgs/msg/ActuationCommandStamped"](
                header=T["std_msgs/msg/Header"](stamp=self.frozen or stamp(), frame_id=""),
                actuation=T["tier4_vehicle_msgs/msg/ActuationCommand"](
                    accel_cmd=accel, brake_cmd=brake, steer_cmd=steer
                ),
            )
        )
        self.gear(T["autoware_vehicle_msgs/msg/GearCommand"](stamp=stamp(), command=DRIVE))

    def _run(self):
        while True:
            if self.on.is_set():
                self.send(self.cmd)
            time.sleep(0.05)


def listen_reports(peer, ns):
    for topic, typename in REPORTS.items():
        peer.subscribe(f"{ns}/{topic}", typename)

    def r(topic):
        return peer.get(f"{ns}/{topic}")

    return r


def engage(peer, ns):
    end = time.monotonic() + 30
    while time.monotonic() < end:
        ok = peer.call_control_mode(ns, AUTONOMOUS)
        if ok:
            say("ok engaged", ns)
            return
        time.sleep(0.2)
    raise AssertionError(f"{ns} would not engage")


def drive_one(peer, ns, tire_angle_per_unit):
    r = listen_reports(peer, ns)
    wait_for("reports", lambda: all(r(t) is not None for t in REPORTS))
    say("steering", r("vehicle/status/steering_status").steering_tire_angle)
    assert r("vehicle/status/control_mode").mode != AUTONOMOUS
    d = Driver(peer, ns)
    # One command before engaging: refused (the test reads it counted by reason).
    d.send((0.0, 1.0, 0.0))
    d.cmd = (0.0, 1.0, 0.0)
    d.on.set()
    engage(peer, ns)
    # As Autoware does: shift while the brake holds, then drive once the gear is in.
    d.cmd = (0.0, 1.0, 0.3)
    wait_for("gear drive", lambda: r("vehicle/status/gear_status").report == DRIVE)
    d.cmd = (0.4, 0.0, 0.3)
    want = 0.3 * tire_angle_per_unit
    wait_for(
        f"steering at {want:.3f} rad",
        lambda: abs(r("vehicle/status/steering_status").steering_tire_angle - want) < 0.02,
    )
    wait_for("moving", lambda: r("vehicle/status/velocity_status").longitudinal_velocity > 0.3)
    assert r("vehicle/status/control_mode").mode == AUTONOMOUS
    return d, r


def drive(endpoint, ns, tire):
    peer = Peer([endpoint])
    diag = f"{ns}/diagnostics"
    peer.subscribe(diag, "diagnostic_msgs/msg/DiagnosticArray")
    emergency = peer.publisher(
        f"{ns}/control/command/emergency_cmd", "tier4_vehicle_msgs/msg/VehicleEmergencyStamped"
    )
    d, r = drive_one(peer, ns, float(tire))
    devices = {"adrive: steer", "adrive: gas", "adrive: brake", "adrive: trans"}
    wait_for(
        "diagnostics of every device",
        lambda: peer.get(diag) is not None and devices <= {s.name for s in peer.get(diag).status},
    )
    # Stop publishing: the watchdog must stop the vehicle.
    d.on.clear()
    say("stopped publishing")
    wait_for("disengaged", lambda: r("vehicle/status/control_mode").mode != AUTONOMOUS, 10)
    wait_for("stopped", lambda: abs(r("vehicle/status/velocity_status").longitudinal_velocity) < 0.01, 20)
    # Publish again, engage, drive; the emergency command must stop her while the
    # actuation stream still asks for gas.
    d.cmd = (0.0, 1.0, 0.0)
    d.on.set()
    engage(peer, ns)
    d.cmd = (0.4, 0.0, 0.0)
    wait_for("moving again", lambda: r("vehicle/status/velocity_status").longitudinal_velocity > 0.3)
    emergency(TS.types["tier4_vehicle_msgs/msg/VehicleEmergencyStamped"](stamp=stamp(), emergency=True))
    say("emergency")
    wait_for("disengaged by the emergency", lambda: r("vehicle/status/control_mode").mode != AUTONOMOUS, 10)
    wait_for("stopped again", lambda: abs(r("vehicle/status/velocity_status").longitudinal_velocity) < 0.01, 20)
    # Engage and drive once more; a stream whose stamp stops advancing is stale: the
    # watchdog stops her although messages keep coming.
    engage(peer, ns)
    wait_for("moving once more", lambda: r("vehicle/status/velocity_status").longitudinal_velocity > 0.3)
    d.frozen = stamp()
    say("stamp frozen")
    wait_for("disengaged on the stale stream", lambda: r("vehicle/status/control_mode").mode != AUTONOMOUS, 10)
    wait_for("stopped a third time", lambda: abs(r("vehicle/status/velocity_status").longitudinal_velocity) < 0.01, 20)
    d.on.clear()
    say("PASS")


def two(ep_a, ns_a, ep_b, ns_b, tire):
    peer = Peer([ep_a, ep_b])
    ra = listen_reports(peer, ns_a)
    wait_for(f"reports of {ns_a}", lambda: all(ra(t) is not None for t in REPORTS))
    d, rb = drive_one(peer, ns_b, float(tire))
    a_mode = ra("vehicle/status/control_mode").mode
    a_steer = ra("vehicle/status/steering_status").steering_tire_angle
    a_speed = ra("vehicle/status/velocity_status").longitudinal_velocity
    say("a", a_mode, a_steer, a_speed)
    assert a_mode != AUTONOMOUS, f"{ns_a} engaged"
    assert abs(a_steer) < 1e-6 and abs(a_speed) < 1e-6, f"{ns_a} moved"
    # The sentinel: a request to A, answered through A's own intake, after every
    # command sent to B.
    ok = peer.call_control_mode(ns_a, MANUAL)
    assert ok, f"{ns_a} did not answer the sentinel"
    d.on.clear()
    say("PASS")


def main():
    try:
        cmd = sys.argv[1]
        if cmd == "interfaces":
            interfaces()
        elif cmd == "drive":
            drive(*sys.argv[2:5])
        elif cmd == "two":
            two(*sys.argv[2:7])
        else:
            raise SystemExit(f"unknown command {cmd}")
        code = 0
    except AssertionError as e:
        say("FAIL:", e)
        code = 1
    sys.stdout.flush()
    # Zenoh's threads may hold the interpreter; the work is done.
    os._exit(code)


if __name__ == "__main__":
    main()

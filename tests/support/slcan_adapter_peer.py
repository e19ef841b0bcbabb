"""A strict SLCAN (Lawicel) adapter with an OSCC kit behind it, on a pseudo-terminal,
for adrive to drive: every frame adrive sends is decoded by cantools against the DBC.

    slcan_adapter_peer.py DBC SAFE_JSON

SAFE_JSON names each module's safe command ({"BRAKE": 1.0, ...}). The adapter starts
healthy on a healthy bus; "MODE refuse" on standard input puts the bus in error: the
adapter passes nothing on from the bus, refuses every frame with BEL and its status
flags say "bus error" (0x80); "MODE strict" heals it.

Standard output, one JSON object a line: first {"port": PATH} (the end adrive opens),
then {"frame": ...} for each frame adrive sends, {"status": N} for the Nth status
request, {"marked": NAME} for each "MARK NAME" and {"mode": MODE} for each "MODE MODE"
read on standard input (a mark is the instant before the test asks adrive something),
and after "END" there, {"verdict": ...}: what adrive did, per module and relative to
the marks, for the test to judge.

The adapter answers as a real one does: CR for a command it takes, BEL for one it
refuses (closing a closed channel, a frame while closed, anything unknown); `z` CR for
each frame taken for transmission. The kit's modules report at 50 Hz with `enabled`
following the ENABLE and DISABLE frames, as OSCC's firmware does, and the car reports
its wheel speeds (0), steering wheel angle and brake pressure.
"""

import json
import os
import sys
import threading
import time
import tty

import cantools

DBC, SAFE = sys.argv[1], json.loads(sys.argv[2])
MODULES = sorted(SAFE)
REPORT_EVERY = 0.020
db = cantools.database.load_file(DBC)
out_lock = threading.Lock()


def emit(obj):
    with out_lock:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


master, slave = os.openpty()
tty.setraw(master)
tty.setraw(slave)
# The slave stays open here too, so adrive closing and reopening it never hangs up
# the master.
emit({"port": os.ttyname(slave)})

state = {
    "mode": "strict",
    "open": False,
    "bitrate": None,
    "enabled": {m: 0 for m in MODULES},
}
frames = []  # (t, module, kind, value) of every frame adrive sent
marks = {}
problems = []  # the adapter protocol broken, or a frame the DBC does not describe
names = {}
statuses = [0]
refused = [0]
stop = threading.Event()
END_LINE = b"#END\r"  # never an SLCAN command: the end of what adrive wrote


def now():
    return time.monotonic()


def reader():
    for line in sys.stdin:
        word = line.split()
        if word[:1] == ["MARK"]:
            marks[word[1]] = now()
            emit({"marked": word[1]})
        elif word[:1] == ["MODE"] and word[1] in ("strict", "refuse"):
            state["mode"] = word[1]
            emit({"mode": word[1]})
        elif word[:1] == ["END"]:
            # The barrier: a line of our own written into the port behind everything
            # adrive wrote (it has exited by now), so that the judgement waits until the
            # reading thread has taken every byte before it.
            os.write(slave, END_LINE)
            return
    stop.set()


threading.Thread(target=reader, daemon=True).start()


def problem(what):
    if len(problems) < 50:
        problems.append(what)


def on_frame(line, t, taken):
    """A `t` frame from adrive: decode, check, note, follow the kit."""
    try:
        ident = int(line[1:4], 16)
        dlc = int(line[4:5], 16)
        data = bytes.fromhex(line[5:].decode())
    except ValueError:
        problem(f"not a frame: {line!r}")
        return
    if len(data) != dlc:
        problem(f"length {dlc} but {len(data)} bytes: {line!r}")
        return
    try:
        message = db.get_message_by_frame_id(ident)
    except KeyError:
        problem(f"0x{ident:03X} is no message of the DBC: {line!r}")
        return
    if dlc != message.length:
        problem(f"{message.name}: {dlc} bytes, the DBC says {message.length}")
    try:
        signals = message.decode(data, decode_choices=False)
    except Exception as e:  # cantools names what is wrong
        problem(f"{message.name}: cantools cannot decode {data.hex()}: {e}")
        return
    if signals.get("magic_0") != 5 or signals.get("magic_1") != 204:
        problem(f"{message.name}: magic bytes {data[:2].hex()}, not 05cc")
    module, _, kind = message.name.partition("_")
    if module not in SAFE or kind not in ("COMMAND", "ENABLE", "DISABLE"):
        problem(f"{message.name}: not a message the controller sends")
        return
    # Reserved bytes of OSCC's structures stay zero.
    used = 6 if kind == "COMMAND" else 2
    if any(data[used:]):
        problem(f"{message.name}: reserved bytes not zero: {data.hex()}")
    value = None
    if kind == "COMMAND":
        (value,) = [v for k, v in signals.items() if not k.startswith("magic")]
    names[message.name] = names.get(message.name, 0) + 1
    frames.append((t, module, kind, value))
    emit({"frame": message.name, "module": module, "kind": kind, "value": value, "taken": taken})
    if taken:
        if kind == "ENABLE":
            state["enabled"][module] = 1
        elif kind == "DISABLE":
            state["enabled"][module] = 0


def answer(line, t):
    """The adapter's answer to one line from adrive (without its CR)."""
    ok, bel = b"\r", b"\x07"
    if not line:
        return ok
    c = line[:1]
    if c == b"C":
        if state["open"]:
            state["open"] = False
            return ok
        return bel
    if c == b"S" and len(line) == 2 and line[1:] in b"012345678":
        if state["open"]:
            problem("bitrate set while open")
            return bel
        state["bitrate"] = int(line[1:])
        return ok
    if c == b"Z" and line[1:] in (b"0", b"1"):
        return ok
    if c == b"O":
        if state["open"] or state["bitrate"] is None:
            problem("open while open or before a bitrate")
            return bel
        if state["bitrate"] != 6:
            problem(f"bitrate S{state['bitrate']}, OSCC's bus is S6 (500 kbit/s)")
        state["open"] = True
        return ok
    if c == b"F":
        statuses[0] += 1
        emit({"status": statuses[0]})
        return b"F80\r" if state["mode"] == "refuse" else b"F00\r"
    if c == b"t":
        if not state["open"]:
            problem(f"a frame while the channel is closed: {line!r}")
            return bel
        taken = state["mode"] == "strict"
        on_frame(line, t, taken)
        if not taken:
            refused[0] += 1
            return bel
        return b"z\r"
    problem(f"not an SLCAN command: {line!r}")
    return bel


def report(message, values):
    m = db.get_message_by_name(message)
    data = m.encode(values)
    return b"t%03X%d%s\r" % (m.frame_id, len(data), data.hex().upper().encode())


def reports():
    kit = {"BRAKE": "BRAKE_REPORT", "STEERING": "STEERING_REPORT", "THROTTLE": "THROTTLE_REPORT"}
    out = b""
    for module in MODULES:
        out += report(
            kit[module],
            {
                "magic_0": 5,
                "magic_1": 204,
                "enabled": state["enabled"][module],
                "operator_override": 0,
                "dtcs": 0,
            },
        )
    out += report(
        "KIA_SOUL_WHEEL_SPEED",
        {
            "wheel_speed_front_left": 0,
            "wheel_speed_front_right": 0,
            "wheel_speed_rear_left": 0,
            "wheel_speed_rear_right": 0,
        },
    )
    out += report("KIA_SOUL_STEERING_WHEEL_ANGLE", {"steering_wheel_angle": 0})
    out += report("KIA_SOUL_BRAKE_PRESSURE", {"master_cylinder_pressure": 0})
    return out


write_lock = threading.Lock()
report_gaps = [0.0]


def write(data):
    with write_lock:
        while data:
            n = os.write(master, data)
            data = data[n:]


def report_loop():
    """The kit's reports every 20 ms, on their own thread: a host slow to read never
    delays them, as on a real bus."""
    last = None
    tick = now()
    while not stop.is_set():
        tick += REPORT_EVERY
        time.sleep(max(0.0, tick - now()))
        if now() > tick + REPORT_EVERY:
            tick = now()
        # A bus in error hears nothing; a closed channel passes nothing on.
        if state["open"] and state["mode"] == "strict":
            write(reports())
            t = now()
            if last is not None:
                report_gaps[0] = max(report_gaps[0], t - last)
            last = t
        else:
            last = None


def read_loop():
    """Every line adrive writes, answered in order."""
    pending = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:
            return
        t = now()
        pending += chunk
        reply = b""
        while True:
            # A line ends at CR (LF tolerated, never sent by adrive).
            cut = [i for i in (pending.find(b"\r"), pending.find(b"\n")) if i >= 0]
            if not cut:
                break
            i = min(cut)
            line, pending = pending[:i], pending[i + 1 :]
            if line + b"\r" == END_LINE:
                stop.set()
                return
            reply += answer(line, t)
        if reply:
            write(reply)


threading.Thread(target=read_loop, daemon=True).start()
threading.Thread(target=report_loop, daemon=True).start()
stop.wait()


def ms(seconds):
    return round(seconds * 1000.0, 3)


def near(a, b):
    return a is not None and abs(a - b) <= 1e-6


def judge():
    engage = marks.get("engage")
    disengage = marks.get("disengage")
    verdict = {
        "problems": problems,
        "names": names,
        "statuses": statuses[0],
        "refused": refused[0],
        "report_gap_max_ms": ms(report_gaps[0]),
        # Each module's frames of each kind from each mark on.
        "after": {
            mark: {m: {k: sum(1 for f in frames if f[0] >= t and f[1] == m and f[2] == k) for k in ("COMMAND", "ENABLE", "DISABLE")} for m in MODULES}
            for mark, t in marks.items()
        },
        "marks": sorted(marks),
        "modules": {},
    }
    for m in MODULES:
        safe = SAFE[m]
        mine = [f for f in frames if f[1] == m]
        v = {"frames": len(mine), "last": mine[-1][2] if mine else None}
        verdict["modules"][m] = v
        enables = [f for f in mine if f[2] == "ENABLE"]
        v["enables"] = len(enables)
        if engage is None:
            continue
        # Before the engage: safe commands only, each followed by the disable message.
        before = [f for f in mine if f[0] < engage]
        v["commands_before_engage"] = sum(1 for f in before if f[2] == "COMMAND")
        v["unsafe_before_engage"] = [f[3] for f in before if f[2] == "COMMAND" and not near(f[3], safe)]
        v["enables_before_engage"] = sum(1 for f in before if f[2] == "ENABLE")
        v["commands_without_disable_before_engage"] = sum(
            1
            for i, f in enumerate(mine)
            if f[0] < engage and f[2] == "COMMAND" and (i + 1 == len(mine) or mine[i + 1][2] != "DISABLE")
        )
        # Engage: a safe command after the request, then the enable message.
        end = disengage if disengage is not None else float("inf")
        after = [f for f in mine if engage <= f[0] < end]
        first = next((i for i, f in enumerate(after) if f[2] == "ENABLE"), None)
        if first is None:
            v["enable_after_engage_ms"] = None
            continue
        v["enable_after_engage_ms"] = ms(after[first][0] - engage)
        lead = after[:first]
        v["safe_command_before_enable"] = any(f[2] == "COMMAND" and near(f[3], safe) for f in lead)
        v["unsafe_before_enable"] = [f[3] for f in lead if f[2] == "COMMAND" and not near(f[3], safe)]
        # Engaged: commands at the resend rate, no disable, the set points on the wire.
        engaged = after[first:]
        v["disables_while_engaged"] = sum(1 for f in engaged if f[2] == "DISABLE")
        v["enables_while_engaged"] = sum(1 for f in engaged if f[2] == "ENABLE")
        times = [f[0] for f in engaged if f[2] == "COMMAND"]
        gaps = sorted(b - a for a, b in zip(times, times[1:]))
        if disengage is not None and times:
            gaps.append(disengage - times[-1])  # the last command before the disengage
            gaps.sort()
        v["commands_while_engaged"] = len(times)
        v["gap_p50_ms"] = ms(gaps[len(gaps) // 2]) if gaps else None
        v["gap_max_ms"] = ms(gaps[-1]) if gaps else None
        v["values_while_engaged"] = sorted({round(f[3], 6) for f in engaged if f[2] == "COMMAND"})
        if disengage is None:
            continue
        # Disengage: the safe command, then the disable message; the last word is the
        # disable message; every command from then on is safe and followed by it.
        later = [f for f in mine if f[0] >= disengage]
        v["frames_after_disengage"] = len(later)
        v["enables_after_disengage"] = sum(1 for f in later if f[2] == "ENABLE")
        safe_at = next((i for i, f in enumerate(later) if f[2] == "COMMAND" and near(f[3], safe)), None)
        v["disable_after_safe_command"] = safe_at is not None and any(
            f[2] == "DISABLE" for f in later[safe_at + 1 :]
        )
        if safe_at is not None:
            v["disable_after_disengage_ms"] = next(
                (ms(f[0] - disengage) for f in later[safe_at + 1 :] if f[2] == "DISABLE"), None
            )
        first_disable = next((i for i, f in enumerate(later) if f[2] == "DISABLE"), len(later))
        settled = later[first_disable:]
        v["unsafe_after_disable"] = [f[3] for f in settled if f[2] == "COMMAND" and not near(f[3], safe)]
        v["commands_without_disable_after_disengage"] = sum(
            1
            for i, f in enumerate(settled)
            if f[2] == "COMMAND" and (i + 1 == len(settled) or settled[i + 1][2] != "DISABLE")
        )
    return verdict


emit({"verdict": judge()})

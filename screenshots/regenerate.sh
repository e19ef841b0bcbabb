#!/usr/bin/env bash
# Regenerate the console screenshots from a real `adrive --sim` run.
#
#   screenshots/regenerate.sh          every screen
#   screenshots/regenerate.sh alice    Alice's screens only
#   screenshots/regenerate.sh many     the many-devices screen only
#   screenshots/regenerate.sh cart     the cart's screen only
#   screenshots/regenerate.sh oscc     the OSCC kit's screens only
#   screenshots/regenerate.sh characterize   the bench's characterization only
#
# Needs tmux and python3 (with venv). It builds adrive (release, as the README runs it), runs it with --sim in a
# detached 80×24 tmux session, drives it with keys, and saves for each screen:
#   NAME.ansi  the screen with colour escapes (tmux capture-pane -p -e)
#   NAME.txt   the same capture, escapes removed
#   NAME.png   the .ansi rendered by render.py (Pillow, installed into a venv under
#              target/screenshots-venv on first use)
# Screens: main (engaged, steering commanded to 0.5), attach (a second console attached
# to that run with `adrive attach`, watching), help, teleop (in drive, `↑` held as
# tmux passes a key repeat: the bar's `repeat` mode), bench (gas, with its raw
# traffic, delay histogram and the simulator's fault keys), recovery and
# recovery-wide (an engine stall injected from the bench while in drive, captured while
# the supervisor's engine_stall procedure runs, at 80×24 and at 120×40), fault
# (steering silenced with the bench's sim key: the supervisor's silent fault in red); many (the tractor's 32
# devices, vehicles/tractor.toml, engaged with a few commanded, and the name prompt
# open); cart (vehicles/cart.toml, engaged, in forward, steering and a turn signal
# commanded); oscc and oscc-bench (vehicles/oscc.toml: the OSCC kit's modules on a CAN
# bus, engaged with a little steering torque; then the steering's bench at 100×30, the
# bus's frames decoded by the DBC); characterize and characterize-done (the steering's
# bench measuring it with `M`, under way and done, its files written under the run's
# temporary directory).
set -euo pipefail
cd "$(dirname "$0")/.."
what=${1:-all}
case "$what" in
    all | alice | many | cart | oscc | characterize) ;;
    *)
        echo "usage: $0 [alice|many|cart|oscc|characterize]" >&2
        exit 2
        ;;
esac
out=screenshots
session=adrive-shots-$$
logs=$(mktemp -d)
trap 'tmux kill-session -t "$session" 2>/dev/null || true; rm -rf "$logs"' EXIT

cargo build --release --quiet
venv=target/screenshots-venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import PIL' 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet pillow
fi

# Start adrive --sim (with these arguments) in the 80×24 session, once the last one
# ended.
start() {
    while tmux has-session -t "$session" 2>/dev/null; do sleep 0.1; done
    tmux new-session -d -s "$session" -x 80 -y 24 -c "$logs" \
        "env TERM=xterm-256color $PWD/target/release/adrive --sim --listen 127.0.0.1:0 --log-dir $logs --socket $logs/adrive.sock $*"
}

# Wait until the screen shows $1 ($2 tenths of a second at most, default 20 s).
wait_for() {
    for _ in $(seq "${2:-200}"); do
        if tmux capture-pane -p -t "$session" | grep -qF -- "$1"; then return 0; fi
        sleep 0.1
    done
    echo "timed out waiting for: $1" >&2
    tmux capture-pane -p -t "$session" >&2
    return 1
}
keys() { tmux send-keys -t "$session" "$@"; }
# Esc alone: the console reads an Esc followed at once by a key as that key with Alt, as
# a terminal sends it; the next key waits until the Esc was taken alone.
esc() { keys Escape; sleep 0.3; }
shot() {
    # One capture, so the text and the colours show the same instant.
    tmux capture-pane -p -e -t "$session" >"$out/$1.ansi"
    sed 's/\x1b\[[0-9;]*m//g' "$out/$1.ansi" >"$out/$1.txt"
    "$venv/bin/python" "$out/render.py" "$out/$1.ansi" "$out/$1.png"
    echo "wrote $out/$1.{txt,ansi,png}"
}

# Wait until the screen no longer shows $1 ($2 tenths of a second at most, default 20 s).
wait_gone() {
    for _ in $(seq "${2:-200}"); do
        if ! tmux capture-pane -p -t "$session" | grep -qF -- "$1"; then return 0; fi
        sleep 0.1
    done
    echo "timed out waiting for this to go: $1" >&2
    tmux capture-pane -p -t "$session" >&2
    return 1
}

# Engage once every device has reported: a device that has not shows its status age as
# "never", and an engage asked for before then is refused with a warning that would
# stay in the log pane of every screen taken after it. Should one be refused anyway
# (a device shown nowhere on the screen), it is asked again.
engage() {
    wait_gone "never"
    for _ in $(seq 50); do
        keys E; wait_for "Engage?"; keys y
        sleep 0.3
        if tmux capture-pane -p -t "$session" | grep -qF "│ ENGAGED"; then break; fi
        sleep 0.3
    done
    wait_for "│ ENGAGED"
}

alice() {
    start
    wait_for "OBD"
    engage
    keys s; wait_for "edit steer command"
    keys 0.5 Enter
    wait_for "meas 0.500"
    sleep 1
    shot main

    # A second console attached to this one's engine, watching.
    tmux new-session -d -s "$session-attach" -x 80 -y 24 \
        "env TERM=xterm-256color target/release/adrive attach --socket $logs/adrive.sock"
    main=$session
    session=$session-attach
    wait_for "WATCHING"; wait_for "meas 0.500"
    sleep 1
    shot attach
    keys q
    session=$main

    keys '?'; wait_for "keys from the loaded keymap"
    shot help
    esc

    keys l x; wait_for "GAS 0…1"; wait_for "raw traffic"
    sleep 1
    shot bench
    esc

    # In drive, stall the engine from the bench, then watch the supervisor recover it.
    keys t; wait_for "edit trans command"
    keys C-u d Enter
    wait_for "state drive"

    # Teleop in drive, `↑` held: tmux passes presses only, so the bar says `repeat`,
    # with the bound learnt from a first hold (a 300 ms delay, then a repeat every
    # 30 ms); captured while the second hold lasts.
    keys d; wait_for "TELEOP repeat"
    hold_up() { keys Up; sleep 0.3; for _ in $(seq "$1"); do keys Up; sleep 0.03; done; }
    hold_up 20
    sleep 0.4
    hold_up 40 &
    wait_for "held ↑" 20
    sleep 0.3
    shot teleop
    wait
    wait_for "the hold brake"
    keys Escape; wait_for "left teleop"

    keys x; wait_for "raw traffic"
    keys K; wait_for "sim: engine stalled"
    esc
    wait_for "RECOVERY engine_stall" 50
    sleep 0.2
    shot recovery
    tmux resize-window -t "$session" -x 120 -y 40
    wait_for "  try 1/3  " 20
    shot recovery-wide
    wait_for "recovery engine_stall done" 100
    tmux resize-window -t "$session" -x 80 -y 24
    sleep 0.5

    # Silence the simulated steering from the bench, then look at the main screen.
    keys x; wait_for "raw traffic"
    for _ in $(seq 6); do
        if tmux capture-pane -p -t "$session" | grep -qF "steer raw traffic"; then break; fi
        keys BTab; sleep 0.3
    done
    wait_for "steer raw traffic"
    keys s; wait_for "FAULT steer"
    keys Escape; wait_for "FAULT steer silent"
    sleep 1
    shot fault

    keys q
}

# The tractor: a row for each of its 32 devices. A few devices commanded from the
# name prompt, then the prompt open on the hydraulics.
many() {
    start --config $PWD/vehicles/tractor.toml
    wait_for "tyre_press"
    engage
    # Find device $2 by typing $1, then command it $3.
    command() {
        keys /; keys -l "$1"; keys Enter; wait_for "${2^^} "
        keys Enter; wait_for "edit $2 command"
        keys C-u; keys -l "$3"; keys Enter; wait_for "$2 ← "
    }
    command wip wiper 0.5
    command hit hitch 40
    command sig turn_signal left
    command head headlights low
    command beac beacon on
    command load loader_arm 0.3
    sleep 1.5
    keys /; keys -l hyd; wait_for "HYDRAULICS"
    sleep 0.5
    shot many
    # Esc, then q once the prompt is gone (sent together they read as Alt-q).
    keys Escape; wait_for "/ find device"
    keys q
}

# The cart: its own devices under their own names, the keys' hints naming them.
cart() {
    start --config $PWD/vehicles/cart.toml
    wait_for "battery"
    engage
    keys t; wait_for "edit direction command"
    keys C-u f Enter; wait_for "direction ← "
    keys s; wait_for "edit steer command"
    keys C-u; keys -l -- "-0.3"; keys Enter; wait_for "meas -0.300"
    keys /; keys -l sig; keys Enter; wait_for "SIGNALS "
    keys Enter; wait_for "edit signals command"
    keys C-u; keys -l left; keys Enter; wait_for "signals ← "
    sleep 1.5
    shot cart
    keys q
}

# The OSCC kit on its CAN bus: the modules on the main screen, enabled by the engage,
# the steering given a little torque; then the steering's bench, the bus decoded.
oscc() {
    start --config $PWD/vehicles/oscc.toml
    wait_for "CAR"
    engage
    wait_for "enabled 1"
    keys s; wait_for "edit steer command"
    keys C-u; keys -l 0.3; keys Enter
    wait_for "angle 162"
    sleep 1
    shot oscc
    tmux resize-window -t "$session" -x 100 -y 30
    keys x; wait_for "bus kit"
    sleep 1.5
    shot oscc-bench
    tmux resize-window -t "$session" -x 80 -y 24
    keys Escape; wait_for "CAR"
    keys q
}

# The steering measured from its bench: asked, under way beside its chart, then done
# with its figures (written into the run's directory, removed with it).
characterize() {
    start
    wait_for "OBD"
    wait_gone "never"
    keys x; wait_for "raw traffic"
    for _ in $(seq 6); do
        if tmux capture-pane -p -t "$session" | grep -qF "steer raw traffic"; then break; fi
        keys BTab; sleep 0.3
    done
    wait_for "steer raw traffic"
    keys M; wait_for "y yes"
    keys y; wait_for "· step "
    wait_for "· step 9 " 300
    shot characterize
    wait_for "characterize steer: done" 900
    wait_for "settle"
    sleep 0.5
    shot characterize-done
    keys q
}

case "$what" in
    alice) alice ;;
    many) many ;;
    cart) cart ;;
    oscc) oscc ;;
    characterize) characterize ;;
    all) alice; many; cart; oscc; characterize ;;
esac

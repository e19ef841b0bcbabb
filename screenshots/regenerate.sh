#!/usr/bin/env bash
# Regenerate the console screenshots from a real `adrive --sim` run.
#
#   screenshots/regenerate.sh
#
# Needs tmux and python3 (with venv). It builds adrive (debug), runs it with --sim in a
# detached 80×24 tmux session, drives it with keys, and saves for each screen:
#   NAME.txt   the plain text (tmux capture-pane -p)
#   NAME.ansi  the same with colour escapes (capture-pane -p -e)
#   NAME.png   the .ansi rendered by render.py (Pillow, installed into a venv under
#              target/screenshots-venv on first use)
# Screens: main (engaged, steering commanded to 0.5), help, bench (gas, with its raw
# traffic and delay histogram), fault (steering silenced through the bench's sim
# fault key, shown in red).
set -euo pipefail
cd "$(dirname "$0")/.."
out=screenshots
session=adrive-shots-$$
logs=$(mktemp -d)
trap 'tmux kill-session -t "$session" 2>/dev/null || true; rm -rf "$logs"' EXIT

cargo build --quiet
venv=target/screenshots-venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import PIL' 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet pillow
fi

tmux new-session -d -s "$session" -x 80 -y 24 \
    "env TERM=xterm-256color target/debug/adrive --sim --log-dir $logs"

# Wait until the screen shows $1 (20 s at most).
wait_for() {
    for _ in $(seq 200); do
        if tmux capture-pane -p -t "$session" | grep -qF -- "$1"; then return 0; fi
        sleep 0.1
    done
    echo "timed out waiting for: $1" >&2
    tmux capture-pane -p -t "$session" >&2
    exit 1
}
keys() { tmux send-keys -t "$session" "$@"; }
shot() {
    tmux capture-pane -p -t "$session" >"$out/$1.txt"
    tmux capture-pane -p -e -t "$session" >"$out/$1.ansi"
    "$venv/bin/python" "$out/render.py" "$out/$1.ansi" "$out/$1.png"
    echo "wrote $out/$1.{txt,ansi,png}"
}

wait_for "OBD"
# Engage once every device has reported.
for _ in $(seq 50); do
    keys E; wait_for "Engage?"; keys y
    sleep 0.3
    if tmux capture-pane -p -t "$session" | grep -qF "│ ENGAGED"; then break; fi
    sleep 0.3
done
wait_for "│ ENGAGED"
keys s; wait_for "edit steer command"
keys 0.5 Enter
wait_for "meas 0.500"
sleep 1
shot main

keys '?'; wait_for "keys from the loaded keymap"
shot help
keys Escape

keys l x; wait_for "GAS 0…1"; wait_for "raw traffic"
sleep 1
shot bench

# Silence the simulated steering from the bench, then look at the main screen.
keys BTab; wait_for "steer raw traffic"
keys f; wait_for "FAULT"
keys Escape; wait_for "1 FAULTY"
sleep 1
shot fault

keys q

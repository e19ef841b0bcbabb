//! `adrive attach` (or any command that runs the console) on a terminal of its own —
//! its controlling terminal, as over SSH — at 100×30, played by a
//! [`Player`](super::terminal_player::Player): the screen rebuilt, keys typed, the
//! console engaged as an operator does.

use super::pty::Master;
use super::terminal_player::Play;
use super::{engage_answered, wait_exit, DEADLINE};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A console in a pseudo-terminal; killed on drop.
pub struct Attached {
    pub child: Child,
    pub term: Master,
}

impl Attached {
    /// Run `cmd` on a terminal that plays `play`, until its console shows every one of
    /// Alice's devices.
    pub fn spawn(cmd: &mut Command, play: Play) -> Attached {
        let a = Attached::open(cmd, play);
        a.wait_devices();
        a
    }

    /// Run `cmd` on a terminal that plays `play`, whatever it shows first.
    pub fn open(cmd: &mut Command, play: Play) -> Attached {
        cmd.env("TERM", "xterm-256color")
            .env_remove("TMUX")
            .env_remove("STY");
        let (child, term) = Master::spawn_playing(cmd, 100, 30, true, play);
        Attached { child, term }
    }

    /// Wait until the console shows every one of Alice's devices.
    pub fn wait_devices(&self) {
        self.wait_for("every device", |s| {
            ["STEER", "GAS", "BRAKE", "TRANS", "ESTOP", "OBD"]
                .iter()
                .all(|d| s.contains(d))
        });
    }

    pub fn screen(&self) -> String {
        super::screen_of(&self.term.bytes(), 100, 30)
    }

    pub fn wait_for(&self, what: &str, ok: impl Fn(&str) -> bool) -> String {
        super::wait_screen(what, Duration::from_millis(20), || self.screen(), ok)
    }

    pub fn keys(&mut self, k: &str) {
        self.term.write(k.as_bytes());
    }

    /// `E`, `y`, until engaged (the devices may not all have reported yet).
    pub fn engage(&mut self) {
        let end = Instant::now() + DEADLINE;
        loop {
            self.keys("E");
            self.wait_for("the confirmation", |s| s.contains("Engage?"));
            self.keys("y");
            // The outcome of this `y`: the frame that closed the question says it (a
            // refusal still on the screen from the last try is not it).
            let s = self.wait_for("the engage outcome", engage_answered);
            if super::engaged_said(&s) {
                self.wait_for("the header", |s| s.contains(" COMMANDING "));
                return;
            }
            assert!(Instant::now() < end, "could not engage:\n{s}");
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// `s`, the value, Enter: the steering command.
    pub fn steer(&mut self, value: &str) {
        self.keys("s");
        self.wait_for("the steering edit", |s| s.contains("edit steer command"));
        self.keys(&format!("\x15{value}\r"));
    }

    /// Wait for the program to exit; its status, once the terminal read all it wrote
    /// (its last words come after it left the screen).
    pub fn wait_exit(&mut self) -> Option<i32> {
        let status = wait_exit(&mut self.child);
        self.term.read_to_end();
        status
    }
}

impl Drop for Attached {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

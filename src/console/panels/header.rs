//! The top bar: the vehicle, the mode, interlocks, how many devices are faulty, and
//! ENGAGED or DISENGAGED with the reason — fitted to the width it gets. The gate is
//! what an operator looks for, so it is always whole: a reason too long is shortened
//! at a word, with "…" and every parenthesis it opened closed, never cut in the
//! middle (at 100 columns it once read `DISENGAGED (gas is faulty (no reply within
//! 100ms)`), and the labels that say only the normal state give way before it does
//! (`GivesWay`: at 80 columns inside tmux it read `(stop from…)` beside `interlocks
//! on`); a vehicle name too long gives way before the gate does. An attached
//! console (`adrive attach`) also says whether it commands or watches, and how its own
//! terminal's keys drive teleop (`keys hold`, `keys repeat ≤100ms`, `keys step`): the
//! operator's terminal, not the vehicle's — where that leaves the gate's words whole
//! (they come first: at 100 columns a long reason once lost its end to the keys). A console inside tmux or screen on this
//! machine says `link unchecked`: the multiplexer, not the operator's terminal, answers
//! the liveness check.

use super::fit::shorten;
use crate::console::keymap::Mode;
use crate::console::model::Model;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};
use unicode_width::UnicodeWidthStr;

/// The fewest columns a long vehicle name is shortened to (" ADRIVE " and 12 more).
const TITLE_MIN: usize = 20;

pub struct Header<'a> {
    pub m: &'a Model,
}

/// A label of the bar that gives way to the gate's reason where the reason would
/// not fit whole: first `KEYS`, then the `ADRIVE` before the vehicle's name, then
/// `interlocks on` (the normal state: `INTERLOCKS OFF` never gives way), then the mode
/// (the screen shows it); what commands, `link unchecked`, the faults and the gate
/// stay.
#[derive(Clone, Copy, PartialEq, Eq)]
enum GivesWay {
    Keys,
    Program,
    InterlocksOn,
    Mode,
}

impl Header<'_> {
    /// The bar for a screen `width` columns wide.
    pub fn line(&self, width: u16) -> Line<'static> {
        let (s, t) = (&self.m.snap, &self.m.theme);
        let bar = t.bar();
        let sep = || Span::styled("│", bar);
        let mode = match self.m.mode {
            Mode::Help | Mode::Confirm | Mode::Edit | Mode::Find => self.m.back_to,
            m => m,
        };
        // The labels after the title, in order, each with whether (and when) it gives
        // way to the reason.
        let mut parts: Vec<(Option<GivesWay>, [Span<'static>; 2])> = vec![(
            Some(GivesWay::Mode),
            [
                sep(),
                Span::styled(format!(" {} ", mode.as_str().to_uppercase()), bar),
            ],
        )];
        parts.push(if s.gate.interlocks {
            (
                Some(GivesWay::InterlocksOn),
                [sep(), Span::styled(" interlocks on ", bar)],
            )
        } else {
            (
                None,
                [
                    sep(),
                    Span::styled(" INTERLOCKS OFF ", t.fault().patch(bar)),
                ],
            )
        });
        // An attached console says whether it commands or only watches, and how its
        // terminal's keys drive.
        if let Some(you) = &s.you {
            let who = if s.gate.engaged && s.gate.commander.as_deref() == Some(you.as_str()) {
                Span::styled(" COMMANDING ", t.good().patch(bar))
            } else {
                Span::styled(" WATCHING ", bar)
            };
            parts.push((None, [sep(), who]));
            let keys = crate::console::panels::teleop::drive_label(
                self.m.drive(),
                &self.m.repeat.figures(),
                false,
            );
            parts.push((
                Some(GivesWay::Keys),
                [sep(), Span::styled(format!(" keys {keys} "), bar)],
            ));
        }
        // A multiplexer on this machine answers the liveness check's round trips for
        // the operator's terminal: the check cannot see the link (docs/console.md).
        if self.m.terminal.multiplexer.is_some() {
            parts.push((
                None,
                [sep(), Span::styled(" link unchecked ", t.warn().patch(bar))],
            ));
        }
        let faults = s.devices.iter().filter(|d| s.red(d)).count();
        if faults > 0 {
            parts.push((
                None,
                [
                    sep(),
                    Span::styled(format!(" {faults} FAULTY "), t.fault().patch(bar)),
                ],
            ));
        }
        let (gate, style) = match s.quiet {
            // An attached console whose adrive sends nothing: the gate it last said is
            // not the vehicle's now, and the operator must not read it as such.
            Some(q) => (
                format!(" NO WORD FROM ADRIVE {:.0} s ", q.as_secs_f64().floor()),
                t.fault().patch(bar),
            ),
            None if s.gate.engaged => (" ENGAGED ".to_string(), t.good().patch(bar)),
            None => (" DISENGAGED ".to_string(), t.warn().patch(bar)),
        };
        // Engaged: who commands it; disengaged: why, in the gate's own words (the
        // same the broadcast and `adrive ctl status` carry).
        let who = match &s.gate.commander {
            Some(c) => format!("by {c}"),
            None => "nobody commands".to_string(),
        };
        let why = match (s.quiet, s.gate.engaged) {
            (Some(_), true) => "last said engaged".to_string(),
            (Some(_), false) => "last said disengaged".to_string(),
            (None, true) => who,
            (None, false) => s.gate.cause.why(),
        };
        let mut title = format!(" ADRIVE {} ", s.vehicle);
        let width = width as usize;
        let reason_wants = why.width() + 2;
        // What the bar needs with the parts kept and the title at its fewest columns.
        let needs = |parts: &[(Option<GivesWay>, [Span; 2])], title: &str| {
            let labels: usize = parts
                .iter()
                .flat_map(|(_, p)| p.iter().map(Span::width))
                .sum();
            labels + "│".width() + gate.width() + reason_wants + title.width().min(TITLE_MIN)
        };
        for give in [
            GivesWay::Keys,
            GivesWay::Program,
            GivesWay::InterlocksOn,
            GivesWay::Mode,
        ] {
            if needs(&parts, &title) <= width {
                break;
            }
            match give {
                GivesWay::Program => title = format!(" {} ", s.vehicle),
                _ => parts.retain(|(g, _)| *g != Some(give)),
            }
        }
        let mut rest: Vec<Span<'static>> = parts.into_iter().flat_map(|(_, p)| p).collect();
        rest.push(sep());
        let fixed: usize = rest.iter().map(Span::width).sum::<usize>() + gate.width();
        // A long vehicle name gives way to the reason, down to TITLE_MIN columns.
        let title_room = width
            .saturating_sub(fixed + reason_wants)
            .max(title.width().min(TITLE_MIN));
        let title = shorten(&title, title_room);
        let room = width.saturating_sub(title.width() + fixed);
        // " ENGAGED " + "(by console)", " DISENGAGED " + "(" + reason + ")" (+ " " when
        // there is room): the words get what is left.
        let gate = match shorten(&why, room.saturating_sub(2)) {
            r if r.is_empty() => gate,
            r if r.width() + 2 < room => format!("{gate}({r}) "),
            r => format!("{gate}({r})"),
        };
        let mut spans = vec![Span::styled(title, t.title().patch(bar))];
        spans.extend(rest);
        spans.push(Span::styled(gate, style));
        Line::from(spans).style(bar)
    }
}

impl Widget for &Header<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        Paragraph::new(self.line(area.width)).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::console::keymap::Keymap;
    use crate::console::panels::fit::open_parens;
    use crate::console::theme::Theme;
    use crate::console::view::MIN_WIDTH;
    use crate::controls::{capture, Sources};
    use crate::snapshot::{Blocker, DisengageCause, GateCause};
    use crate::testkit;
    use std::time::{Duration, Instant};

    /// A long cause, with parentheses inside parentheses.
    fn long() -> DisengageCause {
        DisengageCause::GivingUp {
            why: "gas is faulty (no reply within 100ms); brake is faulty (garbled reply \
                  (bad CRC)); e-stop is in pause"
                .into(),
        }
    }

    fn stop(by: &str) -> DisengageCause {
        DisengageCause::Stop { by: by.into() }
    }

    fn engaged(vehicle: &str) -> Model {
        model(
            GateCause::Engaged {
                by: "console".into(),
            },
            vehicle,
        )
    }

    fn disengaged(why: DisengageCause, vehicle: &str) -> Model {
        model(GateCause::Disengaged { why }, vehicle)
    }

    fn model(cause: GateCause, vehicle: &str) -> Model {
        let now = Instant::now();
        let mut frame = capture(&testkit::gate(now), &Sources::default(), now, None);
        frame.snap.devices[1].health.faulty = true;
        frame.snap.gate.engaged = matches!(cause, GateCause::Engaged { .. });
        frame.snap.gate.reason = cause.to_string();
        frame.snap.gate.cause = cause;
        frame.snap.vehicle = vehicle.to_string();
        Model::new(
            Keymap::default_map(),
            Theme::default(),
            frame,
            Duration::from_secs(1),
        )
    }

    fn text(l: &Line) -> String {
        l.spans.iter().map(|s| s.content.as_ref()).collect()
    }

    /// Inside tmux on the vehicle, the round trip reaches tmux, not the operator: the
    /// header says the link is unchecked, and only then.
    #[test]
    fn under_a_multiplexer_the_link_is_said_to_be_unchecked() {
        let mut m = engaged("Alice");
        assert!(!text(&Header { m: &m }.line(100)).contains("link unchecked"));
        m.terminal.multiplexer = Some("tmux");
        let l = text(&Header { m: &m }.line(100));
        assert!(l.contains("│ link unchecked │"), "{l}");
        assert!(l.contains(" ENGAGED "), "{l}");
    }

    #[test]
    fn a_short_reason_is_shown_whole() {
        let m = disengaged(stop("console"), "Alice");
        let l = text(&Header { m: &m }.line(100));
        assert!(l.ends_with(" DISENGAGED (stop from console) "), "{l}");
    }

    /// At 100 columns the header once ended `DISENGAGED (gas is faulty (no reply
    /// within 100ms)`: half a reason, a parenthesis left open. At any width the gate
    /// is whole, the reason ends in "…" at a word and every parenthesis is closed.
    #[test]
    fn the_header_fits_any_width_with_the_reason_shortened_and_closed() {
        for vehicle in [
            "Alice",
            "Alice, the 2005 Grand Challenge vehicle of Team Caltech",
        ] {
            let m = disengaged(long(), vehicle);
            let reason = long().to_string();
            let reason = reason.as_str();
            // Below MIN_WIDTH the console draws no header, only the size it needs.
            for width in MIN_WIDTH..=200u16 {
                let l = text(&Header { m: &m }.line(width));
                assert!(l.width() <= width as usize, "{width}: {l}");
                assert!(l.contains(" DISENGAGED "), "{width}: {l}");
                assert_eq!(open_parens(&l), 0, "{width}: {l}");
                assert_eq!(
                    l.matches('(').count(),
                    l.matches(')').count(),
                    "{width}: {l}"
                );
                if l.contains(reason) {
                    continue;
                }
                // Shortened: at a word, or to nothing but "…".
                if let Some(r) = l.split(" DISENGAGED (").nth(1) {
                    let cut = r.trim_end_matches([')', ' ']);
                    assert!(cut.ends_with('…'), "{width}: {l}");
                    let kept = cut.trim_end_matches('…');
                    assert!(reason.starts_with(kept), "{width}: {l}");
                    let next = reason[kept.len()..].chars().next().unwrap();
                    let one_word = !kept.contains(' ');
                    assert!(
                        one_word || " (;,:".contains(next),
                        "{width}: cut inside a word: {l}"
                    );
                }
            }
        }
    }

    /// At 100 columns a device's fault once read `DISENGAGED (gas is faulty (no
    /// reply…))` beside the program's name: the name gives way first.
    #[test]
    fn at_100_columns_the_program_s_name_gives_way_to_the_reason() {
        let faulty = Blocker::Faulty {
            device: "gas".into(),
            fault: "no reply within 100ms".into(),
        };
        let mut m = disengaged(DisengageCause::Blocked { blocker: faulty }, "Alice");
        m.mode = Mode::Bench;
        let l = text(&Header { m: &m }.line(100));
        assert!(
            l.starts_with(" Alice │ BENCH │ interlocks on │ 1 FAULTY │ DISENGAGED (gas is faulty (no reply within 100ms)) "),
            "{l}"
        );
    }

    /// At 80×24, inside tmux, the gate's reason read `(e-stop is…)` while `interlocks
    /// on` and `link unchecked` kept their room, and an attached console's dropped it
    /// whole. What gives way does, in its order (the keys, `ADRIVE`, `interlocks on`,
    /// the mode), until the reason is whole; `INTERLOCKS OFF`, what commands, the link
    /// and the faults never do.
    #[test]
    fn at_80_columns_the_normal_state_s_labels_give_way_to_the_reason() {
        let estop = || DisengageCause::Blocked {
            blocker: Blocker::Estop {
                state: crate::value::EstopState::Pause,
            },
        };
        let line = |mux: bool, you: bool, interlocks: bool, width: u16| {
            let mut m = disengaged(estop(), "Alice");
            m.terminal.multiplexer = mux.then_some("tmux");
            m.snap.you = you.then(|| "console #1".to_string());
            m.snap.snap.gate.interlocks = interlocks;
            text(&Header { m: &m }.line(width))
        };
        let gate = "│ 1 FAULTY │ DISENGAGED (e-stop is in pause)";
        for (mux, you, interlocks, want) in [
            (false, false, true, " Alice │ MAIN │ interlocks on "),
            (true, false, true, " Alice │ MAIN │ link unchecked "),
            (false, true, true, " Alice │ MAIN │ WATCHING "),
            (true, true, true, " Alice │ WATCHING │ link unchecked "),
            (false, false, false, " Alice │ MAIN │ INTERLOCKS OFF "),
        ] {
            let l = line(mux, you, interlocks, 80);
            assert!(l.starts_with(&format!("{want}{gate}")), "{l}");
            assert!(l.width() <= 80, "{l}");
        }
        // Nothing left to give way: the reason is shortened, at a word.
        let l = line(true, false, false, 80);
        assert!(
            l.starts_with(
                " Alice │ INTERLOCKS OFF │ link unchecked │ 1 FAULTY │ DISENGAGED (e-stop is in…)"
            ),
            "{l}"
        );
        // Where there is room, everything.
        assert!(
            line(true, true, true, 140).starts_with(&format!(
                " ADRIVE Alice │ MAIN │ interlocks on │ WATCHING │ keys repeat ≤150ms │ link unchecked {gate}"
            )),
            "{}",
            line(true, true, true, 140)
        );
    }

    #[test]
    fn engaged_names_who_commands_and_a_long_name_gives_way() {
        let mut m = engaged("a vehicle with a name far too long for any header bar");
        m.snap.snap.gate.commander = Some("network 127.0.0.1:5555".into());
        let l = text(&Header { m: &m }.line(100));
        assert!(l.ends_with(" ENGAGED (by network 127.0.0.1:5555) "), "{l}");
        let l = text(&Header { m: &m }.line(80));
        assert!(l.contains(" ENGAGED (by network"), "{l}");
        assert!(l.starts_with(" a vehicle"), "{l}");
        assert!(l.contains('…') && l.width() <= 80, "{l}");
    }

    /// After `C` cleared a driver's override the header still read `DISENGAGED
    /// (driver override on steer)`, as if the driver still had the wheel. The header
    /// shows the gate's reason, which says the override is cleared.
    #[test]
    fn a_cleared_override_is_said_to_be_cleared() {
        let now = Instant::now();
        let gate = testkit::gate(now);
        let mut m = disengaged(stop("console"), "Alice");
        let header = |m: &mut Model| {
            m.snap.snap.gate = gate.view(Instant::now());
            text(&Header { m }.line(120))
        };
        gate.take_over("steer", "a driver's hand");
        let l = header(&mut m);
        assert!(
            l.ends_with(" DISENGAGED (driver override on steer) "),
            "{l}"
        );
        gate.clear_overrides().expect("no hand is on it");
        let l = header(&mut m);
        assert!(
            l.ends_with(" DISENGAGED (driver override on steer, cleared) "),
            "{l}"
        );
    }

    /// An attached console's header says how its own terminal's keys drive teleop:
    /// the operator's terminal, whatever the vehicle's gives.
    #[test]
    fn an_attached_console_names_how_its_own_keys_drive() {
        let mut m = engaged("Alice");
        assert!(!text(&Header { m: &m }.line(120)).contains(" keys "));
        m.snap.you = Some("console #1".into());
        let l = text(&Header { m: &m }.line(120));
        assert!(l.contains("│ WATCHING │ keys repeat ≤150ms │"), "{l}");
        m.terminal.keyboard = Some(crate::console::input::Keyboard::Releases);
        let l = text(&Header { m: &m }.line(120));
        assert!(l.contains("│ keys hold │"), "{l}");
        m.teleop.forced_step = true;
        let l = text(&Header { m: &m }.line(120));
        assert!(l.contains("│ keys step │"), "{l}");
    }

    /// The gate's words come first: where the keys would cut the reason, they give way.
    #[test]
    fn an_attached_console_s_keys_give_way_to_the_gate_s_reason() {
        let why = "stop from console #2";
        let mut m = disengaged(stop("console #2"), "Alice");
        m.snap.you = Some("console #1".into());
        let l = text(&Header { m: &m }.line(100));
        assert!(l.contains(&format!("DISENGAGED ({why})")), "{l}");
        assert!(!l.contains("keys"), "{l}");
        let l = text(&Header { m: &m }.line(130));
        assert!(
            l.contains(&format!(
                "│ WATCHING │ keys repeat ≤150ms │ 1 FAULTY │ DISENGAGED ({why})"
            )),
            "{l}"
        );
    }
}

//! The bench's characterization box: while a characterization started from the bench
//! runs, the stage it is in, its move of all those planned, the time it has taken and
//! an estimate of what is left, the keys that end it and where it writes; once it is
//! done, its headline figures and where it wrote them; ended early, why, and that
//! nothing was written. The bench draws the device's chart beside it (command and
//! measured position over the last seconds).

use super::fit::{self, Fitted};
use super::hint::key_name;
use super::wrap;
use crate::console::keymap::{Action, Keymap, Mode};
use crate::console::theme::Theme;
use crate::controls::Characterizing;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Widget};

/// The rows the box takes at most: its border and four lines.
pub(crate) const RUN_BOX: u16 = 6;

pub(crate) struct RunBox<'a> {
    pub run: &'a Characterizing,
    pub map: &'a Keymap,
    pub theme: Theme,
}

/// Seconds as `8.1 s`, or `1 min 05 s` from a minute on.
fn secs(d: std::time::Duration) -> String {
    let s = d.as_secs_f64();
    if s < 60.0 {
        format!("{s:.1} s")
    } else {
        format!("{} min {:02} s", (s / 60.0) as u64, (s % 60.0) as u64)
    }
}

impl RunBox<'_> {
    fn title(&self) -> String {
        let state = match &self.run.end {
            None => "running",
            Some(Ok(_)) => "done",
            Some(Err(_)) => "ended early",
        };
        format!(" characterize {}: {state} ", self.run.name)
    }

    /// The box's lines for `width` columns, the most important first (the first rows
    /// are what a short box keeps).
    pub(crate) fn lines(&self, width: u16) -> Vec<Line<'static>> {
        let t = &self.theme;
        let r = self.run;
        let out = r.out.display().to_string();
        let w = usize::from(width);
        match &r.end {
            None => {
                let p = &r.progress;
                let left = p.left().map_or("estimating what is left".into(), |l| {
                    format!("about {} left", secs(l))
                });
                let stop = key_name(self.map, Mode::Bench, Action::Stop);
                let back = key_name(self.map, Mode::Bench, Action::Back);
                vec![
                    Line::from(vec![
                        Span::styled(p.stage.to_string(), t.warn()),
                        Span::raw(format!(
                            " · step {} of {} · {} · {left}",
                            (p.done + 1).min(p.total),
                            p.total,
                            secs(p.elapsed)
                        )),
                    ]),
                    Line::from(vec![
                        Span::styled(stop, t.key()),
                        Span::raw(" STOP or "),
                        Span::styled(back, t.key()),
                        Span::raw(" ends it at once, the safe state first"),
                    ]),
                    Line::from(vec![
                        Span::styled("writing to ", t.label()),
                        Span::raw(path_in(&out, w.saturating_sub(11))),
                    ]),
                ]
            }
            Some(Ok(h)) => {
                let done = format!("done in {}", secs_f(h.took));
                let room =
                    w.saturating_sub(done.chars().count() + " · written to ".chars().count());
                let mut lines = vec![Line::from(vec![
                    Span::styled(done, t.good()),
                    Span::styled(" · written to ", t.label()),
                    Span::raw(path_in(&out, room)),
                ])];
                let groups = h.words().into_iter().map(|w| vec![Span::raw(w)]).collect();
                lines.extend(wrap(groups, width, ""));
                lines
            }
            Some(Err(why)) => vec![
                Line::from(vec![
                    Span::styled("ended early: ", t.fault()),
                    Span::styled(why.clone(), t.fault()),
                ]),
                Line::from(Span::raw(
                    "the vehicle was let go in its safe state; nothing was written",
                )),
            ],
        }
    }
}

/// `path` in at most `room` columns: whole, or its end after a mark (the end of a
/// directory's path is what tells it from another).
fn path_in(path: &str, room: usize) -> String {
    let chars: Vec<char> = path.chars().collect();
    if chars.len() <= room {
        return path.to_string();
    }
    let keep = room.saturating_sub(1);
    format!(
        "{}{}",
        fit::MARK,
        chars[chars.len() - keep..].iter().collect::<String>()
    )
}

fn secs_f(s: f64) -> String {
    secs(std::time::Duration::from_secs_f64(s.max(0.0)))
}

impl Widget for &RunBox<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        let style = match &self.run.end {
            Some(Err(_)) => self.theme.fault(),
            None => self.theme.warn(),
            Some(Ok(_)) => self.theme.title(),
        };
        let block = Block::bordered()
            .border_style(style)
            .title(Span::styled(fit::title(&self.title(), area.width), style));
        let inner = block.inner(area);
        block.render(area, buf);
        Fitted(self.lines(inner.width)).render(inner, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::{Progress, Stage};
    use crate::controls::Headline;
    use crate::value::DeviceId;
    use std::time::Duration;

    pub(crate) fn running() -> Characterizing {
        Characterizing {
            device: DeviceId(0),
            name: "steer".into(),
            procedures: crate::characterize::Procedure::ALL.to_vec(),
            out: "/home/op/characterize-steer-20261127-140812".into(),
            progress: Progress {
                stage: Stage::Steps,
                done: 11,
                total: 50,
                elapsed: Duration::from_millis(8100),
            },
            end: None,
        }
    }

    fn rows(buf: &Buffer) -> Vec<String> {
        (0..buf.area.height)
            .map(|y| (0..buf.area.width).map(|x| buf[(x, y)].symbol()).collect())
            .collect()
    }

    fn drawn(run: &Characterizing, w: u16, h: u16) -> Vec<String> {
        let map = Keymap::default_map();
        let b = RunBox {
            run,
            map: &map,
            theme: Theme::default(),
        };
        let mut buf = Buffer::empty(Rect::new(0, 0, w, h));
        (&b).render(buf.area, &mut buf);
        rows(&buf)
    }

    #[test]
    fn while_it_runs_the_stage_its_step_the_time_and_the_keys_that_end_it() {
        let r = drawn(&running(), 80, RUN_BOX);
        assert!(
            r[0].starts_with("┌ characterize steer: running ─"),
            "{}",
            r[0]
        );
        // 11 moves in 8.1 s: 39 more at that pace.
        assert_eq!(
            r[1],
            format!(
                "│{:<78}│",
                "large steps · step 12 of 50 · 8.1 s · about 28.7 s left"
            )
        );
        assert!(
            r[2].contains("Space STOP or Esc ends it at once"),
            "{}",
            r[2]
        );
        assert!(
            r[3].contains("writing to /home/op/characterize-steer-"),
            "{}",
            r[3]
        );
        // Too long a path keeps its end, which tells it from another.
        let r = drawn(&running(), 40, RUN_BOX);
        assert_eq!(r[3], "│writing to …rize-steer-20261127-140812│");
    }

    #[test]
    fn once_done_the_headline_figures_and_where_they_were_written() {
        let mut run = running();
        run.end = Some(Ok(Headline {
            units: String::new(),
            rate_up: Some(1.0),
            rate_down: Some(0.998),
            delay: Some(0.012),
            deadband: Some(crate::controls::Deadband::Measured(0.02)),
            backlash: Some(0.031),
            rise: Some(0.48),
            overshoot_pct: Some(0.0),
            settle: Some(0.62),
            took: 31.2,
        }));
        // Where the path does not fit, its end.
        let r = drawn(&run, 60, RUN_BOX);
        assert_eq!(
            r[1],
            "│done in 31.2 s · written to …cterize-steer-20261127-140812│"
        );
        let r = drawn(&run, 80, RUN_BOX);
        let text = r.join("\n");
        assert!(r[0].starts_with("┌ characterize steer: done ─"), "{text}");
        assert!(
            r[1].contains("done in 31.2 s · written to /home/op/"),
            "{text}"
        );
        for f in [
            "rate up 1.000 /s",
            "down 0.998 /s",
            "delay 12 ms",
            "deadband 0.020",
            "backlash 0.031",
            "rise 480 ms",
            "overshoot 0.0 %",
            "settle 620 ms",
        ] {
            assert!(text.contains(f), "{f} in\n{text}");
        }
    }

    /// At the smallest bench (80×22: the box gets four rows) the first two lines — what
    /// it does now and how to end it — are drawn, each whole or cut with a mark.
    #[test]
    fn a_short_narrow_box_keeps_its_first_lines_and_cuts_with_a_mark() {
        let r = drawn(&running(), 80, 4);
        assert!(r[1].contains("step 12 of 50"), "{r:?}");
        assert!(r[2].contains("STOP"), "{r:?}");
        let mut ended = running();
        ended.end = Some(Err(
            "the vehicle was disengaged: stop from console, and then some more words".into(),
        ));
        let r = drawn(&ended, 40, 4);
        assert!(
            r[0].starts_with("┌ characterize steer: ended early ─"),
            "{r:?}"
        );
        assert!(r[1].starts_with("│ended early: the vehicle was…"), "{r:?}");
    }
}

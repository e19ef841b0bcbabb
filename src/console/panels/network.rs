//! The network panel: listen address, senders, commands per device, rejections by
//! reason and the command watchdog, from a [`NetStatus`] when the listener runs;
//! "not running" otherwise (with the intake's own rejections, which the console's
//! commands count in too).

use crate::console::controls::{NetStatus, Snapshot, Watchdog};
use crate::console::theme::Theme;
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::text::{Line, Span};
use ratatui::widgets::{Paragraph, Widget};

pub struct NetworkPanel<'a> {
    pub snap: &'a Snapshot,
    pub theme: Theme,
}

fn rejections(list: &[(String, u64)]) -> String {
    if list.is_empty() {
        return "none".into();
    }
    list.iter()
        .map(|(r, n)| format!("{r} {n}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl NetworkPanel<'_> {
    fn running(&self, n: &NetStatus) -> Vec<Line<'static>> {
        let t = &self.theme;
        let l = |x: &'static str| Span::styled(x, t.label());
        let wd = match n.watchdog {
            Watchdog::Idle => Span::raw("idle"),
            Watchdog::Ok {
                since_last,
                timeout,
            } => Span::styled(
                format!("ok {}/{}ms", since_last.as_millis(), timeout.as_millis()),
                t.good(),
            ),
            Watchdog::Tripped => Span::styled("TRIPPED", t.fault()),
        };
        let cmds = n
            .commands
            .iter()
            .map(|(r, c)| format!("{r} {c}"))
            .collect::<Vec<_>>()
            .join(" ");
        vec![
            Line::from(vec![
                Span::styled("NETWORK ", t.title()),
                Span::raw(n.listen.clone()),
                l(" senders "),
                Span::raw(n.senders.len().to_string()),
                l(" watchdog "),
                wd,
            ]),
            Line::from(vec![l("cmds "), Span::raw(cmds)]),
            Line::from(vec![l("rejected "), Span::raw(rejections(&n.rejections))]),
            Line::from(vec![l("from "), Span::raw(n.senders.join(", "))]),
        ]
    }

    pub fn lines(&self) -> Vec<Line<'static>> {
        let t = &self.theme;
        match &self.snap.net {
            Some(n) => self.running(n),
            None => {
                let intake: Vec<(String, u64)> = self
                    .snap
                    .rejections
                    .iter()
                    .map(|(r, n)| (r.as_str().to_string(), *n))
                    .collect();
                vec![
                    Line::from(vec![
                        Span::styled("NETWORK ", t.title()),
                        Span::styled("network: not running", t.label()),
                    ]),
                    Line::from(vec![
                        Span::styled("intake rejected ", t.label()),
                        Span::raw(rejections(&intake)),
                    ]),
                ]
            }
        }
    }
}

impl Widget for &NetworkPanel<'_> {
    fn render(self, area: Rect, buf: &mut Buffer) {
        Paragraph::new(self.lines()).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::value::Role;
    use std::time::Duration;

    fn text(p: &NetworkPanel, w: u16, h: u16) -> Vec<String> {
        let mut buf = Buffer::empty(Rect::new(0, 0, w, h));
        p.render(buf.area, &mut buf);
        (0..h)
            .map(|y| {
                (0..w)
                    .map(|x| buf[(x, y)].symbol().to_string())
                    .collect::<String>()
                    .trim_end()
                    .to_string()
            })
            .collect()
    }

    #[test]
    fn without_a_listener_it_says_not_running() {
        let snap = Snapshot::default();
        let p = NetworkPanel {
            snap: &snap,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&p, 40, 2),
            ["NETWORK network: not running", "intake rejected none"]
        );
    }

    #[test]
    fn with_a_listener_it_shows_its_figures() {
        let snap = Snapshot {
            net: Some(NetStatus {
                listen: "127.0.0.1:7400".into(),
                senders: vec!["127.0.0.1:5000".into()],
                commands: vec![(Role::Steer, 12), (Role::Gas, 3)],
                rejections: vec![("disengaged".into(), 2)],
                watchdog: Watchdog::Ok {
                    since_last: Duration::from_millis(40),
                    timeout: Duration::from_millis(500),
                },
            }),
            ..Snapshot::default()
        };
        let p = NetworkPanel {
            snap: &snap,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&p, 60, 3),
            [
                "NETWORK 127.0.0.1:7400 senders 1 watchdog ok 40/500ms",
                "cmds steer 12 gas 3",
                "rejected disengaged 2",
            ]
        );
    }
}

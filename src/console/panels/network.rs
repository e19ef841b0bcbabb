//! The network panel: listen address, senders, commands per device, rejections by
//! reason and the command watchdog, from the snapshot's network part when the
//! listener runs, and the live view's viewers and the messages they lost (`--foxglove`);
//! "not running" otherwise (with the intake's own rejections, which the console's
//! commands count in too).

use super::fit::Fitted;
use crate::console::theme::Theme;
use crate::controls::Scene;
use crate::snapshot::{LiveView, NetView, WatchdogState};
use ratatui::buffer::Buffer;
use ratatui::layout::Rect;
use ratatui::style::Style;
use ratatui::text::{Line, Span};
use ratatui::widgets::Widget;

pub(crate) struct NetworkPanel<'a> {
    pub snap: &'a Scene,
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
    /// The lines for a panel `width` columns wide: the command watchdog ends the first
    /// line, or opens the second where the first has no room for it whole.
    fn running(&self, n: &NetView, width: u16) -> Vec<Line<'static>> {
        let t = &self.theme;
        let l = |x: &'static str| Span::styled(x, t.label());
        // The commander's watchdog (a network sender's, ROS 2's, or the teleop deadman).
        let wd = match &self.snap.gate.watchdog {
            None => Span::raw("idle"),
            Some(w) => match w.state {
                WatchdogState::Off | WatchdogState::Idle => Span::raw("idle"),
                WatchdogState::Armed => Span::styled(
                    format!(
                        "ok {:.0}/{:.0}ms",
                        w.last_command_age_ms.unwrap_or(0.0),
                        w.timeout_ms
                    ),
                    t.good(),
                ),
                WatchdogState::Tripped => Span::styled("TRIPPED", t.fault()),
            },
        };
        let cmds = n
            .commands
            .iter()
            .filter(|(_, c)| **c > 0)
            .map(|(r, c)| format!("{r} {c}"))
            .collect::<Vec<_>>()
            .join(" ");
        let mut rejected: Vec<(String, u64)> = [
            &n.rejected.datagram,
            &n.rejected.intake,
            &n.rejected.refused,
        ]
        .into_iter()
        .flat_map(|p| p.iter())
        .filter(|(_, c)| **c > 0)
        .map(|(r, c)| (r.to_string(), *c))
        .collect();
        rejected.sort_by_key(|r| std::cmp::Reverse(r.1));
        let senders: Vec<String> = n
            .senders
            .iter()
            .map(|x| format!("{}{}", x.addr, if x.commanding { "*" } else { "" }))
            .collect();
        let mut first = Line::from(vec![
            Span::styled("NETWORK ", t.title()),
            Span::raw(n.listen.to_string()),
            l(" senders "),
            Span::raw(n.senders.len().to_string()),
        ]);
        let mut second = Line::from(vec![
            l("cmds "),
            Span::raw(if cmds.is_empty() { "none".into() } else { cmds }),
        ]);
        let watchdog = [l(" watchdog "), wd];
        let room = usize::from(width);
        if first.width() + watchdog.iter().map(Span::width).sum::<usize>() <= room {
            first.spans.extend(watchdog);
        } else {
            let [_, wd] = watchdog;
            let mut spans = vec![l("watchdog "), wd, l("  ")];
            spans.append(&mut second.spans);
            second = Line::from(spans);
        }
        let mut lines = vec![
            first,
            second,
            Line::from(vec![l("rejected "), Span::raw(rejections(&rejected))]),
        ];
        lines.extend(n.foxglove.as_ref().map(|f| self.live(f)));
        lines.push(Line::from(vec![l("from "), Span::raw(senders.join(", "))]));
        lines
    }

    /// The live view: where, how many watch, and the messages they lost (a viewer
    /// reading too slowly; the vehicle never waits for one).
    fn live(&self, f: &LiveView) -> Line<'static> {
        let t = &self.theme;
        let dropped = f.dropped + f.tap_dropped;
        Line::from(vec![
            Span::styled("foxglove ", t.label()),
            Span::raw(f.listen.to_string()),
            Span::styled(" viewers ", t.label()),
            Span::raw(f.viewers.len().to_string()),
            Span::styled(" dropped ", t.label()),
            Span::styled(
                dropped.to_string(),
                if dropped > 0 {
                    t.warn()
                } else {
                    Style::default()
                },
            ),
        ])
    }

    /// The lines for a panel `width` columns wide.
    pub(crate) fn lines(&self, width: u16) -> Vec<Line<'static>> {
        let t = &self.theme;
        match &self.snap.net {
            Some(n) => self.running(n, width),
            None => {
                let intake: Vec<(String, u64)> = self
                    .snap
                    .rejections
                    .iter()
                    .filter(|(_, n)| **n > 0)
                    .map(|(r, n)| (r.to_string(), *n))
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
        Fitted(self.lines(area.width)).render(area, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::snapshot::{Pairs, Rejections, SenderView, Snapshot, WatchdogView};

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
        let snap = Scene::default();
        let p = NetworkPanel {
            snap: &snap,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&p, 40, 2),
            ["NETWORK network: not running", "intake rejected none"]
        );
    }

    fn listening() -> Scene {
        let pairs = |v: &[(&str, u64)]| -> Pairs<u64> {
            v.iter().map(|(n, c)| (n.to_string(), *c)).collect()
        };
        Scene {
            snap: Snapshot {
                net: Some(NetView {
                    listen: "127.0.0.1:7400".parse().unwrap(),
                    datagrams: 17,
                    accepted: 15,
                    senders: vec![SenderView {
                        addr: "127.0.0.1:5000".parse().unwrap(),
                        age_ms: 40.0,
                        seq: None,
                        datagrams: 17,
                        accepted: 15,
                        rejected: 2,
                        commanding: false,
                        frozen: false,
                        latched: false,
                    }],
                    commands: pairs(&[("steer", 12), ("gas", 3), ("brake", 0)]),
                    rejected: Rejections {
                        intake: pairs(&[("disengaged", 2), ("gas_estop", 0)]),
                        ..Rejections::default()
                    },
                    foxglove: None,
                }),
                gate: crate::snapshot::GateView {
                    watchdog: Some(WatchdogView {
                        state: WatchdogState::Armed,
                        timeout_ms: 500.0,
                        last_command_age_ms: Some(40.0),
                        last_trip: None,
                        trip: None,
                    }),
                    ..Default::default()
                },
                ..Snapshot::default()
            },
            ..Scene::default()
        }
    }

    #[test]
    fn with_a_listener_it_shows_its_figures() {
        let snap = listening();
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

    /// At 80 columns the panel is 40 wide, and its first line ended `senders 0
    /// watchd`: the command watchdog was cut off. Where it does not fit it opens the
    /// next line, whole; what does not fit after it is cut at a word with `…`.
    #[test]
    fn at_40_columns_the_watchdog_opens_the_next_line_whole() {
        let snap = listening();
        let p = NetworkPanel {
            snap: &snap,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&p, 40, 3),
            [
                "NETWORK 127.0.0.1:7400 senders 1",
                "watchdog ok 40/500ms  cmds steer 12 gas…",
                "rejected disengaged 2",
            ]
        );
    }

    #[test]
    fn a_live_view_shows_its_viewers_and_what_they_lost() {
        let mut snap = listening();
        let net = snap.snap.net.as_mut().unwrap();
        net.foxglove = Some(LiveView {
            listen: "127.0.0.1:8765".parse().unwrap(),
            viewers: vec![crate::snapshot::ViewerView {
                addr: "127.0.0.1:5001".parse().unwrap(),
                subprotocol: "foxglove.sdk.v1".into(),
                subscriptions: 3,
                sent: 900,
                dropped: 12,
            }],
            dropped: 12,
            tap_dropped: 0,
        });
        let p = NetworkPanel {
            snap: &snap,
            theme: Theme::default(),
        };
        assert_eq!(
            text(&p, 60, 5)[3],
            "foxglove 127.0.0.1:8765 viewers 1 dropped 12"
        );
        let mut buf = Buffer::empty(Rect::new(0, 0, 60, 5));
        (&p).render(buf.area, &mut buf);
        let at = "foxglove 127.0.0.1:8765 viewers 1 dropped ".len() as u16;
        assert_eq!(buf[(at, 3)].style().fg, Theme::default().warn().fg);
    }
}

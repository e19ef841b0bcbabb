//! The terminal's bytes, as keys and replies: a pure decoder, tested on bytes alone.
//!
//! What a terminal sends a program mixes two things: the operator's keys, and the
//! terminal's replies to what the program asked — a cursor position report
//! (`CSI row ; col R`, the answer to the liveness check's `CSI 6 n`), the kitty keyboard
//! protocol's flags (`CSI ? flags u`) and the primary device attributes (`CSI ? … c`),
//! the two answers of the start-up probe. crossterm's reader parses the replies into
//! events of its own that `event::read` never returns, and its key parser is not public;
//! terminput's ([`terminput::Event::parse_from`], crossterm's parser lightly modified,
//! with the kitty protocol's press, repeat and release) decodes one sequence at a time
//! but does not take the replies (it reads a cursor report as F3) and does not say
//! where a sequence ends. So [`Decoder`] frames the bytes itself:
//!
//! 1. **framing** ([`sequence`]): where the next sequence ends, by ECMA-48's grammar — a
//!    control sequence is `ESC [`, parameter bytes, intermediate bytes, one final
//!    byte; `ESC O x` is one key; `ESC` before a key is Alt; a UTF-8 character is whole
//!    or not yet. A sequence split across reads waits for its end; bytes that cannot
//!    start or continue a sequence are dropped, never the key after them;
//! 2. **replies** ([`reply`]) are taken out before any key is decoded;
//! 3. **keys**: terminput decodes the sequence; [`crossterm_key`] turns it into the
//!    `KeyEvent` crossterm would have given, so the keymap is unchanged (terminput says
//!    `Tab` with Shift where crossterm says `BackTab`, and `Alt+Esc` for `ESC ESC`,
//!    which crossterm reads as Esc).
//!
//! A lone `ESC` is the Esc key only once nothing follows it: the reader calls
//! [`Decoder::flush`] when no byte came for [`ESC_WAIT`]. In the kitty protocol Esc is
//! `CSI 27 u` and never waits.
//!
//! A cursor position report is indistinguishable from F3 with modifiers in the legacy
//! encoding (`CSI 1 ; 2 R` is both Shift+F3 and "row 1, column 2"); as crossterm does,
//! it is always taken as the report. The console counts an answer only against a
//! request it made (input's `link`), so a stray Shift+F3 proves nothing.

use crossterm::event::{
    KeyCode, KeyEvent, KeyEventKind, KeyEventState, KeyModifiers, MediaKeyCode, ModifierKeyCode,
};
use std::time::Duration;

/// How long a lone `ESC` waits for the rest of a sequence before it is the Esc key.
pub(crate) const ESC_WAIT: Duration = Duration::from_millis(50);
/// The longest sequence kept waiting for its end; longer is garbage, dropped.
const LONGEST: usize = 64;
const ESC: u8 = 0x1b;

/// A reply of the terminal to something adrive asked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reply {
    /// A cursor position report (`CSI row ; col R`): the answer to `CSI 6 n`.
    Cursor,
    /// The kitty keyboard protocol's flags in force (`CSI ? flags u`).
    Flags(u16),
    /// The primary device attributes (`CSI ? … c`), which every terminal answers.
    Attributes,
}

/// What a sequence of the terminal's bytes is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Token {
    Key(KeyEvent),
    Reply(Reply),
}

/// Where the next sequence at the start of some bytes ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sequence {
    /// Not whole yet: more bytes may complete it.
    Incomplete,
    /// A whole sequence of this many bytes.
    Whole(usize),
    /// This many bytes that are no sequence: drop them.
    Garbage(usize),
}

/// Where the sequence at the start of `b` (not empty) ends.
pub(crate) fn sequence(b: &[u8]) -> Sequence {
    match b[0] {
        ESC => match b.get(1) {
            None => Sequence::Incomplete,
            Some(b'[') => control_sequence(b),
            // SS3: one more byte (F1–F4, the arrows in application mode).
            Some(b'O') if b.len() < 3 => Sequence::Incomplete,
            Some(b'O') => Sequence::Whole(3),
            Some(&ESC) => match b.get(2) {
                None => Sequence::Incomplete,
                // The Esc key, and a sequence after it: the operator's Esc just before
                // a terminal's reply (`ESC ESC [ 21 ; 76 R`). Taken as one Esc, the
                // reply's `[ 21 ; 76 R` were keys — and `R` releases command.
                Some(b'[' | b'O') => Sequence::Whole(1),
                // crossterm reads `ESC ESC` as one Esc.
                Some(_) => Sequence::Whole(2),
            },
            // Alt and the key after it.
            Some(_) => match sequence(&b[1..]) {
                Sequence::Whole(n) => Sequence::Whole(n + 1),
                Sequence::Incomplete => Sequence::Incomplete,
                Sequence::Garbage(_) => Sequence::Garbage(1),
            },
        },
        0x80..=0xff => {
            let need = match b[0] {
                0xc2..=0xdf => 2,
                0xe0..=0xef => 3,
                0xf0..=0xf4 => 4,
                _ => return Sequence::Garbage(1),
            };
            // Every byte there so far must continue the character.
            if let Some(i) = (1..need.min(b.len())).find(|&i| b[i] & 0xc0 != 0x80) {
                return Sequence::Garbage(i);
            }
            if b.len() < need {
                return Sequence::Incomplete;
            }
            match std::str::from_utf8(&b[..need]) {
                Ok(_) => Sequence::Whole(need),
                Err(_) => Sequence::Garbage(need),
            }
        }
        _ => Sequence::Whole(1),
    }
}

/// `ESC [`, parameter bytes (0x30–0x3F), intermediate bytes (0x20–0x2F), a final byte
/// (0x40–0x7E). The Linux console's F1–F5 are `ESC [ [ A`…`E`.
fn control_sequence(b: &[u8]) -> Sequence {
    match b.get(2) {
        None => return Sequence::Incomplete,
        Some(b'[') if b.len() < 4 => return Sequence::Incomplete,
        Some(b'[') => return Sequence::Whole(4),
        Some(_) => {}
    }
    let mut i = 2;
    while i < b.len() && (0x20..=0x3f).contains(&b[i]) {
        i += 1;
    }
    match b.get(i) {
        None if i >= LONGEST => Sequence::Garbage(i),
        None => Sequence::Incomplete,
        Some(0x40..=0x7e) => Sequence::Whole(i + 1),
        // A byte that cannot be in a control sequence (a control character, another
        // ESC): the sequence so far is broken, and that byte starts the next.
        Some(_) => Sequence::Garbage(i),
    }
}

/// The terminal's reply that `seq` (a whole sequence) is, if it is one.
pub(crate) fn reply(seq: &[u8]) -> Option<Reply> {
    let body = seq.strip_prefix(b"\x1b[")?;
    let (&last, params) = body.split_last()?;
    let digits = |p: &[u8]| !p.is_empty() && p.iter().all(u8::is_ascii_digit);
    match (params.first(), last) {
        (Some(b'?'), b'u') => {
            let flags = std::str::from_utf8(&params[1..]).ok()?.parse().ok()?;
            Some(Reply::Flags(flags))
        }
        (Some(b'?'), b'c') => Some(Reply::Attributes),
        (Some(_), b'R') => {
            let mut it = params.split(|&c| c == b';');
            let (row, col) = (it.next()?, it.next()?);
            (digits(row) && digits(col) && it.next().is_none()).then_some(Reply::Cursor)
        }
        _ => None,
    }
}

/// What a whole sequence means: a reply, a key, or nothing adrive uses (a mouse
/// report, focus, a sequence no terminal should send).
pub(crate) fn token(seq: &[u8]) -> Option<Token> {
    if let Some(r) = reply(seq) {
        return Some(Token::Reply(r));
    }
    // terminput says Alt+Esc; crossterm read it as Esc.
    if seq == [ESC, ESC] || seq == [ESC] {
        return Some(Token::Key(KeyEvent::new(KeyCode::Esc, KeyModifiers::NONE)));
    }
    match terminput::Event::parse_from(seq) {
        Ok(Some(terminput::Event::Key(k))) => crossterm_key(k).map(Token::Key),
        _ => None,
    }
}

/// The key terminput decoded, as crossterm's `KeyEvent` (what the keymap matches).
pub(crate) fn crossterm_key(k: terminput::KeyEvent) -> Option<KeyEvent> {
    use terminput::KeyCode as T;
    let mut modifiers = KeyModifiers::NONE;
    for (t, c) in [
        (terminput::KeyModifiers::SHIFT, KeyModifiers::SHIFT),
        (terminput::KeyModifiers::CTRL, KeyModifiers::CONTROL),
        (terminput::KeyModifiers::ALT, KeyModifiers::ALT),
        (terminput::KeyModifiers::SUPER, KeyModifiers::SUPER),
        (terminput::KeyModifiers::HYPER, KeyModifiers::HYPER),
        (terminput::KeyModifiers::META, KeyModifiers::META),
    ] {
        if k.modifiers.contains(t) {
            modifiers |= c;
        }
    }
    let code = match k.code {
        T::Backspace => KeyCode::Backspace,
        T::Enter => KeyCode::Enter,
        T::Left => KeyCode::Left,
        T::Right => KeyCode::Right,
        T::Up => KeyCode::Up,
        T::Down => KeyCode::Down,
        T::Home => KeyCode::Home,
        T::End => KeyCode::End,
        T::PageUp => KeyCode::PageUp,
        T::PageDown => KeyCode::PageDown,
        T::Tab if modifiers.contains(KeyModifiers::SHIFT) => KeyCode::BackTab,
        T::Tab => KeyCode::Tab,
        T::Delete => KeyCode::Delete,
        T::Insert => KeyCode::Insert,
        T::F(n) => KeyCode::F(n),
        T::Char(c) => KeyCode::Char(c),
        T::Esc => KeyCode::Esc,
        T::CapsLock => KeyCode::CapsLock,
        T::ScrollLock => KeyCode::ScrollLock,
        T::NumLock => KeyCode::NumLock,
        T::PrintScreen => KeyCode::PrintScreen,
        T::Pause => KeyCode::Pause,
        T::Menu => KeyCode::Menu,
        T::KeypadBegin => KeyCode::KeypadBegin,
        T::Media(m) => KeyCode::Media(media(m)),
        T::Modifier(m, d) => KeyCode::Modifier(modifier(m, d)?),
    };
    let kind = match k.kind {
        terminput::KeyEventKind::Press => KeyEventKind::Press,
        terminput::KeyEventKind::Repeat => KeyEventKind::Repeat,
        terminput::KeyEventKind::Release => KeyEventKind::Release,
    };
    let mut state = KeyEventState::NONE;
    for (t, c) in [
        (terminput::KeyEventState::KEYPAD, KeyEventState::KEYPAD),
        (
            terminput::KeyEventState::CAPS_LOCK,
            KeyEventState::CAPS_LOCK,
        ),
        (terminput::KeyEventState::NUM_LOCK, KeyEventState::NUM_LOCK),
    ] {
        if k.state.contains(t) {
            state |= c;
        }
    }
    Some(KeyEvent::new_with_kind_and_state(
        code, modifiers, kind, state,
    ))
}

fn media(m: terminput::MediaKeyCode) -> MediaKeyCode {
    use terminput::MediaKeyCode as T;
    match m {
        T::Play => MediaKeyCode::Play,
        T::Pause => MediaKeyCode::Pause,
        T::PlayPause => MediaKeyCode::PlayPause,
        T::Reverse => MediaKeyCode::Reverse,
        T::Stop => MediaKeyCode::Stop,
        T::FastForward => MediaKeyCode::FastForward,
        T::Rewind => MediaKeyCode::Rewind,
        T::TrackNext => MediaKeyCode::TrackNext,
        T::TrackPrevious => MediaKeyCode::TrackPrevious,
        T::Record => MediaKeyCode::Record,
        T::LowerVolume => MediaKeyCode::LowerVolume,
        T::RaiseVolume => MediaKeyCode::RaiseVolume,
        T::MuteVolume => MediaKeyCode::MuteVolume,
    }
}

fn modifier(
    m: terminput::ModifierKeyCode,
    d: terminput::ModifierDirection,
) -> Option<ModifierKeyCode> {
    use terminput::ModifierDirection::{Left, Right, Unknown};
    use terminput::ModifierKeyCode as T;
    Some(match (m, d) {
        (T::Shift, Left | Unknown) => ModifierKeyCode::LeftShift,
        (T::Shift, Right) => ModifierKeyCode::RightShift,
        (T::Control, Left | Unknown) => ModifierKeyCode::LeftControl,
        (T::Control, Right) => ModifierKeyCode::RightControl,
        (T::Alt, Left | Unknown) => ModifierKeyCode::LeftAlt,
        (T::Alt, Right) => ModifierKeyCode::RightAlt,
        (T::Super, Left | Unknown) => ModifierKeyCode::LeftSuper,
        (T::Super, Right) => ModifierKeyCode::RightSuper,
        (T::Hyper, Left | Unknown) => ModifierKeyCode::LeftHyper,
        (T::Hyper, Right) => ModifierKeyCode::RightHyper,
        (T::Meta, Left | Unknown) => ModifierKeyCode::LeftMeta,
        (T::Meta, Right) => ModifierKeyCode::RightMeta,
        (T::IsoLevel3Shift, _) => ModifierKeyCode::IsoLevel3Shift,
        (T::IsoLevel5Shift, _) => ModifierKeyCode::IsoLevel5Shift,
    })
}

/// The terminal's bytes as they arrive, read by read, into tokens. What ends a read in
/// the middle of a sequence waits for the next read (or [`Decoder::flush`]).
#[derive(Debug, Default)]
pub(crate) struct Decoder {
    buf: Vec<u8>,
    /// What the last [`Decoder::flush`] took of a sequence cut short, from its last
    /// `ESC`: a terminal's reply split by a pause longer than [`ESC_WAIT`] (a slow SSH
    /// link) goes on in the next read, and is still the reply, not keys.
    cut: Vec<u8>,
}

impl Decoder {
    /// Decode `bytes` after what was waiting; every whole token goes to `out`.
    pub(crate) fn feed(&mut self, bytes: &[u8], out: &mut Vec<Token>) {
        self.buf.extend_from_slice(bytes);
        let mut at = self.rest_of_a_cut_reply(out);
        while at < self.buf.len() {
            match sequence(&self.buf[at..]) {
                Sequence::Incomplete => break,
                Sequence::Garbage(n) => at += n,
                Sequence::Whole(n) => {
                    out.extend(token(&self.buf[at..at + n]));
                    at += n;
                }
            }
        }
        self.buf.drain(..at);
    }

    /// How many bytes at the start of the buffer end a reply the last flush cut short
    /// (the reply goes to `out`); 0 when they do not. Only two bytes or more count: an
    /// operator's key arrives in a read of its own, and a lone `c`, `u` or `R` typed
    /// after a cut is that key.
    fn rest_of_a_cut_reply(&mut self, out: &mut Vec<Token>) -> usize {
        let cut = std::mem::take(&mut self.cut);
        if cut.is_empty() || self.buf.first() == Some(&ESC) {
            return 0;
        }
        let joined = [cut.as_slice(), self.buf.as_slice()].concat();
        let Sequence::Whole(n) = sequence(&joined) else {
            return 0;
        };
        match reply(&joined[..n]) {
            Some(r) if n >= cut.len() + 2 => {
                out.push(Token::Reply(r));
                n - cut.len()
            }
            _ => 0,
        }
    }

    /// Bytes are waiting for the rest of their sequence.
    pub(crate) fn waiting(&self) -> bool {
        !self.buf.is_empty()
    }

    /// Nothing more came: what waits is taken as it stands — a lone `ESC` is the Esc
    /// key, `ESC` and a key that could begin a sequence (`ESC [`, `ESC O`) is Alt and
    /// that key; a sequence cut short is dropped.
    pub(crate) fn flush(&mut self, out: &mut Vec<Token>) {
        let buf = std::mem::take(&mut self.buf);
        if let Some(i) = buf.iter().rposition(|&b| b == ESC) {
            self.cut = buf[i..].to_vec();
        }
        let key = match buf.as_slice() {
            [ESC] | [ESC, ESC] => Some(KeyEvent::new(KeyCode::Esc, KeyModifiers::NONE)),
            [ESC, c @ (b'[' | b'O')] => {
                let c = char::from(*c);
                let shift = if c.is_uppercase() {
                    KeyModifiers::SHIFT
                } else {
                    KeyModifiers::NONE
                };
                Some(KeyEvent::new(KeyCode::Char(c), KeyModifiers::ALT | shift))
            }
            _ => None,
        };
        out.extend(key.map(Token::Key));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn key(code: KeyCode, m: KeyModifiers) -> Token {
        Token::Key(KeyEvent::new(code, m))
    }

    fn kind(code: KeyCode, m: KeyModifiers, kind: KeyEventKind) -> Token {
        Token::Key(KeyEvent::new_with_kind(code, m, kind))
    }

    fn decode(bytes: &[u8]) -> Vec<Token> {
        let mut d = Decoder::default();
        let mut out = Vec::new();
        d.feed(bytes, &mut out);
        d.flush(&mut out);
        out
    }

    const NONE: KeyModifiers = KeyModifiers::NONE;
    const SHIFT: KeyModifiers = KeyModifiers::SHIFT;
    const CTRL: KeyModifiers = KeyModifiers::CONTROL;
    const ALT: KeyModifiers = KeyModifiers::ALT;

    /// Every key the keymaps name (keymap.rs's `<Name>`s, characters, Ctrl and Alt),
    /// as legacy terminals send them, and the event crossterm's own reader gave for
    /// each: the keymap sees what it saw before.
    fn legacy_table() -> Vec<(&'static [u8], Token)> {
        vec![
            (b"a", key(KeyCode::Char('a'), NONE)),
            (b"G", key(KeyCode::Char('G'), SHIFT)),
            (b"?", key(KeyCode::Char('?'), NONE)),
            (b"<", key(KeyCode::Char('<'), NONE)),
            (b" ", key(KeyCode::Char(' '), NONE)),
            ("é".as_bytes(), key(KeyCode::Char('é'), NONE)),
            ("→".as_bytes(), key(KeyCode::Char('→'), NONE)),
            ("🚗".as_bytes(), key(KeyCode::Char('🚗'), NONE)),
            (b"\x03", key(KeyCode::Char('c'), CTRL)),
            (b"\x15", key(KeyCode::Char('u'), CTRL)),
            (b"\x0a", key(KeyCode::Char('j'), CTRL)),
            (b"\x00", key(KeyCode::Char(' '), CTRL)),
            (b"\x1c", key(KeyCode::Char('4'), CTRL)),
            (b"\r", key(KeyCode::Enter, NONE)),
            (b"\t", key(KeyCode::Tab, NONE)),
            (b"\x7f", key(KeyCode::Backspace, NONE)),
            (b"\x1b", key(KeyCode::Esc, NONE)),
            (b"\x1b\x1b", key(KeyCode::Esc, NONE)),
            (b"\x1bx", key(KeyCode::Char('x'), ALT)),
            (b"\x1b\x03", key(KeyCode::Char('c'), CTRL | ALT)),
            (b"\x1b[A", key(KeyCode::Up, NONE)),
            (b"\x1b[B", key(KeyCode::Down, NONE)),
            (b"\x1b[C", key(KeyCode::Right, NONE)),
            (b"\x1b[D", key(KeyCode::Left, NONE)),
            (b"\x1bOA", key(KeyCode::Up, NONE)),
            (b"\x1bOD", key(KeyCode::Left, NONE)),
            (b"\x1b[H", key(KeyCode::Home, NONE)),
            (b"\x1b[F", key(KeyCode::End, NONE)),
            (b"\x1bOH", key(KeyCode::Home, NONE)),
            (b"\x1b[1~", key(KeyCode::Home, NONE)),
            (b"\x1b[4~", key(KeyCode::End, NONE)),
            (b"\x1b[2~", key(KeyCode::Insert, NONE)),
            (b"\x1b[3~", key(KeyCode::Delete, NONE)),
            (b"\x1b[5~", key(KeyCode::PageUp, NONE)),
            (b"\x1b[6~", key(KeyCode::PageDown, NONE)),
            (b"\x1b[Z", key(KeyCode::BackTab, SHIFT)),
            (b"\x1bOP", key(KeyCode::F(1), NONE)),
            (b"\x1bOS", key(KeyCode::F(4), NONE)),
            (b"\x1b[[A", key(KeyCode::F(1), NONE)),
            (b"\x1b[15~", key(KeyCode::F(5), NONE)),
            (b"\x1b[24~", key(KeyCode::F(12), NONE)),
            (b"\x1b[1;5A", key(KeyCode::Up, CTRL)),
            (b"\x1b[1;2D", key(KeyCode::Left, SHIFT)),
            (b"\x1b[1;3C", key(KeyCode::Right, ALT)),
            (b"\x1b[3;5~", key(KeyCode::Delete, CTRL)),
        ]
    }

    /// The kitty protocol at flags 3 (disambiguate, event types), as kitty, foot and
    /// WezTerm send it: presses, repeats and releases with their kind.
    fn kitty_table() -> Vec<(&'static [u8], Token)> {
        use KeyEventKind::{Press, Release, Repeat};
        vec![
            (b"\x1b[A", kind(KeyCode::Up, NONE, Press)),
            (b"\x1b[1;1:1A", kind(KeyCode::Up, NONE, Press)),
            (b"\x1b[1;1:2A", kind(KeyCode::Up, NONE, Repeat)),
            (b"\x1b[1;1:3A", kind(KeyCode::Up, NONE, Release)),
            (b"\x1b[1;1:3B", kind(KeyCode::Down, NONE, Release)),
            (b"\x1b[1;1:2D", kind(KeyCode::Left, NONE, Repeat)),
            (b"\x1b[1;1:3C", kind(KeyCode::Right, NONE, Release)),
            (b"\x1b[1;5:3A", kind(KeyCode::Up, CTRL, Release)),
            (b"\x1b[27u", kind(KeyCode::Esc, NONE, Press)),
            (b"\x1b[27;1:3u", kind(KeyCode::Esc, NONE, Release)),
            (b"\x1b[97;1:2u", kind(KeyCode::Char('a'), NONE, Repeat)),
            (b"\x1b[97;1:3u", kind(KeyCode::Char('a'), NONE, Release)),
            (b"\x1b[32;1:3u", kind(KeyCode::Char(' '), NONE, Release)),
            (b"\x1b[99;5u", kind(KeyCode::Char('c'), CTRL, Press)),
            (b"\x1b[13u", kind(KeyCode::Enter, NONE, Press)),
            (b"\x1b[9;2u", kind(KeyCode::BackTab, SHIFT, Press)),
            (b"\x1b[127u", kind(KeyCode::Backspace, NONE, Press)),
            (b"\x1b[3;1:3~", kind(KeyCode::Delete, NONE, Release)),
            (b"\x1b[13~", kind(KeyCode::F(3), NONE, Press)),
            (b"\x1b[5;1:2~", kind(KeyCode::PageUp, NONE, Repeat)),
        ]
    }

    #[test]
    fn every_key_of_the_tables_decodes_as_crossterm_read_it() {
        for (bytes, want) in legacy_table().into_iter().chain(kitty_table()) {
            assert_eq!(decode(bytes), [want], "{bytes:?}");
        }
    }

    #[test]
    fn keys_in_one_read_decode_one_by_one() {
        let mut all = Vec::new();
        let mut want = Vec::new();
        for (bytes, t) in legacy_table().into_iter().chain(kitty_table()) {
            // A lone ESC or ESC ESC merges with what follows: not in one read.
            if bytes.starts_with(b"\x1b") && bytes.len() <= 2 && bytes != b"\x1bx" {
                continue;
            }
            all.extend_from_slice(bytes);
            want.push(t);
        }
        assert_eq!(decode(&all), want);
    }

    #[test]
    fn replies_are_taken_out_before_keys() {
        assert_eq!(decode(b"\x1b[12;40R"), [Token::Reply(Reply::Cursor)]);
        assert_eq!(decode(b"\x1b[?0u"), [Token::Reply(Reply::Flags(0))]);
        assert_eq!(decode(b"\x1b[?3u"), [Token::Reply(Reply::Flags(3))]);
        assert_eq!(decode(b"\x1b[?62;22c"), [Token::Reply(Reply::Attributes)]);
        assert_eq!(decode(b"\x1b[?1;2c"), [Token::Reply(Reply::Attributes)]);
        assert_eq!(
            decode(b"q\x1b[3;7Rq"),
            [
                key(KeyCode::Char('q'), NONE),
                Token::Reply(Reply::Cursor),
                key(KeyCode::Char('q'), NONE)
            ]
        );
    }

    /// A reply split anywhere across reads is one reply, and the key after it one key.
    #[test]
    fn a_reply_split_across_reads_is_one_reply() {
        let all = b"\x1b[?1u\x1b[?62;22c\x1b[24;80R\x1b[A";
        for cut in 0..=all.len() {
            for cut2 in cut..=all.len() {
                let mut d = Decoder::default();
                let mut out = Vec::new();
                d.feed(&all[..cut], &mut out);
                d.feed(&all[cut..cut2], &mut out);
                d.feed(&all[cut2..], &mut out);
                assert!(!d.waiting(), "{cut} {cut2}");
                assert_eq!(
                    out,
                    [
                        Token::Reply(Reply::Flags(1)),
                        Token::Reply(Reply::Attributes),
                        Token::Reply(Reply::Cursor),
                        key(KeyCode::Up, NONE)
                    ],
                    "cut at {cut} and {cut2}"
                );
            }
        }
    }

    #[test]
    fn a_lone_escape_waits_then_is_esc() {
        let mut d = Decoder::default();
        let mut out = Vec::new();
        d.feed(b"\x1b", &mut out);
        assert!(out.is_empty() && d.waiting());
        // The rest of a sequence arrives in time: one key.
        d.feed(b"[B", &mut out);
        assert_eq!(out, [key(KeyCode::Down, NONE)]);
        out.clear();
        d.feed(b"\x1b", &mut out);
        d.flush(&mut out);
        assert_eq!(out, [key(KeyCode::Esc, NONE)]);
        assert!(!d.waiting());
        // Alt-[ typed: ESC [ and nothing more.
        assert_eq!(decode(b"\x1b["), [key(KeyCode::Char('['), ALT)]);
    }

    /// The operator's Esc just before the terminal's reply, in one read or split
    /// anywhere: the Esc key and the reply, never the reply's bytes as keys (its `R`
    /// released command in a real run).
    #[test]
    fn an_esc_just_before_a_reply_is_the_esc_key_and_the_reply() {
        let esc = key(KeyCode::Esc, NONE);
        let all = b"\x1b\x1b[21;76R";
        for cut in 0..=all.len() {
            let mut d = Decoder::default();
            let mut out = Vec::new();
            d.feed(&all[..cut], &mut out);
            d.feed(&all[cut..], &mut out);
            d.flush(&mut out);
            assert_eq!(out, [esc, Token::Reply(Reply::Cursor)], "cut at {cut}");
        }
        assert_eq!(
            decode(b"\x1b\x1b[?1u"),
            [esc, Token::Reply(Reply::Flags(1))]
        );
        assert_eq!(decode(b"\x1b\x1bOA"), [esc, key(KeyCode::Up, NONE)]);
    }

    /// A reply cut by a pause longer than ESC_WAIT (the terminal fell quiet mid-reply,
    /// the flush took what had come): what comes after is still the reply, not keys.
    #[test]
    fn a_reply_cut_by_a_pause_is_never_keys() {
        for reply in [&b"\x1b[21;76R"[..], b"\x1b[?62;22c", b"\x1b[?1u"] {
            for with_esc in [false, true] {
                let all = [if with_esc { &b"\x1b"[..] } else { b"" }, reply].concat();
                for cut in 1..all.len() - 1 {
                    let mut d = Decoder::default();
                    let mut out = Vec::new();
                    d.feed(&all[..cut], &mut out);
                    d.flush(&mut out);
                    d.feed(&all[cut..], &mut out);
                    d.flush(&mut out);
                    let keys: Vec<_> = out
                        .iter()
                        .filter_map(|t| match t {
                            Token::Key(k) => Some(k.code),
                            Token::Reply(_) => None,
                        })
                        .collect();
                    // The flush may have taken a lone ESC as Esc or `ESC [` as Alt-[;
                    // nothing of the reply's own is a key.
                    assert!(
                        keys.iter()
                            .all(|c| matches!(c, KeyCode::Esc | KeyCode::Char('['))),
                        "{all:?} cut at {cut}: {out:?}"
                    );
                    assert!(
                        out.iter().any(|t| matches!(t, Token::Reply(_))),
                        "{all:?} cut at {cut}: {out:?}"
                    );
                }
            }
        }
        // A key typed after a cut is that key, even one that ends a reply.
        let mut d = Decoder::default();
        let mut out = Vec::new();
        d.feed(b"\x1b[21;7", &mut out);
        d.flush(&mut out);
        d.feed(b"R", &mut out);
        assert_eq!(out, [key(KeyCode::Char('R'), SHIFT)]);
    }

    #[test]
    fn broken_sequences_are_dropped_and_the_next_key_kept() {
        // A control character inside a control sequence.
        assert_eq!(decode(b"\x1b[1;\x03"), [key(KeyCode::Char('c'), CTRL)]);
        // A sequence nobody sends, then a key.
        assert_eq!(decode(b"\x1b[99;99;99zq"), [key(KeyCode::Char('q'), NONE)]);
        // Invalid UTF-8, then a key.
        assert_eq!(decode(b"\xff\xc3q"), [key(KeyCode::Char('q'), NONE)]);
        // Too long to be a sequence.
        let mut long = b"\x1b[".to_vec();
        long.extend(std::iter::repeat_n(b'1', 100));
        long.extend(b"\x1b[A");
        assert_eq!(decode(&long), [key(KeyCode::Up, NONE)]);
    }

    fn keys() -> impl Strategy<Value = (Vec<u8>, Token)> {
        let all: Vec<_> = legacy_table()
            .into_iter()
            .chain(kitty_table())
            .map(|(b, t)| (b.to_vec(), t))
            .collect();
        proptest::sample::select(all)
    }

    proptest! {
        /// Arbitrary bytes never panic the decoder, never leave more than a sequence's
        /// worth waiting, and never take the key that follows them once the terminal
        /// fell quiet (the flush).
        #[test]
        fn arbitrary_bytes_never_panic_nor_lose_the_next_key(
            garbage in prop::collection::vec(any::<u8>(), 0..200),
            split in 0usize..200,
            (bytes, want) in keys(),
        ) {
            let mut d = Decoder::default();
            let mut out = Vec::new();
            let split = split.min(garbage.len());
            d.feed(&garbage[..split], &mut out);
            d.feed(&garbage[split..], &mut out);
            prop_assert!(d.buf.len() <= LONGEST + 4);
            d.flush(&mut out);
            out.clear();
            d.feed(&bytes, &mut out);
            d.flush(&mut out);
            prop_assert_eq!(out, vec![want]);
        }
    }
}

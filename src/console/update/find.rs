//! The name prompt (`/`), on the main screen and the bench: every character typed
//! puts the cursor (or the bench) on the best match at once ([`names::matches`]);
//! completion, next and previous match while it is open; Enter keeps the device,
//! Esc goes back to where the prompt was opened. Afterwards the next and previous
//! match keys look for the same name again.

use crate::console::keymap::{Action, Mode};
use crate::console::model::{Find, Model};
use crate::console::names;
use crate::value::DeviceId;

/// Open the prompt over the current mode.
pub(super) fn open(m: &mut Model) {
    m.find = Some(Find {
        query: String::new(),
        from_cursor: m.cursor,
        from_bench: m.bench,
    });
    m.back_to = m.mode;
    m.mode = Mode::Find;
}

/// The names, in the vehicle's order.
fn names(m: &Model) -> Vec<String> {
    m.snap.devices.iter().map(|d| d.name.clone()).collect()
}

fn matches(m: &Model, query: &str) -> Vec<usize> {
    let names = names(m);
    names::matches(names.iter().map(String::as_str), query)
}

fn go(m: &mut Model, i: usize) {
    let id = DeviceId(i as u16);
    if m.in_bench() {
        m.bench = id;
    } else {
        m.select_device(id);
    }
}

/// Back to where the prompt was opened.
fn restore(m: &mut Model, f: &Find) {
    m.cursor = f.from_cursor;
    m.bench = f.from_bench;
}

/// Put the cursor on the best match of the query, or back where it was.
fn follow(m: &mut Model) {
    let Some(f) = m.find.clone() else { return };
    match matches(m, &f.query).first() {
        Some(&i) => go(m, i),
        None => restore(m, &f),
    }
}

/// The next (`step` 1) or previous (−1) device matching `query` from the one the
/// prompt moves; false when none matches.
fn step(m: &mut Model, query: &str, step: isize) -> bool {
    let found = matches(m, query);
    match names::next(&found, m.found_device(), step) {
        Some(i) => {
            go(m, i);
            true
        }
        None => false,
    }
}

/// A key while the prompt is open.
pub(super) fn prompt(m: &mut Model, a: Action) {
    let Some(f) = m.find.as_mut() else {
        m.mode = m.back_to;
        return;
    };
    match a {
        Action::Input(c) => {
            f.query.extend(c.to_lowercase());
            follow(m);
        }
        Action::Backspace => {
            f.query.pop();
            follow(m);
        }
        Action::Clear => {
            f.query.clear();
            follow(m);
        }
        Action::Complete => {
            let names = names(m);
            if let Some(f) = m.find.as_mut() {
                f.query = names::complete(names.iter().map(String::as_str), &f.query);
            }
            follow(m);
        }
        Action::FindNext | Action::Down | Action::FindPrev | Action::Up => {
            let query = f.query.clone();
            let dir = if matches!(a, Action::FindNext | Action::Down) {
                1
            } else {
                -1
            };
            step(m, &query, dir);
        }
        Action::Commit => {
            let f = m.find.take().expect("open");
            m.mode = m.back_to;
            if f.query.is_empty() {
                restore(m, &f);
            } else if matches(m, &f.query).is_empty() {
                restore(m, &f);
                m.say(format!("no device matches {:?}", f.query), true);
            } else {
                m.last_find = Some(f.query);
            }
        }
        Action::Cancel | Action::Back => {
            let f = m.find.take().expect("open");
            restore(m, &f);
            m.mode = m.back_to;
        }
        _ => {}
    }
}

/// The next or previous match of the last name looked for (`n`, `N`).
pub(super) fn again(m: &mut Model, dir: isize) {
    let Some(query) = m.last_find.clone() else {
        let key = m
            .keymap
            .key_for(m.mode, Action::Find)
            .map_or("the find key".to_string(), |k| k.to_string());
        return m.say(
            format!("no name looked for yet: {key} finds a device by its name"),
            true,
        );
    };
    if !step(m, &query, dir) {
        m.say(format!("no device matches {query:?}"), true);
    }
}

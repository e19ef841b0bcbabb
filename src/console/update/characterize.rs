//! Characterizing the device on the bench, from the console: its key asks first —
//! naming the device, the procedures, the directory, what it does to the device and
//! what proved the vehicle still — or is refused at once with the reason; once
//! confirmed, the engine's process runs it ([`Controls::characterize`]) and each tick
//! reads where it stands. While it runs the bench stays on its device, and leaving
//! the bench ends it at once (the runner lets the vehicle go, safe state first); STOP
//! ends it as it ends any command. How it ended is said once, on the message line.

use super::ask as ask_question;
use crate::characterize::background::out_dir;
use crate::characterize::Procedure;
use crate::console::keymap::Action;
use crate::console::model::{CharacterizeAsk, Model, Question};
use crate::controls::Controls;

/// The key: refused with the reason where it cannot run, else the question.
pub(super) fn ask(m: &mut Model, c: &dyn Controls) {
    let id = m.bench;
    let name = m.bench_device().map_or("?".into(), |d| d.name.clone());
    if m.characterize_running() {
        return m.say(
            "characterize refused: a characterization is already running",
            true,
        );
    }
    match c.characterize_check(id) {
        Err(why) => m.say(format!("characterize {name} refused: {why}"), true),
        Ok(proof) => {
            m.characterize_ask = Some(CharacterizeAsk {
                device: id,
                out: out_dir(&name, std::time::SystemTime::now()),
                name,
                procedures: Procedure::ALL.to_vec(),
                proof,
            });
            ask_question(m, Question::Characterize(id));
        }
    }
}

/// The operator said yes: start it (the engine checks again).
pub(super) fn confirmed(m: &mut Model, c: &dyn Controls, id: crate::value::DeviceId) {
    let Some(a) = m.characterize_ask.take().filter(|a| a.device == id) else {
        return;
    };
    match c.characterize(id, &a.procedures, &a.out) {
        Ok(()) => {
            m.characterize_shown = true;
            m.characterizing = c.characterizing();
            m.say(
                format!("characterize {}: started; STOP or Esc ends it", a.name),
                false,
            );
        }
        Err(why) => m.say(format!("characterize {} refused: {why}", a.name), true),
    }
}

/// While it runs, the bench stays on the device measured: a key that would turn it to
/// another is refused (`true`), saying how to end the run.
pub(super) fn holds_the_bench(m: &mut Model, a: Action) -> bool {
    let turns = matches!(
        a,
        Action::NextDevice
            | Action::PrevDevice
            | Action::Right
            | Action::Left
            | Action::Up
            | Action::Down
            | Action::Find
            | Action::FindNext
            | Action::FindPrev
    );
    if turns && m.characterize_running() {
        m.say(
            "the bench stays on the device characterized while it runs: STOP or Esc ends it",
            true,
        );
    }
    turns && m.characterize_running()
}

/// The bench is left: a run under way ends at once, saying `why`.
pub(super) fn left(m: &mut Model, c: &dyn Controls, why: &str) {
    if m.characterize_running() {
        // It has ended when this returns: the answer to the operator's key.
        c.characterize_end(why);
        m.characterizing = c.characterizing();
        if let Some((text, bad)) = m.characterizing.as_ref().and_then(ending) {
            m.say(text, bad);
        }
    }
    m.characterize_shown = false;
}

/// How run `run` ended, in words, and whether that is bad news; `None` while it runs.
fn ending(run: &crate::controls::Characterizing) -> Option<(String, bool)> {
    match run.end.as_ref()? {
        Ok(h) => Some((
            format!(
                "characterize {}: done in {:.1} s, written to {}",
                run.name,
                h.took,
                run.out.display()
            ),
            false,
        )),
        Err(why) => Some((
            format!(
                "characterize {} ended early: {why}; safe state, nothing written",
                run.name
            ),
            true,
        )),
    }
}

/// Read where the run stands; say once how it ended.
pub(super) fn tick(m: &mut Model, c: &dyn Controls) {
    let was_running = m.characterize_running();
    m.characterizing = c.characterizing();
    if !was_running {
        return;
    }
    if let Some((text, bad)) = m.characterizing.as_ref().and_then(ending) {
        m.tell(text, bad);
    }
}

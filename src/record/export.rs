//! `adrive export FILE --csv DIR`: one CSV file per channel, for spreadsheets and
//! plotting. Each row is one message: `time_s` (seconds from the recording's first
//! message), `log_time_ns`, then every field of the message flattened to a column —
//! `position`, `gate.engaged`, `devices.steer.commanded` (an array of objects with a
//! `name` is keyed by it), lists of plain values joined with `; `.

use super::read::{ReadError, Recording};
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The CSV file of a topic: `/steer/reading` → `steer.reading.csv`.
pub(crate) fn file_name(topic: &str) -> String {
    let stem: String = topic
        .trim_start_matches('/')
        .chars()
        .map(|c| match c {
            '/' => '.',
            c if c.is_alphanumeric() || c == '-' || c == '_' || c == '.' => c,
            _ => '_',
        })
        .collect();
    format!("{}.csv", if stem.is_empty() { "root" } else { &stem })
}

/// Flatten a message into (column, cell) pairs, in the message's order.
pub(crate) fn flatten(v: &Value) -> Vec<(String, String)> {
    let mut out = Vec::new();
    walk(v, String::new(), &mut out);
    out
}

fn walk(v: &Value, path: String, out: &mut Vec<(String, String)>) {
    let join = |key: &str| {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    };
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                walk(x, join(k), out);
            }
        }
        Value::Array(items) if items.iter().any(|x| x.is_object() || x.is_array()) => {
            for (i, x) in items.iter().enumerate() {
                let key = x
                    .get("name")
                    .and_then(Value::as_str)
                    .map_or_else(|| i.to_string(), str::to_string);
                walk(x, join(&key), out);
            }
        }
        Value::Array(items) => {
            let cells: Vec<String> = items.iter().map(cell).collect();
            out.push((path, cells.join("; ")));
        }
        other => out.push((path, cell(other))),
    }
}

fn cell(v: &Value) -> String {
    match v {
        Value::Null => String::new(),
        Value::String(s) => s.clone(),
        Value::Number(n) if n.is_f64() => n.as_f64().map_or_else(|| n.to_string(), number),
        other => other.to_string(),
    }
}

/// A float to 12 significant digits, trailing zeros dropped: `57.958`, not the
/// `57.958000000000006` its arithmetic left (a spreadsheet reads both alike; a
/// person does not). Numbers below a millionth are written whole.
fn number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || x.abs() < 1e-6 {
        return x.to_string();
    }
    let whole_digits = x.abs().log10().floor() as i32 + 1;
    let decimals = (12 - whole_digits).clamp(0, 17) as usize;
    let s = format!("{x:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Write one CSV per channel of `rec` into `dir` (created if needed); returns the
/// files written with their row counts.
pub(crate) fn csv(rec: &Recording, dir: &Path) -> Result<Vec<(PathBuf, u64)>, ReadError> {
    let fail = |p: &Path, e: &dyn std::fmt::Display| ReadError {
        path: p.display().to_string(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| fail(dir, &e))?;
    // First the columns of every channel, in the order they appear.
    let mut columns: Vec<(String, Vec<String>)> = Vec::new();
    let mut first = None;
    rec.for_each(|m| {
        first = Some(first.unwrap_or(m.log_time));
        let Ok(v) = serde_json::from_slice::<Value>(m.data) else {
            return;
        };
        let cols = match columns.iter_mut().find(|(t, _)| t == m.topic) {
            Some((_, c)) => c,
            None => {
                columns.push((m.topic.to_string(), Vec::new()));
                &mut columns.last_mut().expect("pushed").1
            }
        };
        for (k, _) in flatten(&v) {
            if !cols.contains(&k) {
                cols.push(k);
            }
        }
    });
    let start = first.unwrap_or(0);
    let mut writers = HashMap::new();
    let mut written = Vec::new();
    for (topic, cols) in &columns {
        let path = dir.join(file_name(topic));
        let mut w = csv::Writer::from_path(&path).map_err(|e| fail(&path, &e))?;
        let header = ["time_s", "log_time_ns"]
            .into_iter()
            .map(str::to_string)
            .chain(cols.iter().cloned());
        w.write_record(header).map_err(|e| fail(&path, &e))?;
        let index: HashMap<&str, usize> = cols
            .iter()
            .enumerate()
            .map(|(i, c)| (c.as_str(), i))
            .collect();
        writers.insert(topic.as_str(), (w, index, path, 0u64));
    }
    let mut error = None;
    rec.for_each(|m| {
        let Ok(v) = serde_json::from_slice::<Value>(m.data) else {
            return;
        };
        let Some((w, index, path, rows)) = writers.get_mut(m.topic) else {
            return;
        };
        let mut row = vec![String::new(); index.len() + 2];
        row[0] = format!("{:.6}", m.log_time.saturating_sub(start) as f64 / 1e9);
        row[1] = m.log_time.to_string();
        for (k, c) in flatten(&v) {
            if let Some(&i) = index.get(k.as_str()) {
                row[i + 2] = c;
            }
        }
        if let Err(e) = w.write_record(&row) {
            error.get_or_insert_with(|| fail(path, &e));
        }
        *rows += 1;
    });
    if let Some(e) = error {
        return Err(e);
    }
    for (topic, _) in &columns {
        let (mut w, _, path, rows) = writers.remove(topic.as_str()).expect("one per channel");
        w.flush().map_err(|e| fail(&path, &e))?;
        written.push((path, rows));
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A status age computed as 57.958 ms was exported as `57.958000000000006`: the
    /// float's exact value, noise for a spreadsheet.
    #[test]
    fn numbers_are_written_as_people_read_them() {
        assert_eq!(cell(&json!(57.958000000000006)), "57.958");
        assert_eq!(cell(&json!(0.1 + 0.2)), "0.3");
        assert_eq!(cell(&json!(-0.25)), "-0.25");
        assert_eq!(cell(&json!(0.001234)), "0.001234");
        assert_eq!(cell(&json!(3)), "3");
        assert_eq!(cell(&json!(1_795_299_498_139u64)), "1795299498139");
        assert_eq!(cell(&json!(1_795_299_498.5)), "1795299498.5");
        assert_eq!(cell(&json!(2.5e-9)), "0.0000000025");
    }

    #[test]
    fn topics_become_file_names() {
        assert_eq!(file_name("/steer/reading"), "steer.reading.csv");
        assert_eq!(file_name("/snapshot"), "snapshot.csv");
        assert_eq!(file_name("/a b/raw"), "a_b.raw.csv");
    }

    #[test]
    fn messages_flatten_by_name_and_path() {
        let v = json!({
            "gate": { "engaged": true, "blockers": ["a", "b"] },
            "devices": [ { "name": "steer", "commanded": 0.25 }, { "name": "gas", "commanded": null } ],
            "seq": 3
        });
        let f = flatten(&v);
        // Keys in JSON's order (serde_json keeps objects sorted by key).
        assert_eq!(
            f,
            [
                ("devices.steer.commanded".to_string(), "0.25".to_string()),
                ("devices.steer.name".into(), "steer".into()),
                ("devices.gas.commanded".into(), String::new()),
                ("devices.gas.name".into(), "gas".into()),
                ("gate.blockers".into(), "a; b".into()),
                ("gate.engaged".into(), "true".into()),
                ("seq".into(), "3".into()),
            ]
        );
    }
}

//! Finding a device by its name, as the name prompt (`/`) does while the operator
//! types: pure functions over the names, in the vehicle's order.
//!
//! A name matches when it starts with what was typed; failing that, when it contains
//! it (`brake` finds `brake`, then `parking_brake`). Typing puts the cursor on the
//! best match at once; the next and previous match keys walk every match in the
//! vehicle's order from the device under the cursor, wrapping around (as `n` and `N`
//! do in vim and less); completion extends what was typed to the longest prefix the
//! matching names share, as a shell completes a file name.

/// The devices whose names match `query`, best first: those starting with it in the
/// vehicle's order, then those containing it. An empty query matches nothing.
pub(crate) fn matches<'a>(names: impl IntoIterator<Item = &'a str>, query: &str) -> Vec<usize> {
    if query.is_empty() {
        return Vec::new();
    }
    let names: Vec<&str> = names.into_iter().collect();
    let starting = (0..names.len()).filter(|&i| names[i].starts_with(query));
    let containing =
        (0..names.len()).filter(|&i| !names[i].starts_with(query) && names[i].contains(query));
    starting.chain(containing).collect()
}

/// The match after device `at` (`step` 1) or before it (−1), in the vehicle's order,
/// wrapping around; `at` itself when it is the only one.
pub(crate) fn next(matches: &[usize], at: usize, step: isize) -> Option<usize> {
    let mut sorted = matches.to_vec();
    sorted.sort_unstable();
    if step >= 0 {
        sorted.iter().find(|&&i| i > at).or(sorted.first()).copied()
    } else {
        sorted
            .iter()
            .rev()
            .find(|&&i| i < at)
            .or(sorted.last())
            .copied()
    }
}

/// What `query` completes to: the longest prefix shared by the names starting with
/// it (the query itself when none does, or when they part at once).
pub(crate) fn complete<'a>(names: impl IntoIterator<Item = &'a str>, query: &str) -> String {
    let mut starting = names.into_iter().filter(|n| n.starts_with(query));
    let Some(first) = starting.next() else {
        return query.to_string();
    };
    let mut common = first.len();
    for n in starting {
        common = first
            .bytes()
            .zip(n.bytes())
            .take(common)
            .take_while(|(a, b)| a == b)
            .count();
    }
    first[..common.max(query.len())].to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 7] = [
        "steer",
        "brake",
        "parking_brake",
        "hitch",
        "hitch_load",
        "headlights",
        "switch",
    ];

    #[test]
    fn names_starting_with_the_query_come_first_then_those_containing_it() {
        assert_eq!(matches(NAMES, "brake"), [1, 2]);
        assert_eq!(matches(NAMES, "br"), [1, 2]);
        assert_eq!(matches(NAMES, "h"), [3, 4, 5, 6]);
        assert_eq!(matches(NAMES, "load"), [4]);
        assert!(matches(NAMES, "wiper").is_empty());
        assert!(matches(NAMES, "").is_empty());
    }

    #[test]
    fn next_and_previous_walk_the_matches_in_the_vehicles_order_and_wrap() {
        let m = matches(NAMES, "h");
        assert_eq!(next(&m, 3, 1), Some(4));
        assert_eq!(next(&m, 6, 1), Some(3), "wraps to the first");
        assert_eq!(next(&m, 3, -1), Some(6), "wraps to the last");
        // From a device that does not match: the next one that does.
        assert_eq!(next(&m, 0, 1), Some(3));
        assert_eq!(next(&[2], 2, 1), Some(2));
        assert_eq!(next(&[], 2, 1), None);
    }

    #[test]
    fn completion_extends_to_the_prefix_the_matches_share() {
        assert_eq!(complete(NAMES, "hi"), "hitch");
        assert_eq!(complete(NAMES, "hitch_"), "hitch_load");
        assert_eq!(complete(NAMES, "he"), "headlights");
        assert_eq!(
            complete(NAMES, "h"),
            "h",
            "hitch and headlights part at once"
        );
        assert_eq!(complete(NAMES, "x"), "x");
    }
}

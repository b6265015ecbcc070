//! "Did you mean ...?": the known name closest to a mistyped one, for the
//! config's unknown keys and kinds and the command line's unknown skins and
//! layers.
//!
//! ```
//! let keys = ["sensors", "layers", "sensors_per_module"];
//! assert_eq!(skin::suggest::closest("sensor_per_module", keys), Some("sensors_per_module"));
//! assert_eq!(skin::suggest::closest("colour", keys), None);
//! ```

/// The candidate closest to `input`, if one is close enough to be what was
/// meant and no other is as close. Close: a few edits (insertions,
/// deletions, substitutions, swaps of neighbours; about one per four
/// characters, at least one), or a common start with little added
/// (`rate` for `rate_hz`, by Jaro-Winkler similarity of 0.9 or more);
/// letter case does not count. Two candidates equally close give none: the
/// caller lists them all anyway, and a guess between them would mislead.
pub fn closest<'a>(input: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let input = input.to_lowercase();
    let mut best: Option<(&'a str, usize, f64)> = None;
    let mut tied = false;
    for candidate in candidates {
        let lower = candidate.to_lowercase();
        let edits = strsim::damerau_levenshtein(&input, &lower);
        let similarity = strsim::jaro_winkler(&input, &lower);
        let allowed = (lower.chars().count() / 4).max(1);
        if edits > allowed && similarity < 0.9 {
            continue;
        }
        match best {
            Some((kept, best_edits, best_similarity)) => {
                let closer = (edits, -similarity) < (best_edits, -best_similarity);
                let same = edits == best_edits && similarity == best_similarity && kept != candidate;
                if closer {
                    best = Some((candidate, edits, similarity));
                    tied = false;
                } else if same {
                    tied = true;
                }
            }
            None => best = Some((candidate, edits, similarity)),
        }
    }
    best.filter(|_| !tied).map(|(candidate, _, _)| candidate)
}

/// The same message with "did you mean `X`?" where it is serde's report of
/// an unknown field or variant ("unknown field `sensor_per_module`,
/// expected one of `name`, ...") and one of the expected names is close to
/// the unknown one; `None` for any other message, or without a close name.
/// The suggestion comes before the list of every name, which can be long
/// (a driver table has 37 keys).
pub fn annotate_unknown_name(message: &str) -> Option<String> {
    let (start, prefix) = ["unknown field `", "unknown variant `"]
        .iter()
        .find_map(|prefix| message.find(prefix).map(|at| (at, *prefix)))?;
    let after = start + prefix.len();
    let rest = &message[after..];
    let end = rest.find("`, expected ")?;
    let unknown = &rest[..end];
    let expected = &rest[end + "`, ".len()..];
    // The expected names are the quoted ones: every other piece between backticks.
    let names = expected.split('`').skip(1).step_by(2);
    let suggestion = closest(unknown, names)?;
    let split = after + end + 1;
    Some(format!("{}; did you mean `{suggestion}`? ({})", &message[..split], &message[split + ", ".len()..]))
}

/// Up to `max` names of `names` joined with ", ", and how many more there
/// are: a listing that stays one line on a skin of hundreds of layers.
pub fn list(names: &[String], max: usize) -> String {
    if names.len() <= max {
        return names.join(", ");
    }
    format!("{} and {} more", names[..max].join(", "), names.len() - max)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    const DRIVER_KEYS: [&str; 8] =
        ["name", "kind", "sensors", "layers", "sensors_per_module", "modules_per_patch", "rate_hz", "seed"];

    #[test]
    fn a_typo_finds_the_key_meant() {
        assert_eq!(closest("sensor_per_module", DRIVER_KEYS), Some("sensors_per_module"));
        assert_eq!(closest("sensorz", DRIVER_KEYS), Some("sensors"));
        assert_eq!(closest("Rate_Hz", DRIVER_KEYS), Some("rate_hz"));
        assert_eq!(closest("rate", DRIVER_KEYS), Some("rate_hz"));
        assert_eq!(closest("modules_par_patch", DRIVER_KEYS), Some("modules_per_patch"));
        assert_eq!(closest("virtul", ["virtual", "can", "replay", "ethercat"]), Some("virtual"));
    }

    #[test]
    fn nothing_close_suggests_nothing() {
        assert_eq!(closest("colour", DRIVER_KEYS), None);
        assert_eq!(closest("", DRIVER_KEYS), None);
        assert_eq!(closest("x", ["y", "z"].iter().copied().filter(|_| false)), None);
        assert_eq!(closest("torso", ["virtual-0", "virtual-1"]), None);
    }

    #[test]
    fn equally_close_names_suggest_none() {
        // virtual-9 is one edit from each of them: a guess would mislead.
        assert_eq!(closest("virtual-9", ["virtual-0", "virtual-1", "virtual-2"]), None);
        assert_eq!(closest("virtal-2", ["virtual-0", "virtual-1", "virtual-2"]), Some("virtual-2"));
        // A name listed twice is still one name.
        assert_eq!(closest("victm-0", ["victim-0", "victim-0", "steady-0"]), Some("victim-0"));
    }

    #[test]
    fn serde_reports_get_the_suggestion_before_the_list() {
        let message = "unknown field `sensor_per_module`, expected one of `name`, `sensors`, `sensors_per_module`";
        assert_eq!(
            annotate_unknown_name(message).unwrap(),
            "unknown field `sensor_per_module`; did you mean `sensors_per_module`? \
             (expected one of `name`, `sensors`, `sensors_per_module`)"
        );
        let message = "unknown variant `virtul`, expected one of `virtual`, `can`, `replay`, `ethercat`";
        assert!(annotate_unknown_name(message).unwrap().contains("did you mean `virtual`?"));
        let message = "unknown field `seeds`, expected `seed` or `name`";
        assert_eq!(
            annotate_unknown_name(message).unwrap(),
            "unknown field `seeds`; did you mean `seed`? (expected `seed` or `name`)"
        );
        assert_eq!(annotate_unknown_name("unknown field `colour`, expected one of `name`, `kind`"), None);
        assert_eq!(annotate_unknown_name("unknown field `x`, there are no fields"), None);
        assert_eq!(annotate_unknown_name("invalid type: string \"two\", expected usize"), None);
    }

    #[test]
    fn lists_stay_short() {
        let names: Vec<String> = (0..5).map(|k| format!("l{k}")).collect();
        assert_eq!(list(&names, 5), "l0, l1, l2, l3, l4");
        assert_eq!(list(&names, 2), "l0, l1 and 3 more");
        assert_eq!(list(&[], 2), "");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(if cfg!(miri) { 8 } else { 512 }))]

        /// Whatever the strings, a suggestion is one of the candidates, and
        /// a name that is a candidate suggests itself.
        #[test]
        fn suggestions_are_candidates(input in ".{0,40}", candidates in proptest::collection::vec(".{0,20}", 0..8)) {
            let names = candidates.iter().map(String::as_str);
            if let Some(found) = closest(&input, names) {
                prop_assert!(candidates.iter().any(|c| c == found));
            }
            if let Some(first) = candidates.first()
                && candidates.iter().all(|c| c.to_lowercase() != first.to_lowercase() || c == first)
            {
                prop_assert_eq!(closest(first, candidates.iter().map(String::as_str)), Some(first.as_str()));
            }
        }

        /// Any text, including serde-like reports with backticks in odd
        /// places, is annotated or left alone, never a panic.
        #[test]
        fn any_message_is_safe(prefix in "(unknown field `|unknown variant `|)", body in "[`a-z, ]{0,60}|.{0,60}") {
            let message = format!("{prefix}{body}");
            if let Some(annotated) = annotate_unknown_name(&message) {
                prop_assert!(annotated.contains("did you mean `"));
            }
        }
    }
}

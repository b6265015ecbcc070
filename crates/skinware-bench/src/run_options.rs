//! What every bench is run with ([`RunOptions`]), and the checks of the
//! durations a bench and its helper processes are given.

use std::path::PathBuf;

/// The options every bench takes from `skin bench`, and the executable it
/// runs again for its helper processes. A bench with options of its own
/// holds one of these (its `run` field) beside them; a bench with none
/// takes this alone.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// A short, CI-sized run.
    pub quick: bool,
    /// Directory for the JSON, the plots and the work files.
    pub out: PathBuf,
    /// Seconds per configuration (and round), instead of the bench's
    /// default for a quick or a full run. Benches that count rounds rather
    /// than seconds (`follow`) and the soak (minutes) ignore it.
    pub seconds: Option<f64>,
    /// The `skin` executable: benches run it again for their helper
    /// processes (its hidden roles) and for its commands (`skin run`,
    /// `skin record`, `skin bridge`, the viewer).
    pub exe: PathBuf,
}

impl RunOptions {
    /// `--seconds` if given, else the bench's default for a quick or a full run.
    pub fn seconds_or(&self, quick: f64, full: f64) -> f64 {
        self.seconds.unwrap_or(if self.quick { quick } else { full })
    }
}

/// The longest `--seconds` a bench accepts: a day per configuration.
pub const MAX_BENCH_SECONDS: f64 = 86_400.0;

/// The longest `--seconds` of the benches' own helper processes, which their
/// bench starts with its `--seconds` plus a margin (at most a minute now).
pub const MAX_HELPER_SECONDS: f64 = 2.0 * MAX_BENCH_SECONDS;

/// A duration on the command line that is no number, or out of range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DurationError {
    /// The text is not a number.
    #[error("{text:?} is not a number of {unit}")]
    NotANumber {
        /// What was given.
        text: String,
        /// `seconds` or `minutes`.
        unit: &'static str,
    },
    /// Zero, negative, infinite, NaN or too long.
    #[error("{text} {unit}: give more than 0 and at most {most} ({said})")]
    OutOfRange {
        /// What was given.
        text: String,
        /// `seconds` or `minutes`.
        unit: &'static str,
        /// The most allowed, in `unit`.
        most: f64,
        /// `most` in words ("a day").
        said: &'static str,
    },
}

/// `--seconds` of a bench: a positive, finite number of seconds up to a
/// day, refused here rather than as a panic deep in a bench (`1e20` seconds
/// is no `Duration` at all).
pub fn parse_bench_seconds(text: &str) -> Result<f64, DurationError> {
    parse_up_to(text, "seconds", MAX_BENCH_SECONDS, "a day")
}

/// `--seconds` of a bench's helper process (a hidden role).
pub fn parse_helper_seconds(text: &str) -> Result<f64, DurationError> {
    parse_up_to(text, "seconds", MAX_HELPER_SECONDS, "two days")
}

/// A positive, finite number of `unit` up to `most` (`said` in words).
pub(crate) fn parse_up_to(text: &str, unit: &'static str, most: f64, said: &'static str) -> Result<f64, DurationError> {
    let value: f64 = text.trim().parse().map_err(|_| DurationError::NotANumber { text: text.to_owned(), unit })?;
    if value.is_finite() && value > 0.0 && value <= most {
        Ok(value)
    } else {
        Err(DurationError::OutOfRange { text: text.to_owned(), unit, most, said })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_seconds_are_a_positive_number_up_to_a_day() {
        assert_eq!(parse_bench_seconds("2.5"), Ok(2.5));
        assert_eq!(parse_bench_seconds("86400"), Ok(86_400.0));
        for bad in ["0", "-1", "1e20", "inf", "NaN", "ten"] {
            let error = parse_bench_seconds(bad).unwrap_err().to_string();
            assert!(error.contains(bad) || error.contains("not a number"), "{bad}: {error}");
        }
        assert_eq!(
            parse_bench_seconds("0").unwrap_err().to_string(),
            "0 seconds: give more than 0 and at most 86400 (a day)"
        );
        assert_eq!(parse_bench_seconds("ten").unwrap_err().to_string(), "\"ten\" is not a number of seconds");
        // A bench's helper gets the bench's seconds plus a margin.
        assert_eq!(parse_helper_seconds("86430"), Ok(86_430.0));
        assert!(parse_helper_seconds("1e20").is_err());
    }

    #[test]
    fn a_quick_run_takes_the_quick_default_unless_told() {
        let mut run = RunOptions { quick: true, out: PathBuf::new(), seconds: None, exe: PathBuf::new() };
        assert_eq!(run.seconds_or(2.0, 20.0), 2.0);
        run.quick = false;
        assert_eq!(run.seconds_or(2.0, 20.0), 20.0);
        run.seconds = Some(7.0);
        assert_eq!(run.seconds_or(2.0, 20.0), 7.0);
    }
}

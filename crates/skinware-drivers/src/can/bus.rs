//! "A source and sink of CAN frames": the one trait every transport
//! implements, and opening one from its URL.
//!
//! | URL | transport |
//! |---|---|
//! | `socketcan://can0` | the kernel's SocketCAN ([`super::kernel`]) |
//! | `slcan:///dev/ttyACM0?bitrate=1000000` | a Lawicel adapter on a serial line ([`super::serial`]) |
//! | `cannelloni://0.0.0.0:20000?peer=192.168.1.10:20000` | CAN in UDP ([`super::udp`]) |
//! | `candump:///path/to/file.log?speed=1&loop=false` | replay of a `candump -l` log ([`super::replay`]) |

use std::time::Duration;

use super::CanFrame;

/// A source and sink of CAN frames.
pub trait CanBus: Send {
    /// Sends one frame.
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError>;

    /// The next frame from the bus, waiting at most `timeout`; `Ok(None)` if
    /// none came in time.
    fn receive(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError>;

    /// The URL it was opened with, for messages.
    fn url(&self) -> &str;
}

/// What went wrong with a bus. Every variant names the device and, where
/// there is one, the fix.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The URL cannot be understood.
    #[error(
        "bad CAN interface {url:?}: {problem}; use socketcan://can0, slcan:///dev/ttyACM0?bitrate=1000000, cannelloni://LOCAL:PORT?peer=REMOTE:PORT or candump:///path/file.log"
    )]
    BadUrl {
        /// The URL as given.
        url: String,
        /// What is wrong with it.
        problem: String,
    },
    /// The device could not be opened.
    #[error("cannot open {url}: {source}; {hint}")]
    Open {
        /// The URL.
        url: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
        /// What to do about it.
        hint: String,
    },
    /// The device failed or went away while in use (a cable pulled, an
    /// adapter unplugged): reopen it.
    #[error("{url}: {source}")]
    Lost {
        /// The URL.
        url: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The device said no (an SLCAN adapter refusing a command).
    #[error("{url}: {problem}")]
    Refused {
        /// The URL.
        url: String,
        /// What was refused.
        problem: String,
    },
    /// A replayed log is over (and does not loop).
    #[error("{url}: the log is over")]
    Ended {
        /// The URL.
        url: String,
    },
}

/// A URL split into scheme, path and `key=value` options.
#[derive(Debug)]
pub(crate) struct BusUrl<'a> {
    pub url: &'a str,
    pub scheme: &'a str,
    pub path: &'a str,
    pub options: Vec<(&'a str, &'a str)>,
}

impl<'a> BusUrl<'a> {
    pub fn parse(url: &'a str) -> Result<BusUrl<'a>, BusError> {
        let bad = |problem: &str| BusError::BadUrl { url: url.to_owned(), problem: problem.to_owned() };
        let (scheme, rest) = url.split_once("://").ok_or_else(|| bad("it has no scheme://"))?;
        let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
        if path.is_empty() {
            return Err(bad("it names no device"));
        }
        let mut options = Vec::new();
        for pair in query.split('&').filter(|p| !p.is_empty()) {
            let (key, value) = pair.split_once('=').ok_or_else(|| bad(&format!("option {pair:?} is not key=value")))?;
            options.push((key, value));
        }
        Ok(BusUrl { url, scheme, path, options })
    }

    /// The value of option `key`, parsed; the default if absent.
    pub fn option<T: std::str::FromStr>(&self, key: &str, default: T) -> Result<T, BusError> {
        match self.options.iter().find(|(k, _)| *k == key) {
            None => Ok(default),
            Some((_, value)) => value.parse().map_err(|_| BusError::BadUrl {
                url: self.url.to_owned(),
                problem: format!("option {key}={value} is not a valid value"),
            }),
        }
    }

    /// Refuses options other than `known`.
    pub fn only(&self, known: &[&str]) -> Result<(), BusError> {
        match self.options.iter().find(|(k, _)| !known.contains(k)) {
            None => Ok(()),
            Some((key, _)) => Err(BusError::BadUrl {
                url: self.url.to_owned(),
                problem: format!(
                    "unknown option {key:?}; {} takes {}",
                    self.scheme,
                    if known.is_empty() { "none".to_owned() } else { known.join(", ") }
                ),
            }),
        }
    }
}

/// The hint for an OS error opening a device.
pub(crate) fn open_hint(error: &std::io::Error, device: &str) -> String {
    match error.kind() {
        std::io::ErrorKind::NotFound => {
            format!("{device} does not exist: is the adapter plugged in, and is this its name?")
        }
        std::io::ErrorKind::PermissionDenied => {
            format!("no permission to open {device}: add your user to its group (often `dialout`), or run as root")
        }
        _ => format!("check that {device} is the adapter and that no other program holds it"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_urls_say_what_is_wrong() {
        for (url, problem) in [
            ("can0", "no scheme"),
            ("slcan://", "names no device"),
            ("usb://x", "unknown transport"),
            ("slcan:///dev/x?bitrate", "not key=value"),
            ("slcan:///dev/x?bitrate=fast", "not a valid value"),
            ("slcan:///dev/x?bitrate=42", "bit rate"),
            ("slcan:///dev/x?speed=1", "unknown option"),
            ("cannelloni://127.0.0.1:0", "peer"),
            ("candump:///x.log?speed=0", "speed"),
        ] {
            let err = crate::can::open(url).err().unwrap_or_else(|| panic!("{url} opened"));
            assert!(err.to_string().contains(problem), "{url}: {err}");
            assert!(matches!(err, BusError::BadUrl { .. }), "{url}: {err}");
        }
    }

    #[test]
    fn a_missing_device_is_named_with_the_fix() {
        let err = crate::can::open("slcan:///dev/ttyNOPE0").err().unwrap();
        let message = err.to_string();
        assert!(message.contains("/dev/ttyNOPE0") && message.contains("plugged in"), "{message}");
    }
}

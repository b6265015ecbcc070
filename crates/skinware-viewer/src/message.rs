//! What the web viewer's page says to the server: small JSON text messages
//! (`docs/viewer.md`, "Browser to server"). [`decode`] turns one into a
//! [`ClientMessage`], or into a [`MessageError`] that says what is wrong; it
//! takes any text, and allocates no more than a few times the text's length.
//!
//! | message | decoded |
//! |---|---|
//! | `{"ack": N}` | [`ClientMessage::Ack`] (N saturates at `u32::MAX`) |
//! | `{"mode": "asap"}` | [`ClientMessage::Mode`] with [`ReadMode::Asap`] |
//! | `{"mode": "periodic", "rate_hz": R}` | [`ReadMode::Periodic`], R from 0.1 to 1000 (30 if absent) |
//! | `{"mode": "request"}` | [`ReadMode::Request`] |
//! | `{"request": true}` | [`ClientMessage::Request`] |

use serde::Deserialize;

/// Longest message accepted, in bytes: the page's are under 50.
pub const MAX_MESSAGE_BYTES: usize = 1024;
/// Slowest periodic reading a browser may ask for, Hz.
pub const MIN_PERIODIC_HZ: f64 = 0.1;
/// Fastest periodic reading a browser may ask for, Hz.
pub const MAX_PERIODIC_HZ: f64 = 1000.0;
/// The periodic rate when the message gives none, Hz.
pub const DEFAULT_PERIODIC_HZ: f64 = 30.0;

/// How the server reads the layers for one browser.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReadMode {
    /// On absolute time at this rate, whether or not the layers published.
    Periodic {
        /// Reads per second.
        rate_hz: f64,
    },
    /// Every frame, as soon as its layer publishes it.
    Asap,
    /// One frame per layer each time the browser asks.
    Request,
}

/// A browser's request, decoded from its JSON text message.
#[derive(Clone, Debug, PartialEq)]
pub enum ClientMessage {
    /// The browser drew `n` updates: it may receive `n` more.
    Ack(u32),
    /// Read the layers in this mode from now on.
    Mode(ReadMode),
    /// Request mode: read one frame of every layer now.
    Request,
}

/// Why a text is not a message of the page.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MessageError {
    /// Longer than any message of the page; not parsed.
    #[error("a message of {bytes} bytes, longer than the {MAX_MESSAGE_BYTES} bytes of any message of the page")]
    TooLong {
        /// Its length.
        bytes: usize,
    },
    /// Not a JSON object of the known keys with values of their types.
    #[error("not a message of the page ({reason}): {text:?}")]
    Malformed {
        /// What the JSON parser objected to, with the column.
        reason: String,
        /// The message (at most [`MAX_MESSAGE_BYTES`]).
        text: String,
    },
    /// Known keys, but not one of the page's messages (several at once,
    /// `"request": false`, or a `rate_hz` without the periodic mode).
    #[error("not one of the page's messages: {text:?}")]
    Unknown {
        /// The message (at most [`MAX_MESSAGE_BYTES`]).
        text: String,
    },
    /// A periodic mode at a rate the server does not read at.
    #[error("periodic rate {rate_hz} Hz is outside {MIN_PERIODIC_HZ}-{MAX_PERIODIC_HZ} Hz")]
    RateOutOfRange {
        /// The rate asked for.
        rate_hz: f64,
    },
}

/// The mode names of `{"mode": ...}`.
#[derive(Deserialize)]
#[serde(rename_all = "lowercase")]
enum ModeName {
    Asap,
    Periodic,
    Request,
}

/// Every key a message may have. Decoding into it rather than into a
/// `serde_json::Value` keeps the allocation to the strings of the error, and
/// the nesting to one level.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Fields {
    ack: Option<u64>,
    request: Option<bool>,
    mode: Option<ModeName>,
    rate_hz: Option<f64>,
}

/// Decodes one text message of the page.
///
/// ```
/// use skinware_viewer::message::{ClientMessage, MessageError, ReadMode, decode};
///
/// assert_eq!(decode(r#"{"mode":"asap"}"#), Ok(ClientMessage::Mode(ReadMode::Asap)));
/// assert!(matches!(decode(r#"{"mode":"periodic","rate_hz":0}"#), Err(MessageError::RateOutOfRange { .. })));
/// ```
pub fn decode(text: &str) -> Result<ClientMessage, MessageError> {
    if text.len() > MAX_MESSAGE_BYTES {
        return Err(MessageError::TooLong { bytes: text.len() });
    }
    // serde would also take a JSON array for the struct, field by field.
    if !text.trim_start().starts_with('{') {
        let reason = "expected a JSON object".to_owned();
        return Err(MessageError::Malformed { reason, text: text.to_owned() });
    }
    let fields: Fields = serde_json::from_str(text)
        .map_err(|e| MessageError::Malformed { reason: e.to_string(), text: text.to_owned() })?;
    match fields {
        Fields { ack: Some(n), request: None, mode: None, rate_hz: None } => {
            Ok(ClientMessage::Ack(u32::try_from(n).unwrap_or(u32::MAX)))
        }
        Fields { ack: None, request: Some(true), mode: None, rate_hz: None } => Ok(ClientMessage::Request),
        Fields { ack: None, request: None, mode: Some(ModeName::Periodic), rate_hz } => {
            let rate_hz = rate_hz.unwrap_or(DEFAULT_PERIODIC_HZ);
            if !(rate_hz.is_finite() && (MIN_PERIODIC_HZ..=MAX_PERIODIC_HZ).contains(&rate_hz)) {
                return Err(MessageError::RateOutOfRange { rate_hz });
            }
            Ok(ClientMessage::Mode(ReadMode::Periodic { rate_hz }))
        }
        Fields { ack: None, request: None, mode: Some(ModeName::Asap), rate_hz: None } => {
            Ok(ClientMessage::Mode(ReadMode::Asap))
        }
        Fields { ack: None, request: None, mode: Some(ModeName::Request), rate_hz: None } => {
            Ok(ClientMessage::Mode(ReadMode::Request))
        }
        _ => Err(MessageError::Unknown { text: text.to_owned() }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pages_messages_decode() {
        assert_eq!(decode(r#"{"ack":2}"#), Ok(ClientMessage::Ack(2)));
        assert_eq!(decode(r#"{"ack":99999999999}"#), Ok(ClientMessage::Ack(u32::MAX)));
        assert_eq!(decode(r#"{"request":true}"#), Ok(ClientMessage::Request));
        assert_eq!(decode(r#"{"mode":"asap"}"#), Ok(ClientMessage::Mode(ReadMode::Asap)));
        assert_eq!(decode(r#" { "mode" : "request" } "#), Ok(ClientMessage::Mode(ReadMode::Request)));
        assert_eq!(
            decode(r#"{"mode":"periodic","rate_hz":12.5}"#),
            Ok(ClientMessage::Mode(ReadMode::Periodic { rate_hz: 12.5 }))
        );
        assert_eq!(
            decode(r#"{"mode":"periodic"}"#),
            Ok(ClientMessage::Mode(ReadMode::Periodic { rate_hz: DEFAULT_PERIODIC_HZ }))
        );
    }

    #[test]
    fn other_texts_are_refused_with_the_reason() {
        assert_eq!(decode(r#"{"mode":"periodic","rate_hz":0}"#), Err(MessageError::RateOutOfRange { rate_hz: 0.0 }));
        assert!(matches!(decode(r#"{"mode":"periodic","rate_hz":1e999}"#), Err(MessageError::Malformed { .. })));
        let malformed = |text: &str| match decode(text) {
            Err(MessageError::Malformed { reason, .. }) => reason,
            other => panic!("{text}: {other:?}"),
        };
        assert!(malformed(r#"{"mode":"sometimes"}"#).contains("unknown variant"));
        assert!(malformed(r#"{"ack":-1}"#).contains("invalid value"));
        assert!(malformed(r#"{"ack":1,"ack":2}"#).contains("duplicate field"));
        assert!(malformed(r#"{"acks":1}"#).contains("unknown field"));
        assert!(malformed("[2, null, null, null]").contains("JSON object"));
        assert!(malformed("ack").contains("JSON object"));
        assert!(malformed("").contains("JSON object"));
        for text in [r#"{}"#, r#"{"request":false}"#, r#"{"ack":1,"request":true}"#, r#"{"mode":"asap","rate_hz":5}"#] {
            assert_eq!(decode(text), Err(MessageError::Unknown { text: text.into() }), "{text}");
        }
        let long = format!("{{\"ack\":1{}}}", " ".repeat(MAX_MESSAGE_BYTES));
        assert_eq!(decode(&long), Err(MessageError::TooLong { bytes: long.len() }));
    }
}

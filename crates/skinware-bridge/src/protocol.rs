//! What a remote skinware reader needs, on zenoh keys under `skinware/<skin>`:
//!
//! | key | what | encoding |
//! |---|---|---|
//! | `skinware/<skin>/@channels` | queryable: every bridged channel and its description | [`ChannelList`] (`SKBCHL01`) |
//! | `skinware/<skin>/@geometry` | queryable: the skin's geometry file | the file, byte for byte |
//! | `skinware/<skin>/<channel>/frame` | every frame the bridge sends | `skinware_msgs/SkinFrame` CDR, as in a recording |
//! | `skinware/<skin>/<channel>/state` | the writer's state, 10 times a second | [`ChannelState`] (`SKBSTA01`) |
//! | `skinware/<skin>/<channel>/request` | queryable: one frame acquired on request | `SkinFrame` CDR |
//! | `skinware/<skin>/<channel>/readers/<zid>` | what a remote reader received, once a second | [`ReaderReport`] (`SKBRRP01`) |
//! | `skinware/<skin>/@bridge` | the bridge's liveliness token | |
//!
//! Every decoder here takes bytes from the network, so none trusts them: any
//! input ends in a value or a [`BridgeError::Malformed`] naming the key and
//! the problem.

use std::time::Duration;

use skinware::wire::{Decoder, Encoder};
use skinware::{ChannelKind, WriterState};
use skinware_ros2::{SkinFrame, SkinFrameRef, ros_time};

use crate::BridgeError;

/// The bridge's TCP send buffer: 64 KiB (the kernel doubles it), a
/// millisecond at 1 Gbit/s, enough for a LAN; a slow link then holds back
/// about a second at 1 Mbit/s instead of many (raise it for long, fast links).
pub const BRIDGE_SEND_BUFFER: usize = 64 << 10;

/// How the bridge begins its answer to a request that timed out (the writer
/// gave no frame in time), so that the asker reports a timeout, not a fault.
pub const TIMEOUT_PREFIX: &str = "timeout: ";

/// The root of every key of skin `skin`.
pub fn skin_prefix(skin: &str) -> String {
    format!("skinware/{skin}")
}

/// The queryable that lists the bridged channels.
pub fn channels_key(skin: &str) -> String {
    format!("skinware/{skin}/@channels")
}

/// The queryable that serves the geometry file.
pub fn geometry_key(skin: &str) -> String {
    format!("skinware/{skin}/@geometry")
}

/// Where `channel`'s frames are published.
pub fn frame_key(skin: &str, channel: &str) -> String {
    format!("skinware/{skin}/{channel}/frame")
}

/// Where `channel`'s state is published.
pub fn state_key(skin: &str, channel: &str) -> String {
    format!("skinware/{skin}/{channel}/state")
}

/// The queryable that acquires one frame of `channel` on request.
pub fn request_key(skin: &str, channel: &str) -> String {
    format!("skinware/{skin}/{channel}/request")
}

/// Where a remote reader of `channel` reports what it received, once a
/// second (`reader` is its zenoh session id), so that the bridge sees what
/// the link lost.
pub fn reader_report_key(skin: &str, channel: &str, reader: &str) -> String {
    format!("skinware/{skin}/{channel}/readers/{reader}")
}

/// The liveliness token of a bridge serving `skin`.
pub fn bridge_token_key(skin: &str) -> String {
    format!("skinware/{skin}/@bridge")
}

/// One bridged channel: what a remote reader needs to read it like a local one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RemoteChannel {
    /// The channel's name.
    pub name: String,
    /// Layer or service.
    pub kind: ChannelKind,
    /// Bytes per frame.
    pub payload_bytes: usize,
    /// The writer's frame buffers (a mirror uses as many).
    pub slots: usize,
    /// The writer's period, or `None` for a sporadic writer.
    pub period: Option<Duration>,
    /// Payload schema name and version.
    pub schema: (String, u32),
    /// The channel's description: a layer's topology, a service's labels.
    pub description: Vec<u8>,
}

/// The answer of the `@channels` queryable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ChannelList {
    /// The skin.
    pub skin: String,
    /// Its bridged channels.
    pub channels: Vec<RemoteChannel>,
}

const CHANNEL_LIST_MAGIC: &[u8; 8] = b"SKBCHL01";
const CHANNEL_STATE_MAGIC: &[u8; 8] = b"SKBSTA01";

fn kind_code(kind: ChannelKind) -> u32 {
    match kind {
        ChannelKind::Layer => 1,
        ChannelKind::Service => 2,
    }
}

impl ChannelList {
    /// Its bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::new(CHANNEL_LIST_MAGIC);
        out.str(&self.skin);
        out.count(self.channels.len());
        for channel in &self.channels {
            out.str(&channel.name);
            out.u32(kind_code(channel.kind));
            out.u64(channel.payload_bytes as u64);
            out.u64(channel.slots as u64);
            out.u64(channel.period.map_or(0, |p| p.as_nanos() as u64));
            out.str(&channel.schema.0);
            out.u32(channel.schema.1);
            out.bytes(&channel.description);
        }
        out.finish()
    }

    /// Reads a list; any bytes give a list or an error.
    pub fn decode(bytes: &[u8]) -> Result<ChannelList, BridgeError> {
        let malformed = |e: skinware::wire::DecodeError| BridgeError::Malformed {
            what: "channel list".into(),
            reason: e.to_string(),
        };
        let mut input = Decoder::new(bytes, "channel list", CHANNEL_LIST_MAGIC).map_err(malformed)?;
        let skin = input.str("skin").map_err(malformed)?;
        // Names become key expressions and, in a mirror, file names: only skinware's own.
        let named = |what: &'static str, name: &str| {
            skinware::shm::validate_name(what, name)
                .map_err(|e| BridgeError::Malformed { what: "channel list".into(), reason: e.to_string() })
        };
        named("skin", &skin)?;
        // name, kind, three u64s, schema, version, description: at least 44 bytes each.
        let count = input.count("channels", 44).map_err(malformed)?;
        let mut channels = Vec::with_capacity(count);
        for _ in 0..count {
            let name = input.str("channel name").map_err(malformed)?;
            named("channel", &name)?;
            let kind = match input.u32("kind").map_err(malformed)? {
                1 => ChannelKind::Layer,
                2 => ChannelKind::Service,
                other => {
                    return Err(malformed(
                        input.invalid("kind", format!("{other} is neither 1 (layer) nor 2 (service)")),
                    ));
                }
            };
            let payload_bytes = input.u64("payload bytes").map_err(malformed)?;
            let slots = input.u64("slots").map_err(malformed)?;
            let period_ns = input.u64("period").map_err(malformed)?;
            let schema_name = input.str("schema name").map_err(malformed)?;
            let schema_version = input.u32("schema version").map_err(malformed)?;
            let description = input.bytes("description").map_err(malformed)?.to_vec();
            let too_big = |what: &str, value: u64, limit: u64| BridgeError::Malformed {
                what: "channel list".into(),
                reason: format!("channel {name:?}: {what} {value} is beyond {limit}"),
            };
            if payload_bytes > MAX_FRAME_BYTES as u64 {
                return Err(too_big("payload bytes", payload_bytes, MAX_FRAME_BYTES as u64));
            }
            if slots > skinware::MAX_SLOTS as u64 {
                return Err(too_big("slots", slots, skinware::MAX_SLOTS as u64));
            }
            channels.push(RemoteChannel {
                name,
                kind,
                payload_bytes: payload_bytes as usize,
                slots: slots as usize,
                period: (period_ns > 0).then(|| Duration::from_nanos(period_ns)),
                schema: (schema_name, schema_version),
                description,
            });
        }
        input.finish().map_err(malformed)?;
        Ok(ChannelList { skin, channels })
    }
}

/// The largest frame a remote reader accepts (a skin of 8 million taxels).
pub const MAX_FRAME_BYTES: usize = 16 << 20;

/// A channel's state as the bridge sees it, sent 10 times a second, so that
/// its absence says the link is cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelState {
    /// The writer's state.
    pub state: WriterState,
    /// The writer's newest sequence number.
    pub published_seq: u64,
    /// Frames the bridge sent.
    pub sent: u64,
    /// Frames the writer published that the bridge did not send (it was
    /// rate-limited by `--max-hz`, or the link was slower than the writer).
    pub dropped: u64,
    /// Mean time from acquisition to the bridge handing the frame to zenoh, ns.
    pub latency_ns: u64,
    /// The writer's period, ns, or 0.
    pub period_ns: u64,
}

impl ChannelState {
    /// Its bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::with_capacity(CHANNEL_STATE_MAGIC, 60);
        out.u32(self.state.code());
        out.u64(self.published_seq);
        out.u64(self.sent);
        out.u64(self.dropped);
        out.u64(self.latency_ns);
        out.u64(self.period_ns);
        out.finish()
    }

    /// Reads a state; any bytes give a state or an error.
    pub fn decode(bytes: &[u8]) -> Result<ChannelState, BridgeError> {
        let malformed = |e: skinware::wire::DecodeError| BridgeError::Malformed {
            what: "channel state".into(),
            reason: e.to_string(),
        };
        let mut input = Decoder::new(bytes, "channel state", CHANNEL_STATE_MAGIC).map_err(malformed)?;
        let code = input.u32("state").map_err(malformed)?;
        let Some(state) = WriterState::from_number(code) else {
            return Err(malformed(input.invalid("state", format!("{code} is not a writer state (1 to 4)"))));
        };
        let state = ChannelState {
            state,
            published_seq: input.u64("published seq").map_err(malformed)?,
            sent: input.u64("sent").map_err(malformed)?,
            dropped: input.u64("dropped").map_err(malformed)?,
            latency_ns: input.u64("latency").map_err(malformed)?,
            period_ns: input.u64("period").map_err(malformed)?,
        };
        input.finish().map_err(malformed)?;
        Ok(state)
    }
}

/// What a remote reader received since it started: the bridge adds it up
/// per channel, so that frames lost on the link show on the robot PC too.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReaderReport {
    /// Frames received.
    pub received: u64,
    /// Frames of the writer never received (sequence gaps).
    pub skipped: u64,
    /// Of those, the frames the bridge sent: lost on the link, or dropped by
    /// zenoh when the link was full (the rest the bridge never sent).
    pub lost: u64,
    /// Messages refused as malformed.
    pub malformed: u64,
    /// Mean acquisition-to-receipt time over the last second, ns.
    pub latency_ns: u64,
}

const READER_REPORT_MAGIC: &[u8; 8] = b"SKBRRP01";

impl ReaderReport {
    /// Its bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::with_capacity(READER_REPORT_MAGIC, 56);
        out.u64(self.received);
        out.u64(self.skipped);
        out.u64(self.lost);
        out.u64(self.malformed);
        out.u64(self.latency_ns);
        out.finish()
    }

    /// Reads a report; any bytes give a report or an error.
    pub fn decode(bytes: &[u8]) -> Result<ReaderReport, BridgeError> {
        let malformed = |e: skinware::wire::DecodeError| BridgeError::Malformed {
            what: "reader report".into(),
            reason: e.to_string(),
        };
        let mut input = Decoder::new(bytes, "reader report", READER_REPORT_MAGIC).map_err(malformed)?;
        let report = ReaderReport {
            received: input.u64("received").map_err(malformed)?,
            skipped: input.u64("skipped").map_err(malformed)?,
            lost: input.u64("lost").map_err(malformed)?,
            malformed: input.u64("malformed").map_err(malformed)?,
            latency_ns: input.u64("latency").map_err(malformed)?,
        };
        input.finish().map_err(malformed)?;
        Ok(report)
    }
}

/// Encodes one frame of a channel as a `SkinFrame` (a layer's responses, or a service's bytes).
pub fn encode_frame(
    kind: ChannelKind,
    frame: &skinware::Frame<'_>,
    wall_offset_ns: i64,
) -> Result<Vec<u8>, BridgeError> {
    let (responses, payload): (&[u16], &[u8]) = match kind {
        ChannelKind::Layer => (frame.responses(), &[]),
        ChannelKind::Service => (&[], frame.bytes()),
    };
    let message = SkinFrameRef {
        stamp: ros_time(frame.acquired_ns(), wall_offset_ns),
        published: ros_time(frame.published_ns(), wall_offset_ns),
        seq: frame.seq(),
        status: frame.status().0,
        skipped: frame.skipped(),
        responses,
        payload,
    };
    Ok(skinware_ros2::encode(&message, 64 + frame.bytes().len())?)
}

/// Decodes a frame of `channel`, checking it against the channel's frame size.
pub fn decode_frame(channel: &RemoteChannel, bytes: &[u8]) -> Result<SkinFrame, BridgeError> {
    let frame: SkinFrame = skinware_ros2::decode(bytes, "SkinFrame")
        .map_err(|e| BridgeError::Malformed { what: format!("frame of {}", channel.name), reason: e.to_string() })?;
    let size = match channel.kind {
        ChannelKind::Layer if frame.payload.is_empty() => frame.responses.len() * 2,
        ChannelKind::Service if frame.responses.is_empty() => frame.payload.len(),
        _ => {
            return Err(BridgeError::Malformed {
                what: format!("frame of {}", channel.name),
                reason: "a layer's frame carries responses only, a service's payload only".into(),
            });
        }
    };
    if size != channel.payload_bytes {
        return Err(BridgeError::Malformed {
            what: format!("frame of {}", channel.name),
            reason: format!("{size} bytes where the channel's frames are {}", channel.payload_bytes),
        });
    }
    Ok(frame)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn layer() -> RemoteChannel {
        RemoteChannel {
            name: "virtual-0".into(),
            kind: ChannelKind::Layer,
            payload_bytes: 6,
            slots: 4,
            period: Some(Duration::from_millis(20)),
            schema: ("skinware.layer".into(), 1),
            description: vec![1, 2, 3],
        }
    }

    #[test]
    fn lists_and_states_round_trip() {
        let list = ChannelList { skin: "default".into(), channels: vec![layer()] };
        assert_eq!(ChannelList::decode(&list.encode()).unwrap(), list);
        let state = ChannelState {
            state: WriterState::Faulted,
            published_seq: 9,
            sent: 8,
            dropped: 1,
            latency_ns: 1000,
            period_ns: 20_000_000,
        };
        assert_eq!(ChannelState::decode(&state.encode()).unwrap(), state);
        let report = ReaderReport { received: 5, skipped: 2, lost: 1, malformed: 1, latency_ns: 3 };
        assert_eq!(ReaderReport::decode(&report.encode()).unwrap(), report);
    }

    #[test]
    fn a_frame_of_the_wrong_size_or_kind_is_refused() {
        let frame = |responses: Vec<u16>, payload: Vec<u8>| {
            skinware_ros2::encode(
                &SkinFrameRef {
                    stamp: skinware_ros2::Time::default(),
                    published: skinware_ros2::Time::default(),
                    seq: 1,
                    status: 0,
                    skipped: 0,
                    responses: &responses,
                    payload: &payload,
                },
                0,
            )
            .unwrap()
        };
        assert_eq!(decode_frame(&layer(), &frame(vec![1, 2, 3], vec![])).unwrap().responses, [1, 2, 3]);
        let short = decode_frame(&layer(), &frame(vec![1, 2], vec![])).unwrap_err().to_string();
        assert!(short.contains("4 bytes where the channel's frames are 6"), "{short}");
        assert!(decode_frame(&layer(), &frame(vec![], vec![1; 6])).is_err());
    }

    #[test]
    fn a_list_with_a_name_that_is_not_a_skinware_name_is_refused() {
        // A hostile bridge's name would become a key with wildcards, or a path.
        for bad in ["a/b", "a*", "../x", ""] {
            let mut channel = layer();
            channel.name = bad.into();
            let list = ChannelList { skin: "default".into(), channels: vec![channel] };
            assert!(ChannelList::decode(&list.encode()).is_err(), "{bad:?}");
        }
        assert!(ChannelList::decode(&ChannelList { skin: "a*".into(), channels: vec![] }.encode()).is_err());
    }

    proptest! {
        #[test]
        fn any_bytes_decode_to_a_value_or_an_error(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = ChannelList::decode(&bytes);
            let _ = ChannelState::decode(&bytes);
            let _ = ReaderReport::decode(&bytes);
            let _ = decode_frame(&layer(), &bytes);
        }

        #[test]
        fn damaged_lists_never_panic(flip in 0usize..200, value: u8) {
            let mut bytes = ChannelList { skin: "s".into(), channels: vec![layer(), layer()] }.encode();
            let at = flip % bytes.len();
            bytes[at] = value;
            let _ = ChannelList::decode(&bytes);
        }
    }
}

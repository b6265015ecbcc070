//! What remote readers ask for: the channel list and the geometry, and a
//! frame on request, each answered from a thread of the bridge (a reply
//! waits for room on a slow link, which must never block zenoh's own
//! threads, as a reply from a callback would).

use std::sync::Arc;
use std::time::Duration;

use skinware::{Error, Reader, lock};
use skinware_geometry::SkinGeometry;
use zenoh::Wait;

use super::Shared;
use super::channel::Channel;
use crate::BridgeError;
use crate::protocol::{self, ChannelList};

/// The channel list and the geometry, answered from a thread of the bridge:
/// a reply waits for room on a slow link, which must never block zenoh's own
/// threads (as a reply from a callback would).
pub(super) fn serve_descriptions(shared: &Arc<Shared>) -> Result<(), BridgeError> {
    let skin = &shared.options.skin;
    let zenoh = |what: &str, e: zenoh::Error| BridgeError::Zenoh(format!("cannot declare {what}: {e}"));
    let channels = shared
        .session
        .declare_queryable(protocol::channels_key(skin))
        .wait()
        .map_err(|e| zenoh("the channel list", e))?;
    let geometry =
        shared.session.declare_queryable(protocol::geometry_key(skin)).wait().map_err(|e| zenoh("the geometry", e))?;
    while !shared.stop.is_stopped() {
        if let Ok(Some(query)) = channels.recv_timeout(Duration::from_millis(50)) {
            let list = ChannelList {
                skin: skin.clone(),
                channels: lock(&shared.channels).values().map(|c| c.info.clone()).collect(),
            };
            let _ = query.reply(query.key_expr().clone(), list.encode()).wait();
        }
        while let Ok(Some(query)) = geometry.try_recv() {
            let path = SkinGeometry::published_path(&shared.dir, skin);
            let _ = match skinware::shm::read_regular(&path, SkinGeometry::MAX_PUBLISHED_BYTES) {
                Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
                Err(e) => query
                    .reply_err(format!(
                        "the skin publishes no geometry ({}: {e}); its layers can still be read",
                        path.display()
                    ))
                    .wait(),
            };
        }
    }
    Ok(())
}

/// Frames on request for one channel: its own thread and reader, so that a
/// request waiting for a slow or sporadic writer delays no other channel's.
pub(super) fn serve_requests(shared: &Arc<Shared>, channel: &Channel) {
    let skin = &shared.options.skin;
    let name = &channel.info.name;
    let mut reader: Option<Reader> = None;
    while !shared.stop.is_stopped() {
        let Some(query) = channel.requests.pop(Duration::from_millis(100)) else { continue };
        if reader.is_none() {
            match Reader::open_with(skin, name, &shared.reader_options()) {
                Ok(mut opened) => {
                    opened.set_stop(&shared.stop);
                    reader = Some(opened);
                }
                Err(e) => {
                    let _ = query.reply_err(format!("error: cannot read {skin}/{name}: {e}")).wait();
                    continue;
                }
            }
        }
        let Some(reader) = reader.as_mut() else { continue };
        let timeout = query
            .parameters()
            .get("timeout_ms")
            .and_then(|t| t.parse::<u64>().ok())
            .map_or(Duration::from_secs(1), Duration::from_millis)
            .min(Duration::from_secs(10));
        let answer = match reader.request(timeout) {
            Ok(frame) => protocol::encode_frame(channel.info.kind, &frame, shared.clock_offset_ns)
                .map_err(|e| format!("error: {e}")),
            Err(e @ (Error::Timeout { .. } | Error::WriterGone { .. })) => {
                Err(format!("{}{e}", protocol::TIMEOUT_PREFIX))
            }
            Err(e) => Err(format!("error: {e}")),
        };
        let _ = match answer {
            Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
            Err(e) => query.reply_err(e).wait(),
        };
    }
}

/// Routes each request to its channel's queue, from zenoh's thread, without waiting.
pub(super) fn declare_requests(shared: &Arc<Shared>) -> Result<zenoh::query::Queryable<()>, BridgeError> {
    let weak = Arc::downgrade(shared);
    shared
        .session
        .declare_queryable(format!("{}/*/request", protocol::skin_prefix(&shared.options.skin)))
        .callback(move |query: zenoh::query::Query| {
            let Some(shared) = weak.upgrade() else { return };
            let name = query.key_expr().as_str().rsplit('/').nth(1).unwrap_or_default().to_owned();
            let channel = lock(&shared.channels).get(&name).cloned();
            // An unknown channel's query is dropped: its asker times out and
            // says the channel is not bridged (it checked the list first).
            if let Some(channel) = channel {
                channel.requests.push(query);
            }
        })
        .wait()
        .map_err(|e| BridgeError::Zenoh(format!("cannot declare the request queryable: {e}")))
}

//! What a remote reader takes from the network: a bridge's channel list,
//! a channel's state, a frame, an rmw_zenoh attachment. Any bytes give a
//! value or an error; a decoded list or state encodes back to itself.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_bridge::protocol::{ChannelList, ChannelState, decode_frame};
use skinware_bridge::rmw_zenoh::Attachment;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(list) = ChannelList::decode(bytes) {
        assert_eq!(ChannelList::decode(&list.encode()).ok().as_ref(), Some(&list));
        for channel in &list.channels {
            let _ = decode_frame(channel, bytes);
        }
    }
    if let Ok(state) = ChannelState::decode(bytes) {
        assert_eq!(ChannelState::decode(&state.encode()).ok(), Some(state));
    }
    if let Ok(attachment) = Attachment::decode(bytes) {
        assert_eq!(&attachment.encode()[..], bytes);
    }
});

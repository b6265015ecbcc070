//! What runs here: the skins whose channels are in the segment directory,
//! for the errors of the commands given a skin (`--skin`) or a channel that
//! is not there. Listing every skin asks their writers, so this is done only
//! once a command has found nothing.

use anyhow::{Result, anyhow};
use skinware::{ChannelInfo, ChannelKind, WriterState};

/// How to start a skin, for the messages that find none.
pub const HOW_TO_START: &str =
    "start one with `skin run CONFIG` (examples/), `skin demo`, or `skin replay FILE.mcap` (a recording)";

/// At most this many names in a list of layers or skins.
const LISTED: usize = 20;

/// One skin with channels here.
pub struct Skin {
    /// Its name.
    pub name: String,
    /// Its layers.
    pub layers: Vec<String>,
    /// Its services' channels.
    pub services: Vec<String>,
    /// Whether any of its writers is alive (else its channels are left over).
    pub live: bool,
}

impl Skin {
    /// `default (5 layers, 3 services)`, or `old (stopped: ...)`.
    fn describe(&self) -> String {
        let count = |n: usize, what: &str| format!("{n} {what}{}", if n == 1 { "" } else { "s" });
        let mut parts = vec![count(self.layers.len(), "layer")];
        if !self.services.is_empty() {
            parts.push(count(self.services.len(), "service"));
        }
        if !self.live {
            parts.push("stopped: its writers are gone, `skin clean` removes what they left".into());
        }
        format!("{} ({})", self.name, parts.join(", "))
    }
}

/// Every skin with a channel in the segment directory, sorted by name.
pub fn all() -> Result<Vec<Skin>> {
    let dir = skinware::shm::segment_dir();
    Ok(group(&skinware::list_channels(&dir)?))
}

/// The skins of `channels` (sorted by skin, as listings are).
fn group(channels: &[ChannelInfo]) -> Vec<Skin> {
    let mut skins: Vec<Skin> = Vec::new();
    for channel in channels {
        if skins.last().is_none_or(|s| s.name != channel.skin) {
            skins.push(Skin { name: channel.skin.clone(), layers: vec![], services: vec![], live: false });
        }
        let skin = skins.last_mut().expect("pushed above");
        match channel.kind {
            Some(ChannelKind::Layer) => skin.layers.push(channel.channel.clone()),
            Some(ChannelKind::Service) => skin.services.push(channel.channel.clone()),
            None => {}
        }
        skin.live |= channel.state != WriterState::Gone;
    }
    skins
}

/// The error for `skin`, named on the command line, of which no channel is
/// here: the skins that are (with a did-you-mean), or that none is and how
/// to start one.
pub fn missing_skin(skin: &str) -> anyhow::Error {
    let dir = skinware::shm::segment_dir();
    let skins = match all() {
        Ok(skins) => skins,
        Err(e) => return anyhow!("skin {skin} is not running here (cannot list {}: {e})", dir.display()),
    };
    missing_skin_among(skin, &skins, &dir, None)
}

/// [`missing_skin`] among `skins`; `hint` (ending in "; ") replaces the
/// guess of a close skin name.
fn missing_skin_among(skin: &str, skins: &[Skin], dir: &std::path::Path, hint: Option<String>) -> anyhow::Error {
    if skins.is_empty() {
        return anyhow!(
            "skin {skin} is not running here, and no other is (no channel in {}); {HOW_TO_START}",
            dir.display()
        );
    }
    let guess = hint.unwrap_or_else(|| {
        skin::suggest::closest(skin, skins.iter().map(|s| s.name.as_str()))
            .map(|close| format!("did you mean --skin {close}? "))
            .unwrap_or_default()
    });
    let listed: Vec<String> = skins.iter().map(Skin::describe).collect();
    anyhow!(
        "skin {skin} is not running here (no channel of it in {}); {guess}the skins here: {}",
        dir.display(),
        skin::suggest::list(&listed, LISTED)
    )
}

/// The error for a skin whose geometry could not be opened: the library's
/// (which names the commands that publish one), and if `skin` is not
/// running, the skins that are.
pub fn missing_geometry(skin: &str, error: skinware_geometry::GeometryError) -> anyhow::Error {
    if !matches!(error, skinware_geometry::GeometryError::Missing { .. }) {
        return error.into();
    }
    let skins = all().unwrap_or_default();
    if skins.iter().any(|s| s.name == skin) {
        return anyhow!("{error}; skin {skin} runs, but not from one of them");
    }
    if skins.is_empty() {
        return anyhow!("{error}; no skin runs here");
    }
    let guess = skin::suggest::closest(skin, skins.iter().map(|s| s.name.as_str()))
        .map(|close| format!("did you mean --skin {close}? "))
        .unwrap_or_default();
    let listed: Vec<String> = skins.iter().map(Skin::describe).collect();
    anyhow!("{error}; {guess}the skins here: {}", skin::suggest::list(&listed, LISTED))
}

/// The error for `channel` of `skin`, a `kind` channel named on the command
/// line that is not there: the skin's channels of that kind (with a
/// did-you-mean), the skin that has it if another does, or that the skin
/// itself is not here.
pub fn missing_channel(skin: &str, channel: &str, kind: ChannelKind) -> anyhow::Error {
    let dir = skinware::shm::segment_dir();
    let skins = match all() {
        Ok(skins) => skins,
        Err(e) => return anyhow!("no {} {skin}/{channel} (cannot list {}: {e})", kind.as_str(), dir.display()),
    };
    let elsewhere: Vec<&str> = skins
        .iter()
        .filter(|s| s.name != skin && (s.layers.iter().chain(&s.services)).any(|c| c == channel))
        .map(|s| s.name.as_str())
        .collect();
    let Some(found) = skins.iter().find(|s| s.name == skin) else {
        let hint = elsewhere.first().map(|other| format!("skin {other} has a {channel}: add --skin {other}; "));
        return missing_skin_among(skin, &skins, &dir, hint);
    };
    let (same, other) = match kind {
        ChannelKind::Layer => (&found.layers, &found.services),
        ChannelKind::Service => (&found.services, &found.layers),
    };
    if other.iter().any(|c| c == channel) {
        let other_kind = if kind == ChannelKind::Layer { "a service" } else { "a layer" };
        return anyhow!("{skin}/{channel} is {other_kind}, not a {}", kind.as_str());
    }
    let hint = match (elsewhere.first(), skin::suggest::closest(channel, same.iter().map(String::as_str))) {
        (Some(other), _) => format!("skin {other} has one: add --skin {other}; "),
        (None, Some(close)) => format!("did you mean {close}? "),
        (None, None) => String::new(),
    };
    let listing = if same.is_empty() { "none".to_owned() } else { skin::suggest::list(same, LISTED) };
    anyhow!("skin {skin} has no {} {channel}; {hint}its {}s: {listing}", kind.as_str(), kind.as_str())
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    fn skin(name: &str, layers: &[&str], live: bool) -> Skin {
        Skin {
            name: name.into(),
            layers: layers.iter().map(|l| (*l).to_owned()).collect(),
            services: vec!["contact".into()],
            live,
        }
    }

    #[test]
    fn a_missing_skin_lists_the_others_and_guesses_a_close_one() {
        let skins = [skin("default", &["virtual-0", "virtual-1"], true), skin("icub", &["torso"], false)];
        let err = missing_skin_among("defualt", &skins, Path::new("/dev/shm"), None).to_string();
        assert_eq!(
            err,
            "skin defualt is not running here (no channel of it in /dev/shm); did you mean --skin default? the skins here: \
             default (2 layers, 1 service), icub (1 layer, 1 service, stopped: its writers are gone, `skin clean` removes what they left)"
        );
        let err = missing_skin_among("nosuch", &skins, Path::new("/dev/shm"), None).to_string();
        assert!(err.contains("(no channel of it in /dev/shm); the skins here: default"), "{err}");
        let err = missing_skin_among("nosuch", &[], Path::new("/dev/shm"), None).to_string();
        assert!(err.contains("no other is (no channel in /dev/shm); start one with `skin run CONFIG`"), "{err}");
        assert!(err.contains("`skin demo`"), "{err}");
    }
}

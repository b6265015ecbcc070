//! The soak's observer: one reader per channel (every layer and service),
//! in a thread of the soak process, that notes when each channel publishes.
//! From it the soak knows when every layer runs again after a fault (each
//! has published a frame after a given moment) and whether a layer was
//! publishing while a verifying reader got nothing (a stuck reader).

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use skinware::{Reader, ReaderOptions, RtOptions, Stop};

/// How often the observer looks at every channel.
const POLL_NS: u64 = 5_000_000;
/// How long it remembers each channel's publications.
const REMEMBER_NS: u64 = 30_000_000_000;
/// The shortest pause between frames taken for a channel that stopped publishing.
const MIN_PAUSE_NS: u64 = 250_000_000;

/// Since when `channel` (whose frames were `published`, in order) has
/// been publishing without a pause longer than `pause_ns`, counting only
/// frames after `from_ns`; `None` if it published none after `from_ns` or
/// has paused since its last frame (at `now_ns`).
pub fn publishing_since(published: &[u64], from_ns: u64, now_ns: u64, pause_ns: u64) -> Option<u64> {
    let mut frames = published.iter().copied().filter(|&ns| ns > from_ns);
    let mut since = frames.next()?;
    let mut last = since;
    for ns in frames {
        if ns.saturating_sub(last) > pause_ns {
            since = ns;
        }
        last = ns;
    }
    (now_ns.saturating_sub(last) <= pause_ns).then_some(since)
}

/// The longest run of `channel`'s frames (`published`, in order) strictly
/// between `from_ns` and `to_ns` without a pause longer than `pause_ns`:
/// from its first frame to its last, ns (0 for fewer than two frames). A
/// reader whose pause between frames held such a run of more than a few
/// periods could have had its frames and did not.
pub fn longest_run_within(published: &[u64], from_ns: u64, to_ns: u64, pause_ns: u64) -> u64 {
    let mut frames = published.iter().copied().filter(|&ns| ns > from_ns && ns < to_ns);
    let Some(first) = frames.next() else { return 0 };
    let (mut since, mut last, mut longest) = (first, first, 0);
    for ns in frames {
        if ns.saturating_sub(last) > pause_ns {
            since = ns;
        }
        last = ns;
        longest = longest.max(last.saturating_sub(since));
    }
    longest
}

/// One channel as the observer last saw it.
#[derive(Clone, Debug, Default)]
struct ChannelView {
    name: String,
    is_layer: bool,
    /// When its frames were published (CLOCK_MONOTONIC ns), the last
    /// [`REMEMBER_NS`] of them, oldest first.
    published: VecDeque<u64>,
    /// The publication time of its first frame after the mark.
    first_after_mark: Option<u64>,
    /// The longest pause between two frames of a channel that still
    /// publishes (three periods, at least 250 ms), ns.
    pause_ns: u64,
}

#[derive(Default)]
struct Views {
    channels: Vec<ChannelView>,
    mark_ns: u64,
}

/// When every layer, and every layer and service, published again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recovered {
    /// The latest of the layers' first frames after the mark (CLOCK_MONOTONIC ns).
    pub layers_ns: u64,
    /// The same over the layers and the services, if all of them published.
    pub all_ns: Option<u64>,
}

/// The observer thread and what it saw.
pub struct Observer {
    views: Arc<Mutex<Views>>,
    stop: Stop,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Why a real-time priority was refused, if it was.
    pub rt_refused: Vec<String>,
}

impl Observer {
    /// Starts observing `layers` and `services` of `skin` in `dir`.
    pub fn start(skin: &str, dir: PathBuf, layers: &[String], services: &[String]) -> Observer {
        let channels: Vec<ChannelView> = layers
            .iter()
            .map(|name| (name, true))
            .chain(services.iter().map(|name| (name, false)))
            .map(|(name, is_layer)| ChannelView {
                name: name.clone(),
                is_layer,
                pause_ns: MIN_PAUSE_NS,
                ..ChannelView::default()
            })
            .collect();
        let views = Arc::new(Mutex::new(Views { channels, mark_ns: u64::MAX }));
        let stop = Stop::new();
        let (refusals_tx, refusals_rx) = std::sync::mpsc::channel();
        let thread = {
            let (views, stop, skin) = (views.clone(), stop.clone(), skin.to_owned());
            std::thread::Builder::new()
                .name("soak-observer".into())
                .spawn(move || {
                    // Above the CPU hog, so that the observer sees frames when
                    // they come; the times it records are the writers' own.
                    let _ = refusals_tx.send(RtOptions { fifo_priority: Some(50), ..RtOptions::default() }.apply());
                    observe(&skin, &dir, &views, &stop);
                })
                .ok()
        };
        let rt_refused = refusals_rx.recv_timeout(Duration::from_secs(5)).unwrap_or_default();
        Observer { views, stop, thread, rt_refused }
    }

    fn views(&self) -> std::sync::MutexGuard<'_, Views> {
        skinware::lock(&self.views)
    }

    /// From now on, note each channel's first frame published after `at_ns`.
    pub fn mark(&self, at_ns: u64) {
        let mut views = self.views();
        views.mark_ns = at_ns;
        for channel in &mut views.channels {
            channel.first_after_mark = channel.published.iter().copied().find(|&ns| ns > at_ns);
        }
    }

    /// When every layer (and every channel) had published after the mark,
    /// once every layer has.
    pub fn recovered(&self) -> Option<Recovered> {
        let views = self.views();
        let latest = |layers_only: bool| {
            views
                .channels
                .iter()
                .filter(|c| c.is_layer || !layers_only)
                .map(|c| c.first_after_mark)
                .try_fold(0u64, |latest, first| Some(latest.max(first?)))
        };
        Some(Recovered { layers_ns: latest(true)?, all_ns: latest(false) })
    }

    /// Frames `channel` published strictly between `from_ns` and `to_ns`.
    pub fn published_between(&self, channel: &str, from_ns: u64, to_ns: u64) -> usize {
        let views = self.views();
        views
            .channels
            .iter()
            .find(|c| c.name == channel)
            .map_or(0, |c| c.published.iter().filter(|&&ns| ns > from_ns && ns < to_ns).count())
    }

    /// The longest run of frames `channel` published between `from_ns` and
    /// `to_ns` without pausing (see [`longest_run_within`]), ns.
    pub fn longest_run_within(&self, channel: &str, from_ns: u64, to_ns: u64) -> u64 {
        let views = self.views();
        let Some(view) = views.channels.iter().find(|c| c.name == channel) else { return 0 };
        let published: Vec<u64> = view.published.iter().copied().collect();
        longest_run_within(&published, from_ns, to_ns, view.pause_ns)
    }

    /// Since when `channel` has been publishing frames after `from_ns`
    /// without pausing (see [`publishing_since`]), if it is now.
    pub fn publishing_since(&self, channel: &str, from_ns: u64) -> Option<u64> {
        let views = self.views();
        let view = views.channels.iter().find(|c| c.name == channel)?;
        let published: Vec<u64> = view.published.iter().copied().collect();
        publishing_since(&published, from_ns, skinware::os::monotonic_ns(), view.pause_ns)
    }

    /// Whether every channel published after `from_ns`.
    pub fn all_published_since(&self, from_ns: u64) -> bool {
        self.views().channels.iter().all(|c| c.published.back().is_some_and(|&ns| ns > from_ns))
    }
}

impl Drop for Observer {
    fn drop(&mut self) {
        self.stop.stop();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A channel's reader in the observer and when it last got a new frame.
struct Watch {
    reader: Option<Reader>,
    last_new_ns: u64,
    next_open_ns: u64,
    stale_ns: u64,
}

fn observe(skin: &str, dir: &std::path::Path, views: &Mutex<Views>, stop: &Stop) {
    let names: Vec<String> = skinware::lock(views).channels.iter().map(|c| c.name.clone()).collect();
    let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
    let mut watches: Vec<Watch> =
        names.iter().map(|_| Watch { reader: None, last_new_ns: 0, next_open_ns: 0, stale_ns: 50_000_000 }).collect();
    let mut next = skinware::os::monotonic_ns();
    loop {
        next += POLL_NS;
        if !stop.sleep_until(next) {
            return;
        }
        let now = skinware::os::monotonic_ns();
        next = next.max(now);
        for (index, watch) in watches.iter_mut().enumerate() {
            if watch.reader.is_none() && now >= watch.next_open_ns {
                watch.next_open_ns = now + 100_000_000;
                if let Ok(reader) = Reader::open_with(skin, &names[index], &options) {
                    watch.stale_ns =
                        reader.writer_period().map_or(50_000_000, |p| 3 * p.as_nanos() as u64 / 2).max(10_000_000);
                    watch.reader = Some(reader);
                }
            }
            let Some(reader) = &mut watch.reader else { continue };
            let published = match reader.latest() {
                Ok(frame) if frame.is_fresh() => Some(frame.published_ns()),
                _ => None,
            };
            match published {
                Some(published_ns) => {
                    watch.last_new_ns = now;
                    let mut views = skinware::lock(views);
                    let mark = views.mark_ns;
                    let view = &mut views.channels[index];
                    view.published.push_back(published_ns);
                    while view.published.front().is_some_and(|&ns| ns + REMEMBER_NS < now) {
                        view.published.pop_front();
                    }
                    if published_ns > mark && view.first_after_mark.is_none() {
                        view.first_after_mark = Some(published_ns);
                    }
                }
                None => {
                    if now.saturating_sub(watch.last_new_ns) > watch.stale_ns {
                        reader.follow_recreated();
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{longest_run_within, publishing_since};

    const MS: u64 = 1_000_000;

    #[test]
    fn publishing_counts_from_the_start_of_the_current_run_of_frames() {
        // A frame 20 ms after the reader's last, a pause of 2.5 s (a dead
        // writer), then a successor every 25 ms.
        let mut published = vec![1_000 * MS, 1_020 * MS];
        published.extend((0..8).map(|i| 3_500 * MS + 25 * MS * i));
        let last = published.last().copied().unwrap();
        assert_eq!(publishing_since(&published, 1_000 * MS, last + 10 * MS, 250 * MS), Some(3_500 * MS));
        // Frames right after the reader's last one, still coming.
        assert_eq!(publishing_since(&published, 3_540 * MS, last, 250 * MS), Some(3_550 * MS));
        // Nothing after the reader's last frame, or a channel that has stopped.
        assert_eq!(publishing_since(&published, last, last + MS, 250 * MS), None);
        assert_eq!(publishing_since(&published, 1_000 * MS, last + 300 * MS, 250 * MS), None);
    }

    #[test]
    fn the_longest_run_within_a_readers_pause_is_measured_between_its_ends() {
        // A writer every 25 ms until 1 s, dead for 2.5 s, then a successor
        // every 25 ms for 3 s.
        let mut published: Vec<u64> = (0..40).map(|i| 25 * MS * i).collect();
        published.extend((0..120).map(|i| 3_500 * MS + 25 * MS * i));
        // The reader's pause covered the death and 1 s of the successor.
        assert_eq!(longest_run_within(&published, 900 * MS, 4_510 * MS, 250 * MS), 1_000 * MS);
        // It covered 2.4 s of the successor.
        assert_eq!(longest_run_within(&published, 3_000 * MS, 5_910 * MS, 250 * MS), 2_400 * MS);
        // Nothing in between, or one frame.
        assert_eq!(longest_run_within(&published, 1_000 * MS, 3_500 * MS, 250 * MS), 0);
        assert_eq!(longest_run_within(&published, 3_490 * MS, 3_510 * MS, 250 * MS), 0);
    }
}

//! `--chromium`: the viewer's page in a real headless Chromium during the
//! loaded run, in place of one of the emulated browsers. It measures what
//! the emulated ones cannot: whether the page, decoding and drawing every
//! update, keeps up (issue #41: "the viewer draws at ≥ 30 fps in headless
//! Chromium"). Chromium runs on the same cores as the skin, so its own CPU
//! is load on the skin as much as a measure of the page.

use std::time::Duration;

use anyhow::{Context, Result};
use serde::Serialize;
use serde_json::Value;

use crate::chromium::{Browser, PageRates, Programs, STATS_PROBE, wait_for};

/// The rate issue #41 asks of the page.
pub(super) const MIN_FPS: f64 = 30.0;

/// The viewer's page open in headless Chromium.
pub(super) struct ChromiumPage {
    browser: Browser,
}

impl ChromiumPage {
    /// Opens the viewer at `address` (host:port) and waits until the page
    /// has drawn an update (a skin of 100,000 taxels takes seconds to load
    /// on a busy machine).
    pub(super) fn open(programs: &Programs, address: &str) -> Result<ChromiumPage> {
        let browser = Browser::start(programs).context("cannot start headless Chromium for --chromium")?;
        let url = format!("http://{address}/");
        browser.open(&url).with_context(|| format!("Chromium cannot open the viewer's page {url}"))?;
        wait_for("the viewer's page to draw in Chromium", Duration::from_secs(120), || {
            let stats = browser.run(STATS_PROBE).ok()?;
            (stats["draws"].as_u64()? > 0 && stats["updates"].as_u64()? > 0).then_some(())
        })?;
        Ok(ChromiumPage { browser })
    }

    /// The page's counters now, for [`PageRates::between`].
    pub(super) fn counters(&self) -> Result<Value> {
        self.browser.run(STATS_PROBE).context("cannot read the page's counters from Chromium")
    }

    /// chromedriver's and Chromium's processes.
    pub(super) fn process_ids(&self) -> Vec<u32> {
        self.browser.process_ids()
    }
}

/// What the page in Chromium did over the measured window.
#[derive(Clone, Copy, Debug, Serialize)]
pub(super) struct ChromiumFigures {
    /// The page's own rates between the window's ends.
    #[serde(flatten)]
    pub(super) page: PageRates,
    /// chromedriver and every Chromium process, % of one core, from their
    /// utime + stime (also under their name in the phase's `cpu_percent`).
    pub(super) cpu_percent: f64,
    /// Whether the page drew at least [`MIN_FPS`] new updates a second.
    pub(super) meets_30_fps: bool,
}

impl ChromiumFigures {
    /// The figures of readings `before` and `after` of the page's counters,
    /// with Chromium's CPU.
    pub(super) fn new(before: &Value, after: &Value, cpu_percent: f64) -> ChromiumFigures {
        let page = PageRates::between(before, after);
        ChromiumFigures { page, cpu_percent, meets_30_fps: page.fps >= MIN_FPS }
    }
}

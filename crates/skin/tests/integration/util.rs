//! What the test modules share.

use std::sync::{Mutex, MutexGuard};

/// Held by each test that runs a whole skin. Those tests assert on timing
/// (no missed period, the page keeps up), and as separate test binaries they
/// never ran at the same time; in one binary the test threads would run them
/// side by side, so each takes this first.
pub fn one_skin_at_a_time() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    // A test that failed while holding it poisoned it; the others still run.
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

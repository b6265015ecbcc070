//! One way to take a lock whose last holder panicked, for every crate of
//! the workspace.

#![forbid(unsafe_code)]

use std::sync::{Mutex, MutexGuard, PoisonError};

/// Locks `mutex`, also when a thread panicked while holding it.
///
/// Skinware's locks guard data that stays consistent at every point a
/// panic could happen (single assignments, pushes, whole-value swaps), so a
/// poisoned lock still holds good data; refusing it would turn one
/// thread's panic into a panic of every thread that shares the value, and
/// a driver or reader must keep running.
pub fn lock<T: ?Sized>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

//! The one place atomics come from, so that `loom` can replace them in model
//! tests. `clippy.toml` forbids the standard library's atomic types and
//! `fence` everywhere else in this crate (`disallowed-types`,
//! `disallowed-methods`), as iceoryx2 does; this module wraps them in types of
//! its own (same layout, `#[repr(transparent)]`), which the lint tells apart.
//!
//! Under `--cfg loom` the protocol modules (`channel::ring`, `channel::copy`,
//! `channel::doorbell`) are compiled against loom's atomics instead and
//! checked exhaustively; everything that maps real shared memory or makes
//! system calls is compiled out.

#![forbid(unsafe_code)]

#[cfg(loom)]
pub(crate) use loom::sync::atomic::{AtomicU32, AtomicU64, Ordering, fence};

#[cfg(not(loom))]
pub(crate) use std::sync::atomic::Ordering;

#[cfg(not(loom))]
pub(crate) use real::{AtomicU32, AtomicU64, fence};

#[cfg(not(loom))]
#[allow(clippy::disallowed_types, clippy::disallowed_methods)]
mod real {
    use std::sync::atomic::Ordering;

    /// A memory fence (`std::sync::atomic::fence`).
    #[inline(always)]
    pub(crate) fn fence(order: Ordering) {
        std::sync::atomic::fence(order);
    }

    macro_rules! atomic {
        ($name:ident, $int:ty, $std:ty) => {
            /// The standard atomic of the same name, with the operations the
            /// exchange uses. Same size, alignment and bit validity, so it may
            /// be placed in shared memory exactly like the standard one.
            #[repr(transparent)]
            #[derive(Debug, Default)]
            pub(crate) struct $name($std);

            #[allow(dead_code)]
            impl $name {
                /// A new atomic holding `value`.
                pub(crate) const fn new(value: $int) -> Self {
                    Self(<$std>::new(value))
                }
                #[inline(always)]
                pub(crate) fn load(&self, order: Ordering) -> $int {
                    self.0.load(order)
                }
                #[inline(always)]
                pub(crate) fn store(&self, value: $int, order: Ordering) {
                    self.0.store(value, order)
                }
                #[inline(always)]
                pub(crate) fn swap(&self, value: $int, order: Ordering) -> $int {
                    self.0.swap(value, order)
                }
                #[inline(always)]
                pub(crate) fn fetch_add(&self, value: $int, order: Ordering) -> $int {
                    self.0.fetch_add(value, order)
                }
                #[inline(always)]
                pub(crate) fn fetch_or(&self, value: $int, order: Ordering) -> $int {
                    self.0.fetch_or(value, order)
                }
                #[inline(always)]
                pub(crate) fn compare_exchange(
                    &self,
                    current: $int,
                    new: $int,
                    success: Ordering,
                    failure: Ordering,
                ) -> Result<$int, $int> {
                    self.0.compare_exchange(current, new, success, failure)
                }
                /// The standard atomic, for system calls that take one (futexes).
                #[inline(always)]
                pub(crate) fn as_std(&self) -> &$std {
                    &self.0
                }
            }
        };
    }

    atomic!(AtomicU32, u32, std::sync::atomic::AtomicU32);
    atomic!(AtomicU64, u64, std::sync::atomic::AtomicU64);
}

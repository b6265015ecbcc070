//! The handles C holds are not pointers to Rust objects but numbers: a slot
//! in a registry and the slot's generation. A handle that was closed, or a
//! pointer C made up, finds no object and gets an error code instead of
//! memory that was freed; a close from another thread while a call is in
//! progress leaves that call its object (each call holds an `Arc`) until it
//! returns.

#![forbid(unsafe_code)]

use std::sync::{Arc, Mutex};

/// One slot: its generation (bumped on each removal) and what it holds.
struct Slot<T> {
    generation: u32,
    value: Option<Arc<T>>,
}

/// The live handles of one type.
pub(crate) struct Registry<T> {
    /// A tag kept in the handle's top bits, so a reader's handle passed
    /// where a writer's is expected is refused too.
    tag: u8,
    slots: Mutex<Vec<Slot<T>>>,
}

/// Slots per registry: handles are refused beyond it (a leak in the caller).
/// Slot i is number i + 1 in a handle's 24 bits, so the last is 2^24 - 2.
const MAX_SLOTS: usize = (1 << 24) - 1;

// Handles pack a tag, a generation and a slot into 64 bits.
const _: () = assert!(usize::BITS == 64, "the C API's handles need a 64-bit target");

impl<T> Registry<T> {
    /// An empty registry whose handles carry `tag` (1 to 255).
    pub(crate) const fn new(tag: u8) -> Registry<T> {
        Registry { tag, slots: Mutex::new(Vec::new()) }
    }

    /// Keeps `value` and returns its handle (never 0), or `None` if the
    /// caller holds 16 Mi handles of this type already.
    pub(crate) fn insert(&self, value: T) -> Option<usize> {
        let mut slots = skinware::lock(&self.slots);
        let index = match slots.iter().position(|slot| slot.value.is_none()) {
            Some(index) => index,
            None if slots.len() < MAX_SLOTS => {
                slots.push(Slot { generation: 0, value: None });
                slots.len() - 1
            }
            None => return None,
        };
        slots[index].value = Some(Arc::new(value));
        Some(self.handle(index, slots[index].generation))
    }

    /// The object behind `handle`, if it is live.
    pub(crate) fn get(&self, handle: usize) -> Option<Arc<T>> {
        let (index, generation) = self.split(handle)?;
        let slots = skinware::lock(&self.slots);
        let slot = slots.get(index)?;
        (slot.generation == generation).then(|| slot.value.clone()).flatten()
    }

    /// Takes the object behind `handle` out; the handle is dead from now on.
    pub(crate) fn remove(&self, handle: usize) -> Option<Arc<T>> {
        let (index, generation) = self.split(handle)?;
        let mut slots = skinware::lock(&self.slots);
        let slot = slots.get_mut(index)?;
        if slot.generation != generation {
            return None;
        }
        let value = slot.value.take()?;
        slot.generation = slot.generation.wrapping_add(1);
        Some(value)
    }

    /// Handles: bits 0-23 the slot + 1, 24-55 the generation, 56-63 the tag.
    fn handle(&self, index: usize, generation: u32) -> usize {
        ((self.tag as usize) << 56) | ((generation as usize) << 24) | (index + 1)
    }

    fn split(&self, handle: usize) -> Option<(usize, u32)> {
        if handle >> 56 != self.tag as usize {
            return None;
        }
        let index = (handle & ((1 << 24) - 1)).checked_sub(1)?;
        Some((index, ((handle >> 24) & 0xffff_ffff) as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_removed_handle_finds_nothing_even_when_its_slot_is_reused() {
        let registry = Registry::new(7);
        let first = registry.insert("a").unwrap();
        assert_eq!(registry.get(first).as_deref(), Some(&"a"));
        assert!(registry.remove(first).is_some());
        assert!(registry.get(first).is_none());
        assert!(registry.remove(first).is_none(), "closed twice");
        let second = registry.insert("b").unwrap();
        assert_ne!(first, second, "the reused slot has a new generation");
        assert!(registry.get(first).is_none());
        assert_eq!(registry.get(second).as_deref(), Some(&"b"));
    }

    proptest::proptest! {
        /// Any number C passes finds an object only if it is a handle that
        /// was issued and not closed.
        #[test]
        #[cfg_attr(miri, ignore = "256 random cases are slow under Miri, and no pointer is involved")]
        fn only_issued_live_handles_find_objects(made_up in proptest::prelude::any::<usize>(), opened in 1usize..20, closed in 0usize..20) {
            let registry: Registry<usize> = Registry::new(9);
            let handles: Vec<usize> = (0..opened).map(|i| registry.insert(i).unwrap()).collect();
            for handle in handles.iter().take(closed) {
                registry.remove(*handle);
            }
            let live = &handles[closed.min(opened)..];
            match registry.get(made_up) {
                Some(found) => proptest::prop_assert_eq!(live.iter().position(|h| *h == made_up), Some(*found - closed.min(opened))),
                None => proptest::prop_assert!(!live.contains(&made_up)),
            }
            for (i, handle) in live.iter().enumerate() {
                let found = registry.get(*handle).map(|value| *value);
                proptest::prop_assert_eq!(found, Some(closed.min(opened) + i));
            }
        }
    }

    #[test]
    fn made_up_and_foreign_handles_find_nothing() {
        let readers: Registry<u32> = Registry::new(1);
        let writers: Registry<u32> = Registry::new(2);
        let reader = readers.insert(1).unwrap();
        assert!(writers.get(reader).is_none(), "a reader's handle is not a writer's");
        for made_up in [0, 1, usize::MAX, 0xdead_beef, reader + 1, reader ^ (1 << 30)] {
            assert!(readers.get(made_up).is_none(), "{made_up:#x}");
        }
    }
}

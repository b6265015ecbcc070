//! The contact detector's per-taxel arrays, laid out one after another in
//! one block of memory that the kernel is asked to back with huge pages
//! ([`skinware::os::HugePageMemory`]).
//!
//! Between two frames of a running service (20 ms at 50 Hz) other programs
//! push the detector's memory out of the caches, page-table entries
//! included, and each frame walks through all of it again: with 4 KiB pages
//! that is a page walk, and a restart of the hardware's prefetchers, every
//! 4 KiB of every array. In one block on huge pages it is one page table
//! entry per 2 MiB.

use std::marker::PhantomData;
use std::ops::Range;

use skinware::os::HugePageMemory;

/// Where one array of `T` lies in a [`TaxelMemory`].
pub(super) struct Placed<T> {
    /// Its words.
    start: usize,
    end: usize,
    /// Its length, in `T`s.
    len: usize,
    _type: PhantomData<T>,
}

impl<T> Clone for Placed<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Placed<T> {}

impl<T> Placed<T> {
    /// Its words in the memory.
    pub fn words(&self) -> Range<usize> {
        self.start..self.end
    }

    /// `words`, the words of this array taken from its memory, as its `T`s.
    pub fn view<'a>(&self, words: &'a [u64]) -> &'a [T]
    where
        T: bytemuck::Pod,
    {
        &bytemuck::cast_slice(words)[..self.len]
    }

    /// [`view`](Self::view), to write.
    pub fn view_mut<'a>(&self, words: &'a mut [u64]) -> &'a mut [T]
    where
        T: bytemuck::Pod,
    {
        &mut bytemuck::cast_slice_mut(words)[..self.len]
    }
}

/// Lays arrays out one after another, each from a multiple of 64 bytes
/// into the block: on its own cache lines where the block is mapped (from a
/// huge page's start); in the heap's fallback, from 8-byte words.
#[derive(Default)]
pub(super) struct Layout {
    words: usize,
}

impl Layout {
    /// Places an array of `len` `T`s: `T` must be whole words or fit
    /// several to a word (as `u8` to `u64` do).
    pub fn place<T: bytemuck::Pod>(&mut self, len: usize) -> Placed<T> {
        const LINE_WORDS: usize = 8;
        const {
            let size = std::mem::size_of::<T>();
            assert!(std::mem::align_of::<T>() <= 8 && size > 0 && (size.is_multiple_of(8) || 8 % size == 0));
        };
        let start = self.words.next_multiple_of(LINE_WORDS);
        let bytes = len.checked_mul(std::mem::size_of::<T>()).expect("an array larger than the address space");
        let end = start + bytes.div_ceil(8);
        self.words = end;
        Placed { start, end, len, _type: PhantomData }
    }
}

/// The words of every array a [`Layout`] placed, zeroed.
pub(super) enum TaxelMemory {
    /// On (transparent) huge pages where the kernel gives them.
    Mapped(HugePageMemory),
    /// On the heap, where the kernel refused a mapping.
    Heap(Vec<u64>),
}

impl TaxelMemory {
    /// Memory for what `layout` placed.
    pub fn new(layout: &Layout) -> TaxelMemory {
        match HugePageMemory::zeroed(layout.words) {
            Ok(memory) => TaxelMemory::Mapped(memory),
            Err(_) => TaxelMemory::Heap(vec![0; layout.words]),
        }
    }

    fn words(&self) -> &[u64] {
        match self {
            TaxelMemory::Mapped(memory) => memory.words(),
            TaxelMemory::Heap(words) => words,
        }
    }

    fn words_mut(&mut self) -> &mut [u64] {
        match self {
            TaxelMemory::Mapped(memory) => memory.words_mut(),
            TaxelMemory::Heap(words) => words,
        }
    }

    /// Array `placed`.
    pub fn get<T: bytemuck::Pod>(&self, placed: Placed<T>) -> &[T] {
        placed.view(&self.words()[placed.words()])
    }

    /// Array `placed`, to write.
    pub fn get_mut<T: bytemuck::Pod>(&mut self, placed: Placed<T>) -> &mut [T] {
        placed.view_mut(&mut self.words_mut()[placed.words()])
    }

    /// The words of several arrays at once, to write, given in the order
    /// they were placed in ([`Placed::words`]; [`Placed::view_mut`] gives
    /// each its type back). Panics if they are out of that order or overlap.
    pub fn words_of_mut<const N: usize>(&mut self, arrays: [Range<usize>; N]) -> [&mut [u64]; N] {
        let mut rest = self.words_mut();
        let mut taken = 0;
        arrays.map(|words| {
            let (_, from_start) = std::mem::take(&mut rest).split_at_mut(words.start - taken);
            let (array, after) = from_start.split_at_mut(words.end - words.start);
            rest = after;
            taken = words.end;
            array
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placed_arrays_are_apart_zeroed_and_typed() {
        let mut layout = Layout::default();
        let floats: Placed<f32> = layout.place(3);
        let bytes: Placed<u8> = layout.place(9);
        let shorts: Placed<u16> = layout.place(5);
        assert_eq!((floats.words(), bytes.words(), shorts.words()), (0..2, 8..10, 16..18));
        let mut memory = TaxelMemory::new(&layout);
        let [f, b, s] = memory.words_of_mut([floats.words(), bytes.words(), shorts.words()]);
        let (f, b, s) = (floats.view_mut(f), bytes.view_mut(b), shorts.view_mut(s));
        assert_eq!((f.len(), b.len(), s.len()), (3, 9, 5));
        assert!(f.iter().all(|&x| x == 0.0) && b.iter().all(|&x| x == 0) && s.iter().all(|&x| x == 0));
        f.fill(1.5);
        b.fill(7);
        s.fill(300);
        assert_eq!(memory.get(floats), [1.5; 3]);
        assert_eq!(memory.get(bytes), [7; 9]);
        assert_eq!(memory.get_mut(shorts), [300; 5]);
    }
}

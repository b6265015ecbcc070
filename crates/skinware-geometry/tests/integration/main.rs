//! The geometry crate's integration tests, as one test binary.

#[path = "../../../skinware/tests/integration/alloc_bound.rs"]
mod alloc_bound;
mod bad_input;
mod wire;

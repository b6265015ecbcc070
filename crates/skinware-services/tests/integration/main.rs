//! The services' integration tests, as one test binary (one link instead of
//! one per file).

#[path = "../../../skinware/tests/integration/alloc_bound.rs"]
mod alloc_bound;
mod framework;
mod scripted;
mod wire;

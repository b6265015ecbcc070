//! The web viewer: an HTTP server (std sockets, one thread per connection)
//! that serves one embedded page and streams the skin to it over a
//! WebSocket, in the compact binary format of [`protocol`] (see
//! `docs/viewer.md`).
//!
//! - [`server`]: HTTP, the page, the WebSocket upgrade;
//! - [`session`]: one browser: geometry, then credit-paced updates;
//! - [`sampler`]: the layers read in the browser's reader mode, newest only;
//! - [`overlays`]: the services' arrows and markers.

#![forbid(unsafe_code)]

pub mod overlays;
pub mod protocol;
pub mod sampler;
pub mod server;
pub mod session;

pub use server::{bind, serve};
pub use session::Site;

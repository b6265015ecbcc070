//! The web viewer: an HTTP server (std sockets, one thread per connection,
//! which sleeps once its browser is handed to a dispatcher)
//! that serves one embedded page and streams the skin to it over a
//! WebSocket, in the compact binary format of [`protocol`] (see
//! `docs/viewer.md`).
//!
//! - [`server`]: HTTP, the page, the WebSocket upgrade;
//! - [`session`]: one browser: geometry, then credit-paced updates;
//! - [`browsers`]: the browsers of one sampler, served by the threads awake anyway;
//! - [`sampler`]: the layers read in the browser's reader mode, newest only;
//! - [`overlays`]: the services' arrows and markers.

#![forbid(unsafe_code)]

pub mod browsers;
pub mod overlays;
pub mod protocol;
pub mod sampler;
pub mod server;
pub mod session;

pub use server::{bind, serve};
pub use session::Site;

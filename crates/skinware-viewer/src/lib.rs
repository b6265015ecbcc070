//! The web viewer of a running skin: an HTTP server (std sockets, one thread
//! per connection) that serves one embedded page and streams the skin to it
//! over a WebSocket, in the compact binary format of [`protocol`] (see
//! `docs/viewer.md`). `skin view` (of a local or a remote skin) and `skin
//! demo` start it.
//!
//! - [`server`]: HTTP, the page, the WebSocket upgrade ([`bind`], [`serve`]);
//! - [`session`]: one browser: geometry, then credit-paced updates ([`Site`]);
//! - [`sampler`]: the layers read in the browser's reader mode, newest only;
//! - [`overlays`]: the services' arrows and markers, which follow the
//!   reader mode;
//! - [`range`]: each layer's colour range, learnt from its responses;
//! - [`labels`]: what each map piece is (its link, the regions holding it)
//!   and each taxel's place;
//! - [`protocol`]: the binary messages from the server to the page;
//! - [`compact`]: the compact encoding of the responses in an update, and
//!   its decoder (for tests and the bench's browsers);
//! - [`message`]: the JSON text messages from the page to the server,
//!   decoded by [`message::decode`] (built without the server too, for the
//!   fuzz target).
//!
//! ```
//! use skinware_viewer::message::{ClientMessage, ReadMode, decode};
//!
//! assert_eq!(decode(r#"{"ack":2}"#)?, ClientMessage::Ack(2));
//! assert_eq!(decode(r#"{"mode":"asap"}"#)?, ClientMessage::Mode(ReadMode::Asap));
//! # Ok::<(), skinware_viewer::message::MessageError>(())
//! ```
//!
//! Serving a skin until SIGINT or SIGTERM (which set `shutdown`):
//!
//! ```no_run
//! # #[cfg(feature = "server")]
//! # fn main() -> anyhow::Result<()> {
//! use std::sync::Arc;
//! use std::sync::atomic::AtomicBool;
//!
//! let listener = skinware_viewer::bind("127.0.0.1:8080")?;
//! let shutdown = Arc::new(AtomicBool::new(false));
//! skinware_viewer::serve(listener, &skinware_viewer::Site::new("hand", None, shutdown))?;
//! # Ok(())
//! # }
//! # #[cfg(not(feature = "server"))]
//! # fn main() {}
//! ```
//!
//! Cargo features: `server` (default) builds the viewer itself and its
//! dependencies (the skin's readers, tungstenite, signal handling); without
//! it only [`message`] is built, which is what the fuzz target does
//! (`default-features = false`).

#![forbid(unsafe_code)]
// The overview above links to the server's modules, which exist only with it.
#![cfg_attr(not(feature = "server"), allow(rustdoc::broken_intra_doc_links))]

#[cfg(feature = "server")]
pub mod compact;
#[cfg(feature = "server")]
pub mod labels;
pub mod message;
#[cfg(feature = "server")]
pub mod overlays;
#[cfg(feature = "server")]
pub mod protocol;
#[cfg(feature = "server")]
pub mod range;
#[cfg(feature = "server")]
pub mod sampler;
#[cfg(feature = "server")]
pub mod server;
#[cfg(feature = "server")]
pub mod session;

#[cfg(feature = "server")]
pub use server::{bind, serve};
#[cfg(feature = "server")]
pub use session::Site;

/// A virtual skin's geometry, as `skin run` would publish it for a config of
/// one virtual driver `v`, for the viewer's tests: `sensors` taxels in two
/// layers, `v-0` and `v-1`. Built from the virtual skin itself (what that
/// config builds), since this crate cannot depend on `skin` for its config.
#[cfg(all(test, feature = "server"))]
pub(crate) fn virtual_geometry(skin: &str, sensors: usize) -> skinware_geometry::SkinGeometry {
    use skinware::Driver;
    use skinware_drivers::{VirtualSkin, VirtualSkinConfig};
    let config = VirtualSkinConfig { name: "v".into(), sensors, layers: 2, ..VirtualSkinConfig::default() };
    let driver = VirtualSkin::new(config).unwrap();
    let layers: Vec<_> = driver.layers().into_iter().map(|spec| spec.topology).collect();
    skinware_geometry::SkinGeometry::build(skin, &layers, &driver.calibration(), &[]).unwrap()
}

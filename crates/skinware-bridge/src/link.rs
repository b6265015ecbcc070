//! Opening a zenoh session for the bridge or a remote reader: endpoints,
//! a zenoh configuration file passed through, and the timing that makes a
//! cut link noticed and a returning one used again within about a second.

use std::path::PathBuf;
use std::time::Duration;

use zenoh::{Config, Session, Wait};

use crate::BridgeError;

/// Where a session listens and what it connects to.
#[derive(Clone, Debug, Default)]
pub struct LinkOptions {
    /// Endpoints to listen on (`tcp/0.0.0.0:7447`).
    pub listen: Vec<String>,
    /// Endpoints to connect to (`tcp/robot-pc:7447`, a `rmw_zenohd` router).
    pub connect: Vec<String>,
    /// A zenoh configuration file (JSON5): TLS, access control, anything
    /// zenoh offers. `listen` and `connect` above replace its endpoints.
    pub config_file: Option<PathBuf>,
    /// How long a silent link lasts before zenoh closes it and reconnects
    /// (default [`DEFAULT_LEASE`]; a configuration file's own stands).
    pub lease: Option<Duration>,
    /// The kernel's send buffer of each TCP link, bytes (`so_sndbuf`): what
    /// a slow link can hold back. `None` keeps the kernel's autotuning (up
    /// to megabytes: seconds of backlog on a slow link).
    pub send_buffer: Option<usize>,
}

pub use crate::protocol::BRIDGE_SEND_BUFFER;

fn with_send_buffer(endpoints: &[String], bytes: Option<usize>) -> Vec<String> {
    endpoints
        .iter()
        .map(|endpoint| match bytes {
            Some(bytes)
                if (endpoint.starts_with("tcp/") || endpoint.starts_with("tls/"))
                    && !endpoint.contains("so_sndbuf") =>
            {
                let separator = if endpoint.contains('#') { ';' } else { '#' };
                format!("{endpoint}{separator}so_sndbuf={bytes}")
            }
            _ => endpoint.clone(),
        })
        .collect()
}

/// The bridge's endpoint when none is given: this machine only.
pub const DEFAULT_LISTEN: &str = "tcp/127.0.0.1:7447";

/// The link lease: zenoh's default is 10 s, which would leave a cut link
/// unnoticed (and a returning one unused) for as long.
pub const DEFAULT_LEASE: Duration = Duration::from_secs(1);

fn config_error(what: &str, e: impl std::fmt::Display) -> BridgeError {
    BridgeError::Invalid(format!("zenoh configuration: cannot set {what}: {e}"))
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|e| format!("{e:?}")).collect();
    format!("[{}]", quoted.join(","))
}

impl LinkOptions {
    /// The zenoh configuration these options describe.
    pub fn config(&self) -> Result<Config, BridgeError> {
        let mut config = match &self.config_file {
            Some(path) => Config::from_file(path).map_err(|e| {
                BridgeError::Invalid(format!(
                    "cannot use the zenoh configuration file {}: {e} (it is JSON5; zenoh's DEFAULT_CONFIG.json5 lists every key)",
                    path.display()
                ))
            })?,
            None => {
                let mut config = Config::default();
                config.insert_json5("mode", "\"peer\"").map_err(|e| config_error("mode", e))?;
                // Say nothing to the LAN unless asked: peers find each other through the endpoints.
                config
                    .insert_json5("scouting/multicast/enabled", "false")
                    .map_err(|e| config_error("scouting/multicast/enabled", e))?;
                let lease = self.lease.unwrap_or(DEFAULT_LEASE).as_millis().max(100);
                config.insert_json5("transport/link/tx/lease", &lease.to_string()).map_err(|e| config_error("lease", e))?;
                // Retry a lost connection every 250 ms, then at most every second.
                config
                    .insert_json5("connect/retry", "{period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2}")
                    .map_err(|e| config_error("connect/retry", e))?;
                config
            }
        };
        if self.listen.is_empty() && !self.connect.is_empty() && self.config_file.is_none() {
            // A reader that only connects opens no port of its own.
            config.insert_json5("listen/endpoints", "[]").map_err(|e| config_error("listen endpoints", e))?;
        }
        if !self.listen.is_empty() {
            config
                .insert_json5("listen/endpoints", &json_list(&with_send_buffer(&self.listen, self.send_buffer)))
                .map_err(|e| config_error(&format!("listen endpoints {:?}", self.listen), e))?;
        }
        if !self.connect.is_empty() {
            config
                .insert_json5("connect/endpoints", &json_list(&with_send_buffer(&self.connect, self.send_buffer)))
                .map_err(|e| config_error(&format!("connect endpoints {:?}", self.connect), e))?;
            // Start even while the other side is away, and keep trying in the background.
            config
                .insert_json5("connect/exit_on_failure", "false")
                .map_err(|e| config_error("connect/exit_on_failure", e))?;
        }
        Ok(config)
    }

    /// Opens a session.
    pub fn open(&self) -> Result<Session, BridgeError> {
        let config = self.config()?;
        zenoh::open(config).wait().map_err(|e| {
            BridgeError::Zenoh(format!(
                "cannot open a session (listen {:?}, connect {:?}): {e}; is the port in use, or the address not this \
                 machine's?",
                self.listen, self.connect
            ))
        })
    }
}

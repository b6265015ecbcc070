//! `[[service]]` tables: the contact and motion services and their settings.

use anyhow::{Result, bail};
use serde::Deserialize;

use super::process::{RestartConfig, RtConfig};

/// The kinds of service.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ServiceKind {
    /// Contact detection (`skinware_services::contact`).
    Contact,
    /// Motion detection (`skinware_services::motion`), on a contact service.
    Motion,
}

/// One `[[service]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct ServiceConfig {
    /// Its channel's name (its taxels' channel is `NAME-taxels`).
    pub name: String,
    /// Which service.
    pub kind: ServiceKind,
    /// Publishing rate; absent for a sporadic service (one frame per request).
    pub rate_hz: Option<f64>,
    /// Motion: the contact service it reads.
    pub input: Option<String>,
    /// Contact: touch threshold in noise standard deviations.
    pub threshold_sigma: Option<f32>,
    /// Contact: minimum touch threshold, response units.
    pub min_threshold: Option<f32>,
    /// Contact: time constant of the baseline (drift compensation), seconds.
    pub baseline_tau_s: Option<f32>,
    /// Motion: slower than this (m/s) is not sliding.
    pub min_speed: Option<f64>,
    /// Motion: velocity fitting window, seconds.
    pub window_s: Option<f64>,
    /// How its process is restarted (`[service.restart]`).
    #[serde(default)]
    pub restart: RestartConfig,
    /// Real-time settings of its thread (`[service.rt]`, as drivers'): a
    /// service at 1 kHz beside real-time writers needs a priority of its own,
    /// or any normal thread can hold it past its period.
    #[serde(default)]
    pub rt: RtConfig,
}

impl ServiceConfig {
    /// Periodic at `rate_hz`, or sporadic.
    pub fn mode(&self) -> skinware_services::framework::ServiceMode {
        match self.rate_hz {
            Some(hz) => skinware_services::framework::ServiceMode::Periodic { hz },
            None => skinware_services::framework::ServiceMode::Sporadic,
        }
    }

    /// The library's form of its real-time settings.
    pub fn rt_options(&self) -> skinware::RtOptions {
        self.rt.options()
    }

    /// The contact service's settings.
    pub fn contact(&self) -> skinware_services::ContactServiceConfig {
        let defaults = skinware_services::ContactParams::default();
        skinware_services::ContactServiceConfig {
            name: self.name.clone(),
            mode: self.mode(),
            params: skinware_services::ContactParams {
                threshold_sigma: self.threshold_sigma.unwrap_or(defaults.threshold_sigma),
                min_threshold: self.min_threshold.unwrap_or(defaults.min_threshold),
                baseline_tau_s: self.baseline_tau_s.unwrap_or(defaults.baseline_tau_s),
                ..defaults
            },
        }
    }

    /// The motion service's settings.
    pub fn motion(&self) -> skinware_services::MotionServiceConfig {
        let defaults = skinware_services::MotionParams::default();
        skinware_services::MotionServiceConfig {
            name: self.name.clone(),
            mode: self.mode(),
            input: self.input.clone().unwrap_or_else(|| "contact".into()),
            params: skinware_services::MotionParams {
                min_speed: self.min_speed.unwrap_or(defaults.min_speed),
                window_s: self.window_s.unwrap_or(defaults.window_s),
                ..defaults
            },
        }
    }

    /// Checks this table's values and keys for its kind, and that a motion
    /// service's input is a periodic contact service among `services`.
    pub(super) fn check(&self, services: &[ServiceConfig]) -> Result<()> {
        skinware::shm::validate_name("service", &self.name)?;
        self.restart.check()?;
        if let Some(hz) = self.rate_hz
            && !(hz.is_finite() && (0.001..=10_000.0).contains(&hz))
        {
            bail!("rate_hz {hz} must be from 0.001 to 10000 (or absent for a sporadic service)");
        }
        let positive = |what: &str, v: Option<f64>| -> Result<()> {
            match v {
                Some(v) if !(v.is_finite() && v > 0.0) => bail!("{what} {v} must be above 0"),
                _ => Ok(()),
            }
        };
        positive("threshold_sigma", self.threshold_sigma.map(f64::from))?;
        positive("min_threshold", self.min_threshold.map(f64::from))?;
        positive("baseline_tau_s", self.baseline_tau_s.map(f64::from))?;
        positive("min_speed", self.min_speed)?;
        positive("window_s", self.window_s)?;
        let contact_only = [
            ("threshold_sigma", self.threshold_sigma.is_some()),
            ("min_threshold", self.min_threshold.is_some()),
            ("baseline_tau_s", self.baseline_tau_s.is_some()),
        ];
        let motion_only = [
            ("input", self.input.is_some()),
            ("min_speed", self.min_speed.is_some()),
            ("window_s", self.window_s.is_some()),
        ];
        let (foreign, kind) = match self.kind {
            ServiceKind::Contact => (&motion_only, "contact"),
            ServiceKind::Motion => (&contact_only, "motion"),
        };
        if let Some((key, _)) = foreign.iter().find(|(_, set)| *set) {
            bail!("`{key}` does not apply to a {kind} service");
        }
        if self.kind == ServiceKind::Motion {
            let input = self.input.as_deref().unwrap_or("contact");
            match services.iter().find(|s| s.name == input && s.kind == ServiceKind::Contact) {
                None => {
                    let contacts: Vec<&str> =
                        services.iter().filter(|s| s.kind == ServiceKind::Contact).map(|s| s.name.as_str()).collect();
                    let hint = match crate::suggest::closest(input, contacts.iter().copied()) {
                        Some(name) => format!("did you mean {name:?}?"),
                        None if contacts.is_empty() => "add one, or set `input`".to_owned(),
                        None => format!("the contact services: {}", contacts.join(", ")),
                    };
                    bail!("its input {input:?} is not a contact service of this config; {hint}")
                }
                Some(contact) if contact.rate_hz.is_none() => {
                    bail!("its input {input:?} is sporadic; give the contact service a rate_hz to track motion on it")
                }
                Some(_) => {}
            }
        }
        Ok(())
    }
}

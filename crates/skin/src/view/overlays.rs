//! What the services add on top of the heatmap: motion arrows and contact
//! markers, in map coordinates (metres on the 2-D map).

#![forbid(unsafe_code)]

/// A motion, from where it started to where it is now on the map, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arrow {
    /// Tail, map metres.
    pub from: [f32; 2],
    /// Head, map metres.
    pub to: [f32; 2],
}

/// A contact: its centre and radius on the map, metres, and its pressure
/// (response above baseline, in the layer's units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Marker {
    /// Centre, map metres.
    pub at: [f32; 2],
    /// Radius, metres.
    pub radius: f32,
    /// Pressure above baseline.
    pub pressure: f32,
}

/// Everything drawn over the heatmap in one update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overlays {
    /// Motion arrows (the motion service).
    pub arrows: Vec<Arrow>,
    /// Contact markers (the contact service).
    pub markers: Vec<Marker>,
}

/// Where the viewer gets its overlays from: the skin's services.
#[derive(Debug)]
pub struct OverlaySource {
    /// The skin whose services to read.
    #[allow(dead_code)]
    skin: String,
}

impl OverlaySource {
    /// The overlay source of `skin`'s services.
    pub fn new(skin: &str) -> OverlaySource {
        OverlaySource { skin: skin.to_owned() }
    }

    /// The newest overlays. Never blocks: called once per update sent.
    pub fn poll(&mut self) -> Overlays {
        // Not wired yet: the motion and contact services' channels are to be
        // read here (their contacts become markers, their motions arrows).
        Overlays::default()
    }
}

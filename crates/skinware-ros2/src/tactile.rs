//! skinware's frames in the messages of the ROS tactile stack: a layer's
//! frame as `tactile_msgs/TactileState`, the contact service's as
//! `tactile_msgs/TactileContacts`, encoded as CDR and ready for any ROS 2
//! transport.

use skinware::LayerTopology;
use skinware_services::contact::RegionContacts;

use crate::cdr::{EncodeError, encode};
use crate::messages::{ChannelFloat32, Header, TactileContact, TactileContacts, TactileState, Time, Vector3, Wrench};

/// The full scale of a response: a value `v` is published as `v / 65535`,
/// which `float32` holds exactly enough that `round(x * 65535)` gives `v` back.
pub const RESPONSE_FULL_SCALE: f32 = 65535.0;

/// Encodes one frame of `layer` as a `TactileState`: one `ChannelFloat32`
/// per patch, in topology order, values scaled to 0..1.
pub fn tactile_state(layer: &LayerTopology, responses: &[u16], acquired: Time) -> Result<Vec<u8>, EncodeError> {
    encode(&tactile_state_message(layer, responses, acquired), 64 + 4 * responses.len() + 32 * layer.patches.len())
}

/// The message [`tactile_state`] encodes.
pub fn tactile_state_message(layer: &LayerTopology, responses: &[u16], acquired: Time) -> TactileState {
    let mut sensors = Vec::with_capacity(layer.patches.len());
    for patch in &layer.patches {
        let first = layer.modules.get(patch.modules.start).map_or(0, |m| m.sensors.start);
        let end =
            patch.modules.end.checked_sub(1).and_then(|last| layer.modules.get(last)).map_or(first, |m| m.sensors.end);
        let values =
            (first..end).map(|i| f32::from(responses.get(i).copied().unwrap_or(0)) / RESPONSE_FULL_SCALE).collect();
        sensors.push(ChannelFloat32 { name: format!("{}/patch{}", layer.name, patch.id), values });
    }
    TactileState { header: Header { stamp: acquired, frame_id: layer.name.clone() }, sensors }
}

/// Encodes one frame of the contact service (one record per region, named
/// by `regions`) as `TactileContacts`.
pub fn tactile_contacts(
    regions: &[String],
    records: &[RegionContacts],
    acquired: Time,
) -> Result<Vec<u8>, EncodeError> {
    encode(&tactile_contacts_message(regions, records, acquired), 256)
}

/// The message [`tactile_contacts`] encodes.
pub fn tactile_contacts_message(regions: &[String], records: &[RegionContacts], acquired: Time) -> TactileContacts {
    let vector = |v: [f32; 3]| Vector3 { x: f64::from(v[0]), y: f64::from(v[1]), z: f64::from(v[2]) };
    let mut contacts = Vec::new();
    for (index, record) in records.iter().enumerate() {
        let region = regions.get(index).cloned().unwrap_or_else(|| format!("region{index}"));
        for (rank, contact) in record.contacts().iter().enumerate() {
            let normal = vector(contact.normal);
            let total = f64::from(contact.total);
            contacts.push(TactileContact {
                header: Header { stamp: acquired, frame_id: region.clone() },
                name: format!("{region}/{rank}"),
                position: vector(contact.centroid),
                normal,
                wrench: Wrench {
                    force: Vector3 { x: -normal.x * total, y: -normal.y * total, z: -normal.z * total },
                    torque: Vector3::default(),
                },
            });
        }
    }
    TactileContacts { contacts }
}

#[cfg(test)]
mod tests {
    use skinware::TopologyBuilder;
    use skinware_services::contact::Contact;

    use super::*;
    use crate::cdr::decode;

    #[test]
    fn a_layer_is_one_named_array_per_patch() {
        let mut builder = TopologyBuilder::new("palm", "pressure", 50.0);
        builder.patch(4).module(0, [10, 11]).module(1, [12]);
        builder.patch(9).module(2, [20, 21]);
        let layer = builder.build().unwrap();
        let bytes = tactile_state(&layer, &[0, 65535, 1, 2, 3], Time { sec: 1, nanosec: 2 }).unwrap();
        let back: TactileState = decode(&bytes, "TactileState").unwrap();
        assert_eq!(back.header.frame_id, "palm");
        assert_eq!(back.sensors.len(), 2);
        assert_eq!(back.sensors[0].name, "palm/patch4");
        assert_eq!(back.sensors[1].name, "palm/patch9");
        let raw: Vec<u16> = back
            .sensors
            .iter()
            .flat_map(|s| s.values.iter().map(|v| (v * RESPONSE_FULL_SCALE).round() as u16))
            .collect();
        assert_eq!(raw, [0, 65535, 1, 2, 3]);
    }

    #[test]
    fn contacts_push_into_the_skin() {
        let mut record = RegionContacts { count: 1, ..RegionContacts::default() };
        record.contacts[0] =
            Contact { centroid: [1.0, 2.0, 3.0], normal: [0.0, 0.0, 1.0], total: 5.0, ..Contact::default() };
        let bytes = tactile_contacts(&["palm".into()], &[record, RegionContacts::default()], Time::default()).unwrap();
        let back: TactileContacts = decode(&bytes, "TactileContacts").unwrap();
        assert_eq!(back.contacts.len(), 1);
        assert_eq!(back.contacts[0].name, "palm/0");
        assert_eq!(back.contacts[0].position, Vector3 { x: 1.0, y: 2.0, z: 3.0 });
        assert_eq!(back.contacts[0].wrench.force.z, -5.0);
    }
}

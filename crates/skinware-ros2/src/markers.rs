//! The contact service's frame as a `visualization_msgs/MarkerArray` that
//! rviz2 and Foxglove draw over the skin's clouds: an arrow per contact,
//! pushing into the skin at its centroid, as long as its pressure.
//!
//! The array starts with a `DELETEALL`, so the contacts of the last frame
//! that are gone now disappear, and each arrow lives a little longer than a
//! frame, so they all disappear when the service stops.

use skinware_geometry::SkinGeometry;
use skinware_services::contact::{MAX_CONTACTS, RegionContacts};

use crate::cdr::{EncodeError, encode};
use crate::messages::{Header, Time, Vector3};
use crate::standard::{
    ColorRgba, CompressedImage, Duration, MARKER_ADD, MARKER_ARROW, MARKER_DELETE_ALL, Marker, MarkerArray, MeshFile,
    Pose, Quaternion,
};

/// The markers' namespace.
pub const CONTACTS_NAMESPACE: &str = "skin_contacts";
/// The shortest arrow, metres.
const MIN_ARROW_M: f64 = 0.02;
/// The longest arrow, metres.
const MAX_ARROW_M: f64 = 0.12;
/// Arrow length per unit of summed response above baseline.
const ARROW_M_PER_RESPONSE: f64 = 1e-6;

/// How the contacts are drawn.
#[derive(Clone, Debug)]
pub struct ContactMarkers<'a> {
    /// The skin's geometry: a contact is drawn in the frame of its most
    /// pressed taxel's link (`None`: every contact in `root`).
    pub geometry: Option<&'a SkinGeometry>,
    /// The frame of a contact whose link is unknown.
    pub root: &'a str,
    /// How long an arrow stays without an update (a few of the service's periods).
    pub lifetime: std::time::Duration,
}

impl ContactMarkers<'_> {
    /// Encodes one frame of the contact service (one record per region).
    /// Contacts with a non-finite centroid or normal (from a writer that
    /// is not the contact service) are left out.
    pub fn encode(&self, records: &[RegionContacts], stamp: Time) -> Result<Vec<u8>, EncodeError> {
        let array = self.markers(records, stamp);
        let size = 256 * array.markers.len();
        encode(&array, size)
    }

    /// The message [`encode`](Self::encode) encodes.
    pub fn markers(&self, records: &[RegionContacts], stamp: Time) -> MarkerArray {
        let mut markers = vec![self.marker(stamp, self.root, 0, MARKER_DELETE_ALL, Vec::new())];
        for (region, record) in records.iter().enumerate() {
            for (rank, contact) in record.contacts().iter().enumerate() {
                let finite = contact.centroid.iter().chain(&contact.normal).all(|v| v.is_finite());
                if !finite {
                    continue;
                }
                let at = vector(contact.centroid);
                let normal = vector(contact.normal);
                let pressure = if contact.total.is_finite() { f64::from(contact.total.max(0.0)) } else { 0.0 };
                let length = (MIN_ARROW_M + pressure * ARROW_M_PER_RESPONSE).min(MAX_ARROW_M);
                // From outside the skin, along the outward normal, to the centroid.
                let tail =
                    Vector3 { x: at.x + normal.x * length, y: at.y + normal.y * length, z: at.z + normal.z * length };
                let frame = self.frame_of(contact.peak_sensor);
                let id = i32::try_from(region * MAX_CONTACTS + rank).unwrap_or(i32::MAX);
                markers.push(self.marker(stamp, frame, id, MARKER_ADD, vec![tail, at]));
            }
        }
        MarkerArray { markers }
    }

    fn frame_of(&self, sensor: u32) -> &str {
        let link = self.geometry.and_then(|g| {
            let link = *g.link_of.get(sensor as usize)?;
            g.links.get(usize::from(link))
        });
        link.map_or(self.root, String::as_str)
    }

    fn marker(&self, stamp: Time, frame: &str, id: i32, action: i32, points: Vec<Vector3>) -> Marker {
        let header = Header { stamp, frame_id: frame.to_owned() };
        Marker {
            header: header.clone(),
            ns: CONTACTS_NAMESPACE.into(),
            id,
            kind: MARKER_ARROW,
            action,
            pose: Pose { position: Vector3::default(), orientation: Quaternion::IDENTITY },
            // Shaft diameter, head diameter, head length.
            scale: Vector3 { x: 0.006, y: 0.012, z: 0.012 },
            color: ColorRgba { r: 1.0, g: 0.25, b: 0.1, a: 0.9 },
            lifetime: Duration::from_std(self.lifetime),
            frame_locked: false,
            points,
            colors: Vec::new(),
            texture_resource: String::new(),
            texture: CompressedImage { header, format: String::new(), data: Vec::new() },
            uv_coordinates: Vec::new(),
            text: String::new(),
            mesh_resource: String::new(),
            mesh_file: MeshFile::default(),
            mesh_use_embedded_materials: false,
        }
    }
}

fn vector(v: [f32; 3]) -> Vector3 {
    Vector3 { x: f64::from(v[0]), y: f64::from(v[1]), z: f64::from(v[2]) }
}

#[cfg(test)]
mod tests {
    use skinware_services::contact::Contact;

    use super::*;
    use crate::cdr::decode;
    use crate::standard::MARKER_ARRAY;

    #[test]
    fn each_contact_is_an_arrow_into_the_skin_after_a_delete_all() {
        let mut record = RegionContacts { count: 2, ..RegionContacts::default() };
        record.contacts[0] =
            Contact { centroid: [0.1, 0.2, 0.3], normal: [0.0, 0.0, 1.0], total: 50_000.0, ..Contact::default() };
        record.contacts[1] = Contact { centroid: [f32::NAN, 0.0, 0.0], normal: [0.0, 0.0, 1.0], ..Contact::default() };
        let drawing =
            ContactMarkers { geometry: None, root: "base_link", lifetime: std::time::Duration::from_millis(250) };
        let bytes = drawing.encode(&[RegionContacts::default(), record], Time { sec: 1, nanosec: 0 }).unwrap();
        let array: MarkerArray = decode(&bytes, MARKER_ARRAY).unwrap();
        assert_eq!(array.markers.len(), 2, "the delete-all and the one finite contact");
        assert_eq!(array.markers[0].action, MARKER_DELETE_ALL);
        let arrow = &array.markers[1];
        assert_eq!((arrow.kind, arrow.action, arrow.id), (MARKER_ARROW, MARKER_ADD, MAX_CONTACTS as i32));
        assert_eq!(arrow.header.frame_id, "base_link");
        assert_eq!(arrow.lifetime, Duration { sec: 0, nanosec: 250_000_000 });
        let [tail, head] = arrow.points[..] else { panic!("{:?}", arrow.points) };
        assert!((head.z - 0.3).abs() < 1e-6);
        assert!((tail.z - head.z - 0.07).abs() < 1e-6, "0.02 m + 50,000 × 1e-6 m: {}", tail.z - head.z);
    }
}

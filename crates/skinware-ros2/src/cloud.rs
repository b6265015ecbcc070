//! A layer's frame as `sensor_msgs/PointCloud2`s, one per robot link the
//! layer covers: each taxel's calibrated position and its response, so that
//! rviz2 and Foxglove draw the skin in 3-D on the robot, coloured by pressure.
//!
//! A cloud's `frame_id` is its link, and its points are the calibrated
//! positions. skinware's calibration gives every position in the robot's
//! frame at the calibration pose, so the skin is drawn as calibrated by
//! placing every link's frame at the robot's root: [`static_links`] gives
//! those identity transforms for `/tf_static`. On a robot whose own TF moves
//! the links, the clouds follow their links only if the calibration gives
//! each taxel's position in its link's frame (and `/tf_static` is left out).
//!
//! A point is 16 bytes: `x`, `y`, `z` (metres) and `response` (the raw
//! response, which a `float32` holds exactly), all little-endian `float32`.

use skinware_geometry::SkinGeometry;

use crate::cdr::{EncodeError, encode};
use crate::messages::{Header, Time, Vector3};
use crate::standard::{
    POINT_FIELD_FLOAT32, PointCloud2, PointField, Quaternion, TfMessage, Transform, TransformStamped,
};

/// Bytes per point.
pub const POINT_STEP: usize = 16;
/// Byte offset of the response in a point.
const RESPONSE_OFFSET: usize = 12;

/// One link's share of a layer.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkCloud {
    /// The link: the cloud's `frame_id`.
    pub link: String,
    /// The layer's sensors on it, as indices into the layer's frame, ascending.
    pub sensors: Vec<u32>,
    /// The points with their positions filled in and responses 0.
    template: Vec<u8>,
    /// Whether every position is finite (the geometry came from a file).
    finite: bool,
}

impl LinkCloud {
    /// Encodes the cloud of `responses` (one frame of the layer): a response
    /// the frame lacks (a short frame) is 0.
    pub fn encode(&self, responses: &[u16], stamp: Time) -> Result<Vec<u8>, EncodeError> {
        encode(&self.cloud(responses, stamp), 256 + self.template.len())
    }

    /// The cloud of `responses`, as [`encode`](Self::encode) encodes it (for
    /// a transport that encodes messages itself, such as DDS).
    pub fn cloud(&self, responses: &[u16], stamp: Time) -> PointCloud2 {
        let mut data = self.template.clone();
        for (point, &sensor) in data.chunks_exact_mut(POINT_STEP).zip(&self.sensors) {
            let response = responses.get(sensor as usize).copied().unwrap_or(0);
            point[RESPONSE_OFFSET..].copy_from_slice(&f32::from(response).to_le_bytes());
        }
        // `new` numbered the sensors in u32: their count fits too.
        let width = self.sensors.len() as u32;
        let field =
            |name: &str, offset: u32| PointField { name: name.into(), offset, datatype: POINT_FIELD_FLOAT32, count: 1 };
        PointCloud2 {
            header: Header { stamp, frame_id: self.link.clone() },
            height: 1,
            width,
            fields: vec![field("x", 0), field("y", 4), field("z", 8), field("response", 12)],
            is_bigendian: false,
            point_step: POINT_STEP as u32,
            row_step: width * POINT_STEP as u32,
            data,
            is_dense: self.finite,
        }
    }
}

/// The clouds of one layer, one per link it covers, in the geometry's link order.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerClouds {
    /// The layer's name.
    pub layer: String,
    /// Its clouds.
    pub clouds: Vec<LinkCloud>,
}

impl LayerClouds {
    /// The clouds of layer `layer` (an index into `geometry.layers`), or
    /// `None` for an index it does not have.
    pub fn new(geometry: &SkinGeometry, layer: usize) -> Option<LayerClouds> {
        let name = geometry.layers.get(layer)?.name.clone();
        let start = *geometry.layer_starts.get(layer)?;
        let end = *geometry.layer_starts.get(layer + 1)?;
        let mut clouds: Vec<LinkCloud> = Vec::new();
        for global in start..end {
            let link = usize::from(*geometry.link_of.get(global)?);
            let link_name = geometry.links.get(link)?;
            let position = geometry.positions.get(global)?;
            let cloud = match clouds.iter().position(|c| &c.link == link_name) {
                Some(found) => &mut clouds[found],
                None => {
                    clouds.push(LinkCloud {
                        link: link_name.clone(),
                        sensors: Vec::new(),
                        template: Vec::new(),
                        finite: true,
                    });
                    clouds.last_mut()?
                }
            };
            cloud.sensors.push(u32::try_from(global - start).ok()?);
            cloud.finite &= position.iter().all(|v| v.is_finite());
            for coordinate in position {
                cloud.template.extend_from_slice(&coordinate.to_le_bytes());
            }
            cloud.template.extend_from_slice(&0f32.to_le_bytes());
        }
        let order = |link: &str| geometry.links.iter().position(|l| l == link);
        clouds.sort_by_key(|c| order(&c.link));
        Some(LayerClouds { layer: name, clouds })
    }
}

/// The identity transforms from `root` to every link of `geometry`, for
/// `/tf_static`: a skin whose calibration is in the robot's frame, on a
/// robot that publishes no TF of its own, is drawn as calibrated.
pub fn static_links(geometry: &SkinGeometry, root: &str, stamp: Time) -> Result<Vec<u8>, EncodeError> {
    encode(&static_transforms(geometry, root, stamp), 64 + 128 * geometry.links.len())
}

/// The message [`static_links`] encodes.
pub fn static_transforms(geometry: &SkinGeometry, root: &str, stamp: Time) -> TfMessage {
    let transforms = geometry
        .links
        .iter()
        .filter(|link| link.as_str() != root)
        .map(|link| TransformStamped {
            header: Header { stamp, frame_id: root.to_owned() },
            child_frame_id: link.clone(),
            transform: Transform { translation: Vector3::default(), rotation: Quaternion::IDENTITY },
        })
        .collect();
    TfMessage { transforms }
}

#[cfg(test)]
mod tests {
    use skinware::TopologyBuilder;
    use skinware_geometry::Calibration;

    use super::*;
    use crate::cdr::decode;
    use crate::standard::{POINT_CLOUD2, TF_MESSAGE};

    fn two_link_geometry() -> SkinGeometry {
        let mut builder = TopologyBuilder::new("arm", "pressure", 50.0);
        builder.patch(1).module(1, [10, 11, 12]);
        let layer = builder.build().unwrap();
        let calibration = Calibration::parse(
            "skinware-calibration 1\n\
             arm 10 0.1 0.2 0.3 0 0 1 0.002 forearm\n\
             arm 11 0.4 0.5 0.6 0 0 1 0.002 hand\n\
             arm 12 0.7 0.8 0.9 0 0 1 0.002 forearm\n",
            "test",
        )
        .unwrap();
        SkinGeometry::build("test", &[layer], &calibration, &[]).unwrap()
    }

    #[test]
    fn a_layer_on_two_links_is_two_clouds_of_positions_and_responses() {
        let geometry = two_link_geometry();
        let layers = LayerClouds::new(&geometry, 0).unwrap();
        assert_eq!(layers.layer, "arm");
        let links: Vec<&str> = layers.clouds.iter().map(|c| c.link.as_str()).collect();
        assert_eq!(links.len(), 2);
        let forearm = layers.clouds.iter().find(|c| c.link == "forearm").unwrap();
        assert_eq!(forearm.sensors, [0, 2]);
        let bytes = forearm.encode(&[100, 200, 65535], Time { sec: 3, nanosec: 4 }).unwrap();
        let cloud: PointCloud2 = decode(&bytes, POINT_CLOUD2).unwrap();
        assert_eq!(cloud.header.frame_id, "forearm");
        assert_eq!((cloud.width, cloud.height, cloud.point_step, cloud.row_step), (2, 1, 16, 32));
        let floats: Vec<f32> = cloud.data.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert_eq!(floats, [0.1, 0.2, 0.3, 100.0, 0.7, 0.8, 0.9, 65535.0]);
        let names: Vec<&str> = cloud.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["x", "y", "z", "response"]);
    }

    #[test]
    fn a_short_frame_gives_zero_responses_not_a_panic() {
        let geometry = two_link_geometry();
        let layers = LayerClouds::new(&geometry, 0).unwrap();
        let cloud: PointCloud2 = decode(&layers.clouds[0].encode(&[], Time::default()).unwrap(), POINT_CLOUD2).unwrap();
        assert!(cloud.data.chunks_exact(16).all(|p| p[12..] == [0; 4]));
        assert!(LayerClouds::new(&geometry, 1).is_none());
    }

    #[test]
    fn every_link_hangs_from_the_root() {
        let geometry = two_link_geometry();
        let tf: TfMessage =
            decode(&static_links(&geometry, "base_link", Time::default()).unwrap(), TF_MESSAGE).unwrap();
        let children: Vec<&str> = tf.transforms.iter().map(|t| t.child_frame_id.as_str()).collect();
        assert_eq!(children.len(), 2);
        assert!(children.contains(&"hand") && children.contains(&"forearm"));
        assert!(tf.transforms.iter().all(|t| t.header.frame_id == "base_link" && t.transform.rotation.w == 1.0));
    }
}

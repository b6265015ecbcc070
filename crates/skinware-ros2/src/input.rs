//! What a ROS 2 tactile topic carries, as a skinware layer's responses: the
//! decoding behind the `ros2` driver kind (`skinware-dds`), kept here, free of
//! DDS, so that it is tested and fuzzed (`fuzz/fuzz_targets/ros2_input.rs`)
//! without building a DDS stack.
//!
//! | message | layout | response |
//! |---|---|---|
//! | `sensor_msgs/PointCloud2` | `N` points (`width × height`), a numeric field named by `field` (default `response`) | the field's value, rounded and clamped to 0..=65535 (NaN: 0) |
//! | `std_msgs/UInt16MultiArray` | `N` elements after `layout.data_offset` | the element |
//! | `std_msgs/Float32MultiArray` | `N` elements after `layout.data_offset`, full scale 0..1 | `round(v × 65535)`, clamped (NaN: 0) |

#![forbid(unsafe_code)]

use crate::standard::{
    FLOAT32_MULTI_ARRAY, Float32MultiArray, MultiArrayLayout, POINT_CLOUD2, PointCloud2, UINT16_MULTI_ARRAY,
    UInt16MultiArray,
};

/// A `message` or `field` setting a `ros2` layer cannot read.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("{0}")]
pub struct UnknownInput(pub String);

/// What a `ros2` layer's topic carries.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ros2Input {
    /// `sensor_msgs/PointCloud2`, the response in the named field.
    PointCloud2 {
        /// The field holding each point's response.
        field: String,
    },
    /// `std_msgs/UInt16MultiArray`: raw responses.
    UInt16MultiArray,
    /// `std_msgs/Float32MultiArray`: responses at full scale 0..1.
    Float32MultiArray,
}

impl Ros2Input {
    /// The input of a config's `message` (a full type name, or its short
    /// name) and `field` (a `PointCloud2`'s, default `response`).
    pub fn parse(message: &str, field: Option<&str>) -> Result<Ros2Input, UnknownInput> {
        let short = message.rsplit('/').next().unwrap_or(message);
        let package = message.split('/').next().filter(|_| message.contains('/'));
        let expected = if short == "PointCloud2" { "sensor_msgs" } else { "std_msgs" };
        if package.is_some_and(|package| package != expected) {
            return Err(UnknownInput(format!(
                "message = {message:?}: a ros2 layer reads {expected}'s {short}, not another package's"
            )));
        }
        let input = match short {
            "PointCloud2" => Ros2Input::PointCloud2 { field: field.unwrap_or("response").to_owned() },
            "UInt16MultiArray" => Ros2Input::UInt16MultiArray,
            "Float32MultiArray" => Ros2Input::Float32MultiArray,
            _ => {
                return Err(UnknownInput(format!(
                    "message = {message:?}: a ros2 layer reads {POINT_CLOUD2}, {UINT16_MULTI_ARRAY} or {FLOAT32_MULTI_ARRAY}"
                )));
            }
        };
        if field.is_some() && !matches!(input, Ros2Input::PointCloud2 { .. }) {
            return Err(UnknownInput(format!(
                "field = {:?} is a setting of a PointCloud2 topic, not of {message}",
                field.unwrap_or_default()
            )));
        }
        Ok(input)
    }

    /// Its full type name.
    pub fn type_name(&self) -> &'static str {
        match self {
            Ros2Input::PointCloud2 { .. } => POINT_CLOUD2,
            Ros2Input::UInt16MultiArray => UINT16_MULTI_ARRAY,
            Ros2Input::Float32MultiArray => FLOAT32_MULTI_ARRAY,
        }
    }
}

/// Why a message gave no frame.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InputError {
    /// The bytes are not a CDR message of the type.
    #[error("{0}")]
    Cdr(String),
    /// The message has another number of responses than the layer has sensors.
    #[error(
        "{what} holds {got} responses, but the layer has {want} sensors; publish one per sensor, in topology order"
    )]
    Count {
        /// The message type.
        what: &'static str,
        /// Responses in the message.
        got: usize,
        /// Sensors in the layer.
        want: usize,
    },
    /// The `PointCloud2` has no usable field of that name.
    #[error(
        "the PointCloud2 has no numeric field {field:?} inside its points (its fields: {fields:?}); set `field` to one of them"
    )]
    NoField {
        /// The field asked for.
        field: String,
        /// The fields it has.
        fields: Vec<String>,
    },
    /// The `PointCloud2`'s sizes disagree with its data.
    #[error("the PointCloud2's layout is inconsistent: {0}")]
    Layout(String),
}

/// Decodes `bytes`, a CDR message of `input`'s type, into `out` (one
/// response per sensor of the layer). Any bytes give `Ok` or an error.
pub fn decode(bytes: &[u8], input: &Ros2Input, out: &mut [u16]) -> Result<(), InputError> {
    let cdr = |e: crate::DecodeError| InputError::Cdr(e.to_string());
    match input {
        Ros2Input::PointCloud2 { field } => {
            let cloud: PointCloud2 = crate::decode(bytes, POINT_CLOUD2).map_err(cdr)?;
            from_cloud(&cloud, field, out)
        }
        Ros2Input::UInt16MultiArray => {
            let array: UInt16MultiArray = crate::decode(bytes, UINT16_MULTI_ARRAY).map_err(cdr)?;
            from_u16(&array, out)
        }
        Ros2Input::Float32MultiArray => {
            let array: Float32MultiArray = crate::decode(bytes, FLOAT32_MULTI_ARRAY).map_err(cdr)?;
            from_f32(&array, out)
        }
    }
}

/// The elements of an array message from its `data_offset`, if exactly `want`.
fn elements<'a, T>(
    layout: &MultiArrayLayout,
    data: &'a [T],
    what: &'static str,
    want: usize,
) -> Result<&'a [T], InputError> {
    let rest = data.get(layout.data_offset as usize..).unwrap_or_default();
    if rest.len() != want {
        return Err(InputError::Count { what, got: rest.len(), want });
    }
    Ok(rest)
}

/// A `UInt16MultiArray`'s responses.
pub fn from_u16(array: &UInt16MultiArray, out: &mut [u16]) -> Result<(), InputError> {
    out.copy_from_slice(elements(&array.layout, &array.data, UINT16_MULTI_ARRAY, out.len())?);
    Ok(())
}

/// A `Float32MultiArray`'s responses (full scale 0..1).
pub fn from_f32(array: &Float32MultiArray, out: &mut [u16]) -> Result<(), InputError> {
    let values = elements(&array.layout, &array.data, FLOAT32_MULTI_ARRAY, out.len())?;
    for (response, value) in out.iter_mut().zip(values) {
        *response = saturate(f64::from(*value) * f64::from(crate::RESPONSE_FULL_SCALE));
    }
    Ok(())
}

/// A response from any number: rounded, clamped to 0..=65535, NaN as 0.
fn saturate(value: f64) -> u16 {
    if value.is_nan() { 0 } else { value.round().clamp(0.0, 65535.0) as u16 }
}

/// A `PointCloud2`'s responses, from its field `field`.
pub fn from_cloud(cloud: &PointCloud2, field: &str, out: &mut [u16]) -> Result<(), InputError> {
    let points = u64::from(cloud.width) * u64::from(cloud.height);
    if points != out.len() as u64 {
        return Err(InputError::Count { what: POINT_CLOUD2, got: points as usize, want: out.len() });
    }
    let step = cloud.point_step as usize;
    let fields = || cloud.fields.iter().map(|f| f.name.clone()).collect::<Vec<_>>();
    let found = cloud.fields.iter().find(|f| f.name == field);
    let Some((offset, size)) = found.and_then(|f| Some((f.offset as usize, datatype_size(f.datatype)?))) else {
        return Err(InputError::NoField { field: field.to_owned(), fields: fields() });
    };
    if offset.checked_add(size).is_none_or(|end| end > step) {
        return Err(InputError::NoField { field: field.to_owned(), fields: fields() });
    }
    let rows = cloud.height as usize;
    let row_step = cloud.row_step as usize;
    let width = cloud.width as usize;
    // Every point's bytes must be in the data: the last row's last point ends the need.
    let needed = rows
        .checked_sub(1)
        .and_then(|last_row| last_row.checked_mul(row_step))
        .and_then(|start| start.checked_add(width.checked_mul(step)?));
    if row_step < width.saturating_mul(step) || needed.is_none_or(|needed| needed > cloud.data.len()) {
        return Err(InputError::Layout(format!(
            "{} × {} points of {step} bytes, rows of {row_step} bytes, in {} bytes of data",
            cloud.width,
            cloud.height,
            cloud.data.len()
        )));
    }
    let datatype = found.map_or(0, |f| f.datatype);
    let mut next = out.iter_mut();
    for row in 0..rows {
        for column in 0..width {
            let at = row * row_step + column * step + offset;
            let bytes = &cloud.data[at..at + size];
            if let Some(response) = next.next() {
                *response = saturate(read_number(bytes, datatype, cloud.is_bigendian));
            }
        }
    }
    Ok(())
}

/// The size of a `sensor_msgs/PointField` datatype (1..=8), if it is one.
fn datatype_size(datatype: u8) -> Option<usize> {
    match datatype {
        1 | 2 => Some(1),
        3 | 4 => Some(2),
        5..=7 => Some(4),
        8 => Some(8),
        _ => None,
    }
}

/// A number of `datatype` from its bytes (`bytes.len()` is its size).
fn read_number(bytes: &[u8], datatype: u8, big_endian: bool) -> f64 {
    let mut raw = [0u8; 8];
    raw[..bytes.len()].copy_from_slice(bytes);
    if big_endian {
        raw[..bytes.len()].reverse();
    }
    let [a, b, c, d, ..] = raw;
    match datatype {
        1 => f64::from(a as i8),
        2 => f64::from(a),
        3 => f64::from(i16::from_le_bytes([a, b])),
        4 => f64::from(u16::from_le_bytes([a, b])),
        5 => f64::from(i32::from_le_bytes([a, b, c, d])),
        6 => f64::from(u32::from_le_bytes([a, b, c, d])),
        7 => f64::from(f32::from_le_bytes([a, b, c, d])),
        _ => f64::from_le_bytes(raw),
    }
}

#[cfg(test)]
mod tests {
    use crate::Header;
    use crate::standard::PointField;
    use proptest::prelude::*;

    use super::*;

    fn cloud(values: &[f32], extra_field: bool) -> PointCloud2 {
        let step = if extra_field { 20 } else { 16 };
        let mut data = Vec::new();
        for (k, value) in values.iter().enumerate() {
            for coordinate in [k as f32, 0.0, 0.0, *value] {
                data.extend_from_slice(&coordinate.to_le_bytes());
            }
            if extra_field {
                data.extend_from_slice(&[0; 4]);
            }
        }
        let field = |name: &str, offset| PointField { name: name.into(), offset, datatype: 7, count: 1 };
        PointCloud2 {
            header: Header { stamp: crate::Time::default(), frame_id: String::new() },
            height: 1,
            width: values.len() as u32,
            fields: vec![field("x", 0), field("y", 4), field("z", 8), field("response", 12)],
            is_bigendian: false,
            point_step: step,
            row_step: step * values.len() as u32,
            data,
            is_dense: true,
        }
    }

    #[test]
    fn skinwares_own_clouds_read_back() {
        let mut out = [0u16; 4];
        from_cloud(&cloud(&[0.0, 1.4, 65535.0, 70000.0], true), "response", &mut out).unwrap();
        assert_eq!(out, [0, 1, 65535, 65535]);
        let bytes = crate::encode(&cloud(&[5.0, 6.0, 7.0, f32::NAN], false), 128).unwrap();
        decode(&bytes, &Ros2Input::PointCloud2 { field: "response".into() }, &mut out).unwrap();
        assert_eq!(out, [5, 6, 7, 0]);
    }

    #[test]
    fn misfits_are_named() {
        let mut out = [0u16; 3];
        let wrong_count = from_cloud(&cloud(&[1.0, 2.0], false), "response", &mut out).unwrap_err();
        assert!(wrong_count.to_string().contains("2 responses, but the layer has 3 sensors"), "{wrong_count}");
        let no_field = from_cloud(&cloud(&[1.0, 2.0, 3.0], false), "pressure", &mut out).unwrap_err();
        assert!(no_field.to_string().contains("\"response\""), "{no_field}");
        let mut short = cloud(&[1.0, 2.0, 3.0], false);
        short.data.truncate(40);
        assert!(matches!(from_cloud(&short, "response", &mut out), Err(InputError::Layout(_))));
        let array =
            UInt16MultiArray { layout: MultiArrayLayout { dim: Vec::new(), data_offset: 1 }, data: vec![9, 1, 2, 3] };
        from_u16(&array, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3], "data_offset skips the first");
        let full = Float32MultiArray { layout: MultiArrayLayout::default(), data: vec![0.0, 0.5, 2.0] };
        from_f32(&full, &mut out).unwrap();
        assert_eq!(out, [0, 32768, 65535]);
        assert!(Ros2Input::parse("std_msgs/msg/String", None).unwrap_err().to_string().contains("PointCloud2"));
        assert!(Ros2Input::parse("UInt16MultiArray", Some("x")).is_err());
    }

    /// The fuzz target's seeds (`fuzz/corpus/ros2_input`) are real messages
    /// of each type: a first byte picking the type and 4 sensors, then CDR.
    #[test]
    fn the_fuzz_seeds_decode() {
        let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus/ros2_input");
        let expected: [(&str, Ros2Input, [u16; 4]); 3] = [
            ("cloud", Ros2Input::PointCloud2 { field: "response".into() }, [0, 100, 200, 300]),
            ("uint16", Ros2Input::UInt16MultiArray, [1, 2, 3, 4]),
            ("float32", Ros2Input::Float32MultiArray, [0, 16384, 32768, 65535]),
        ];
        for (name, input, responses) in expected {
            let seed = std::fs::read(corpus.join(name)).unwrap();
            let mut out = [0u16; 4];
            decode(&seed[1..], &input, &mut out).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(out, responses, "{name}");
        }
    }

    proptest! {
        #[test]
        fn any_bytes_give_a_frame_or_an_error(bytes in proptest::collection::vec(any::<u8>(), 0..512), sensors in 0usize..16) {
            let mut out = vec![0u16; sensors];
            for input in [Ros2Input::PointCloud2 { field: "response".into() }, Ros2Input::UInt16MultiArray, Ros2Input::Float32MultiArray] {
                let _ = decode(&bytes, &input, &mut out);
            }
        }

        #[test]
        fn any_cloud_layout_gives_a_frame_or_an_error(
            width in 0u32..8, height in 0u32..4, step in 0u32..40, row_step in 0u32..200,
            offset in 0u32..40, datatype in 0u8..10, data_len in 0usize..600, big in any::<bool>(),
        ) {
            let cloud = PointCloud2 {
                header: Header { stamp: crate::Time::default(), frame_id: String::new() },
                height,
                width,
                fields: vec![PointField { name: "response".into(), offset, datatype, count: 1 }],
                is_bigendian: big,
                point_step: step,
                row_step,
                data: vec![7; data_len],
                is_dense: true,
            };
            let mut out = vec![0u16; (width * height) as usize];
            let _ = from_cloud(&cloud, "response", &mut out);
        }
    }
}

//! Calibration: where each sensor sits on the robot.
//!
//! Two text formats are read. Both are keyed by (layer name or sensor type, uid),
//! so one file can describe many layers of the same sensor type.
//!
//! * The skinware format, first line `skinware-calibration 1`, then one sensor
//!   per line: `key uid x y z nx ny nz radius link`, lengths in metres, the
//!   normal any non-zero vector, `link` the robot link (body part) name.
//!   Blank lines and `#` comments are ignored.
//! * The original Skinware's `skin.calib`: a first line `N`, then N lines of
//!   `type uid px py pz ox oy oz radius link`, positions and radius in integer
//!   nanometres.
//!
//! [`Calibration::parse`] tells the two apart by their first line.

#![forbid(unsafe_code)]

use std::collections::HashMap;
use std::path::Path;

use super::GeometryError;

/// The calibration of one sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorCalibration {
    /// Position, metres, in the robot's frame.
    pub position: [f64; 3],
    /// Outward unit normal.
    pub normal: [f64; 3],
    /// Radius of the sensing area, metres.
    pub radius: f64,
    /// Robot link (body part) the sensor is on.
    pub link: String,
}

/// Calibrations keyed by (layer name or sensor type, uid).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibration {
    entries: HashMap<(String, u32), SensorCalibration>,
    /// Entries in insertion order, for a canonical encoding.
    order: Vec<(String, u32)>,
}

impl Calibration {
    /// An empty calibration.
    pub fn new() -> Calibration {
        Calibration::default()
    }

    /// Adds (or replaces) the calibration of sensor `uid` under `key`, a layer
    /// name or a sensor type. The normal is normalised; a zero or non-finite
    /// value is refused.
    pub fn insert(&mut self, key: &str, uid: u32, sensor: SensorCalibration) -> Result<(), GeometryError> {
        self.try_insert(key, uid, sensor).map_err(|reason| GeometryError::Sensor { key: key.to_owned(), uid, reason })
    }

    fn try_insert(&mut self, key: &str, uid: u32, mut sensor: SensorCalibration) -> Result<(), String> {
        let finite = sensor.position.iter().chain(&sensor.normal).all(|v| v.is_finite()) && sensor.radius.is_finite();
        if !finite {
            return Err("a coordinate is not a finite number".to_owned());
        }
        let norm = sensor.normal.iter().map(|n| n * n).sum::<f64>().sqrt();
        if norm < 1e-12 {
            return Err("the normal is zero; give the outward direction of the sensor".to_owned());
        }
        if sensor.radius < 0.0 {
            return Err(format!("radius {} is negative", sensor.radius));
        }
        if sensor.link.is_empty() || sensor.link.chars().any(char::is_whitespace) {
            return Err(format!("link {:?} must be one word", sensor.link));
        }
        sensor.normal = sensor.normal.map(|n| n / norm);
        let entry = (key.to_owned(), uid);
        if self.entries.insert(entry.clone(), sensor).is_none() {
            self.order.push(entry);
        }
        Ok(())
    }

    /// The calibration of sensor `uid` of a layer called `layer` with sensors of
    /// type `sensor_type`: an entry under the layer's name wins over one under
    /// its type.
    pub fn get(&self, layer: &str, sensor_type: &str, uid: u32) -> Option<&SensorCalibration> {
        self.entries.get(&(layer.to_owned(), uid)).or_else(|| self.entries.get(&(sensor_type.to_owned(), uid)))
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether there are no entries.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Reads a calibration file in either format.
    pub fn load(path: &Path) -> Result<Calibration, GeometryError> {
        // A line per taxel: 1 GiB is thousands of bytes for each of 300,000.
        let text = skinware::shm::read_named_text(path, 1 << 30).map_err(|e| GeometryError::Calibration {
            source_name: path.display().to_string(),
            line: 0,
            message: format!("cannot read it: {e}"),
        })?;
        Calibration::parse(&text, &path.display().to_string())
    }

    /// Parses a calibration in either format; `source_name` names it in errors.
    pub fn parse(text: &str, source_name: &str) -> Result<Calibration, GeometryError> {
        let error = |line: usize, message: String| GeometryError::Calibration {
            source_name: source_name.to_owned(),
            line,
            message,
        };
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.split('#').next().unwrap_or("").trim()));
        let mut content = lines.by_ref().filter(|(_, l)| !l.is_empty());
        let Some((first_line, first)) = content.next() else {
            return Err(error(1, "the file is empty; expected `skinware-calibration 1` or a skin.calib count".into()));
        };
        if first == "skinware-calibration 1" {
            parse_native(content, &error)
        } else if let Ok(count) = first.parse::<usize>() {
            parse_skin_calib(count, first_line, content, &error)
        } else if first.starts_with("skinware-calibration") {
            Err(error(
                first_line,
                format!("unsupported version {first:?}; this program reads `skinware-calibration 1`"),
            ))
        } else {
            Err(error(
                first_line,
                format!(
                    "unknown format: the first line is {first:?}; a skinware calibration starts with `skinware-calibration 1`, a skin.calib with the number of sensors"
                ),
            ))
        }
    }

    /// Writes the calibration in the skinware format.
    pub fn to_native_text(&self) -> String {
        let mut out = String::from("skinware-calibration 1\n# key uid x y z nx ny nz radius link (metres)\n");
        for key in &self.order {
            let s = &self.entries[key];
            let [x, y, z] = s.position;
            let [nx, ny, nz] = s.normal;
            out.push_str(&format!("{} {} {x} {y} {z} {nx} {ny} {nz} {} {}\n", key.0, key.1, s.radius, s.link));
        }
        out
    }
}

type LineError<'a> = dyn Fn(usize, String) -> GeometryError + 'a;

fn parse_native<'a>(
    content: impl Iterator<Item = (usize, &'a str)>,
    error: &LineError<'_>,
) -> Result<Calibration, GeometryError> {
    let mut calibration = Calibration::new();
    for (line, text) in content {
        let fields: Vec<&str> = text.split_whitespace().collect();
        if fields.len() != 10 {
            return Err(error(
                line,
                format!("expected 10 fields `key uid x y z nx ny nz radius link`, found {}", fields.len()),
            ));
        }
        let uid = parse_field::<u32>(fields[1], "uid", line, error)?;
        let mut numbers = [0.0f64; 7];
        for (k, (value, name)) in fields[2..9].iter().zip(["x", "y", "z", "nx", "ny", "nz", "radius"]).enumerate() {
            numbers[k] = parse_field::<f64>(value, name, line, error)?;
        }
        let sensor = SensorCalibration {
            position: [numbers[0], numbers[1], numbers[2]],
            normal: [numbers[3], numbers[4], numbers[5]],
            radius: numbers[6],
            link: fields[9].to_owned(),
        };
        if calibration.get(fields[0], fields[0], uid).is_some() {
            return Err(error(line, format!("{} uid {uid} is calibrated twice", fields[0])));
        }
        calibration.insert(fields[0], uid, sensor).map_err(|e| error(line, e.to_string()))?;
    }
    Ok(calibration)
}

fn parse_skin_calib<'a>(
    count: usize,
    count_line: usize,
    content: impl Iterator<Item = (usize, &'a str)>,
    error: &LineError<'_>,
) -> Result<Calibration, GeometryError> {
    const NM: f64 = 1e-9;
    let mut calibration = Calibration::new();
    let mut last_line = count_line;
    for (line, text) in content {
        last_line = line;
        if calibration.len() == count {
            return Err(error(line, format!("more sensors than the {count} announced on line {count_line}")));
        }
        let fields: Vec<&str> = text.split_whitespace().collect();
        if fields.len() != 10 {
            return Err(error(
                line,
                format!("expected 10 fields `type uid px py pz ox oy oz radius link`, found {}", fields.len()),
            ));
        }
        let uid = parse_field::<u32>(fields[1], "uid", line, error)?;
        let mut numbers = [0i64; 7];
        for (k, (value, name)) in fields[2..9].iter().zip(["px", "py", "pz", "ox", "oy", "oz", "radius"]).enumerate() {
            numbers[k] = parse_field::<i64>(value, &format!("{name} (integer nanometres)"), line, error)?;
        }
        let sensor = SensorCalibration {
            position: [numbers[0] as f64 * NM, numbers[1] as f64 * NM, numbers[2] as f64 * NM],
            normal: [numbers[3] as f64, numbers[4] as f64, numbers[5] as f64],
            radius: numbers[6] as f64 * NM,
            link: fields[9].to_owned(),
        };
        if calibration.get(fields[0], fields[0], uid).is_some() {
            return Err(error(line, format!("type {} uid {uid} is calibrated twice", fields[0])));
        }
        calibration.insert(fields[0], uid, sensor).map_err(|e| error(line, e.to_string()))?;
    }
    if calibration.len() != count {
        return Err(error(
            last_line,
            format!("line {count_line} announces {count} sensors but the file holds {}", calibration.len()),
        ));
    }
    Ok(calibration)
}

fn parse_field<T: std::str::FromStr>(
    value: &str,
    name: &str,
    line: usize,
    error: &LineError<'_>,
) -> Result<T, GeometryError> {
    value
        .parse::<T>()
        .map_err(|_| error(line, format!("{name} {value:?} is not a valid {}", std::any::type_name::<T>())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg_attr(miri, ignore = "no unsafe code here; too slow under Miri")]
    fn native_format_round_trips() {
        let text = "skinware-calibration 1\n# comment\nskin-0 7 0.1 0.2 0.3 0 0 2 0.002 forearm\n\npressure 8 0 0 0 1 0 0 0.002 palm # trailing\n";
        let calibration = Calibration::parse(text, "test").unwrap();
        assert_eq!(calibration.len(), 2);
        let seven = calibration.get("skin-0", "pressure", 7).unwrap();
        assert_eq!(seven.normal, [0.0, 0.0, 1.0]);
        assert_eq!(seven.link, "forearm");
        // Looked up by type when the layer name has no entry.
        assert_eq!(calibration.get("skin-0", "pressure", 8).unwrap().link, "palm");
        assert!(calibration.get("skin-0", "other", 8).is_none());
        let again = Calibration::parse(&calibration.to_native_text(), "again").unwrap();
        assert_eq!(again, calibration);
    }

    #[test]
    #[cfg_attr(miri, ignore = "no unsafe code here; too slow under Miri")]
    fn skin_calib_is_imported_in_nanometres() {
        let text = "2\n0 1 1000000 0 -2000000 0 0 1000 2000000 3\n0 2 0 1000000 0 1 1 0 2000000 3\n";
        let calibration = Calibration::parse(text, "skin.calib").unwrap();
        let one = calibration.get("layer", "0", 1).unwrap();
        assert_eq!(one.position, [1e-3, 0.0, -2e-3]);
        assert_eq!(one.normal, [0.0, 0.0, 1.0]);
        assert!((one.radius - 2e-3).abs() < 1e-15);
        assert_eq!(one.link, "3");
        let two = calibration.get("layer", "0", 2).unwrap();
        assert!((two.normal[0] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
    }
}

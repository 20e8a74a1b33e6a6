//! A rotating LiDAR head: a table of beams (elevation, azimuth offset), the azimuth steps
//! of one rotation, the rotation rate and the ranges it reports. Presets from the makers'
//! datasheets, or any table from a JSON file (`docs/scan.md` has the schema).

use serde::Deserialize;
use std::fmt;

/// A validated sensor. Beams are in ring order: sorted by elevation, lowest first (ties
/// keep table order), so `ring` is the index into [`Sensor::elevations_deg`].
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    /// Name, for messages and file headers.
    pub name: String,
    /// Each beam's elevation above the sensor's x–y plane, degrees, ascending.
    pub elevations_deg: Vec<f64>,
    /// Each beam's azimuth offset from the head's azimuth, degrees (same order).
    pub azimuth_offsets_deg: Vec<f64>,
    /// Azimuth steps (firings of every beam) in one rotation.
    pub steps_per_rotation: u32,
    /// Rotations per second.
    pub rotation_hz: f64,
    /// Nearest range reported, world units: surfaces nearer are not seen.
    pub min_range: f64,
    /// Farthest range reported, world units.
    pub max_range: f64,
}

/// A sensor that could not be read: the field (`sensor.elevations_deg[3]`) and why.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorError(pub String);

impl fmt::Display for SensorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SensorError {}

/// The sensor JSON file, before validation.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorFile {
    /// Name (default `custom`).
    #[serde(default)]
    pub name: Option<String>,
    /// Beam elevations, degrees, in -90..90, any order.
    pub elevations_deg: Vec<f64>,
    /// Per-beam azimuth offsets, degrees, in -180..180 (default all 0), in the order of
    /// `elevations_deg`.
    #[serde(default)]
    pub azimuth_offsets_deg: Option<Vec<f64>>,
    /// Degrees between azimuth steps; 360 must be a whole multiple of it (to 1e-9).
    /// Exactly one of this and `points_per_rotation`.
    #[serde(default)]
    pub azimuth_resolution_deg: Option<f64>,
    /// Azimuth steps per rotation.
    #[serde(default)]
    pub points_per_rotation: Option<u64>,
    /// Rotations per second, > 0.
    pub rotation_hz: f64,
    /// Nearest range reported, >= 0.
    pub min_range: f64,
    /// Farthest range reported, > min_range, finite.
    pub max_range: f64,
}

/// Most beams in a sensor table.
pub const MAX_BEAMS: usize = 1024;
/// Most azimuth steps in a rotation.
pub const MAX_STEPS: u64 = 1 << 20;

/// The presets: `(name, what it is)`.
pub const PRESETS: [(&str, &str); 3] = [
    (
        "vlp16",
        "Velodyne VLP-16: 16 beams, -15..15 deg by 2, 0.2 deg at 10 Hz, 100 m",
    ),
    (
        "hdl32",
        "Velodyne HDL-32E: 32 beams, -30.67..10.67 deg by 4/3, 0.16 deg at 10 Hz, 100 m",
    ),
    (
        "os1-64",
        "Ouster OS1-64: 64 beams uniform over 33.2 deg (+-16.6), 1024 steps at 10 Hz, 120 m",
    ),
];

impl Sensor {
    /// A preset by name ([`PRESETS`]).
    pub fn preset(name: &str) -> Option<Sensor> {
        let uniform = |n: usize, lo: f64, hi: f64| -> Vec<f64> {
            (0..n)
                .map(|k| lo + (hi - lo) * k as f64 / (n - 1) as f64)
                .collect()
        };
        let (elevations, steps, range) = match name {
            // VLP-16 user manual: 16 lasers from -15 to +15 degrees, 2 degrees apart; 0.2
            // degrees at 10 Hz (1800 firings a turn); range up to 100 m. Its lasers fire in
            // the interleaved order -15, 1, -13, 3, ... within a 55.296 us cycle: here every
            // beam of a step fires at the step's time, and ring = the beam sorted by
            // elevation (ring 0 = -15 degrees), as the Velodyne ROS driver numbers rings.
            "vlp16" => (uniform(16, -15.0, 15.0), 1800, 100.0),
            // HDL-32E datasheet: 32 lasers from -30.67 to +10.67 degrees (4/3 degree
            // spacing), 0.16 degrees at 10 Hz (2250 firings a turn), 80-100 m.
            "hdl32" => (uniform(32, -30.67, 10.67), 2250, 100.0),
            // Ouster OS1-64: 33.2 degrees vertical field of view (+-16.6), beams uniform;
            // 1024 columns at 10 Hz; 120 m.
            "os1-64" => (uniform(64, -16.6, 16.6), 1024, 120.0),
            _ => return None,
        };
        let n = elevations.len();
        Some(Sensor {
            name: name.to_string(),
            elevations_deg: elevations,
            azimuth_offsets_deg: vec![0.0; n],
            steps_per_rotation: steps,
            rotation_hz: 10.0,
            // Not on the datasheets as a hard limit; a near blind zone of this size is
            // typical of these heads.
            min_range: 0.5,
            max_range: range,
        })
    }

    /// Read and validate a sensor JSON text; every error names its field under `sensor.`.
    pub fn from_json(text: &str) -> Result<Sensor, SensorError> {
        let mut de = serde_json::Deserializer::from_str(text);
        // Read as an object only: an array of the fields in order would be accepted by
        // serde's derive.
        let file: crate::scene::strict::Object<SensorFile> =
            serde_path_to_error::deserialize(&mut de).map_err(|e| {
                let path = e.path().to_string();
                let field = if path == "." || path == "?" {
                    "sensor".to_string()
                } else {
                    format!("sensor.{path}")
                };
                SensorError(format!("{field}: {}", e.into_inner()))
            })?;
        de.end()
            .map_err(|e| SensorError(format!("sensor: text after the JSON object: {e}")))?;
        file.0.validate()
    }

    /// Beams (rings).
    pub fn beams(&self) -> usize {
        self.elevations_deg.len()
    }

    /// Seconds between azimuth steps: one rotation's time over its steps.
    pub fn step_seconds(&self) -> f64 {
        1.0 / (self.steps_per_rotation as f64 * self.rotation_hz)
    }
}

/// The error of `field`, long numbers in it cut ([`crate::scene::strict::shorten`]: a
/// resolution of 1e-300 prints 300 digits).
fn bad(field: impl fmt::Display, msg: impl fmt::Display) -> SensorError {
    SensorError(crate::scene::strict::shorten(&format!(
        "sensor.{field}: {msg}"
    )))
}

impl SensorFile {
    /// Check every field and sort the beams into rings.
    pub fn validate(self) -> Result<Sensor, SensorError> {
        // The name goes into the summary line and the file headers as it is.
        if let Some(name) = &self.name
            && name.chars().any(char::is_control)
        {
            return Err(bad(
                "name",
                format!("must not hold control characters, got {name:?}"),
            ));
        }
        let n = self.elevations_deg.len();
        if n == 0 || n > MAX_BEAMS {
            return Err(bad(
                "elevations_deg",
                format!("must list 1..={MAX_BEAMS} beams, got {n}"),
            ));
        }
        for (i, &e) in self.elevations_deg.iter().enumerate() {
            if !(-90.0..=90.0).contains(&e) {
                return Err(bad(
                    format_args!("elevations_deg[{i}]"),
                    format!("{e} is outside -90..90"),
                ));
            }
        }
        let offsets = self.azimuth_offsets_deg.unwrap_or_else(|| vec![0.0; n]);
        if offsets.len() != n {
            return Err(bad(
                "azimuth_offsets_deg",
                format!(
                    "must have one value per beam ({n}, as elevations_deg), got {}",
                    offsets.len()
                ),
            ));
        }
        for (i, &a) in offsets.iter().enumerate() {
            if !(-180.0..=180.0).contains(&a) {
                return Err(bad(
                    format_args!("azimuth_offsets_deg[{i}]"),
                    format!("{a} is outside -180..180"),
                ));
            }
        }
        let steps = match (self.azimuth_resolution_deg, self.points_per_rotation) {
            (Some(_), Some(_)) | (None, None) => {
                return Err(bad(
                    "azimuth_resolution_deg",
                    "give exactly one of azimuth_resolution_deg and points_per_rotation",
                ));
            }
            (Some(res), None) => {
                if !(res > 0.0 && res <= 360.0) {
                    return Err(bad(
                        "azimuth_resolution_deg",
                        format!("{res} is outside (0, 360]"),
                    ));
                }
                let steps = (360.0 / res).round();
                // 360/res must be whole: a rotation is a whole number of firings.
                if (steps * res - 360.0).abs() > 1e-9 * 360.0 || steps > MAX_STEPS as f64 {
                    return Err(bad(
                        "azimuth_resolution_deg",
                        format!(
                            "{res} does not divide 360 into a whole number of steps (at most {MAX_STEPS})"
                        ),
                    ));
                }
                steps as u32
            }
            (None, Some(p)) => {
                if p == 0 || p > MAX_STEPS {
                    return Err(bad(
                        "points_per_rotation",
                        format!("{p} is outside 1..={MAX_STEPS}"),
                    ));
                }
                p as u32
            }
        };
        if !(self.rotation_hz > 0.0 && self.rotation_hz.is_finite()) {
            return Err(bad(
                "rotation_hz",
                format!("{} must be finite and > 0", self.rotation_hz),
            ));
        }
        // Each step's time is `s / (steps · hz)`: the period must be finite (not a
        // subnormal rate's infinity) and a step's time a normal number (not zero).
        let step = 1.0 / (f64::from(steps) * self.rotation_hz);
        if !(step.is_normal() && (1.0 / self.rotation_hz).is_finite()) {
            return Err(bad(
                "rotation_hz",
                format!(
                    "{:e} gives a step time of {step:e} s ({steps} steps a rotation): must \
                     give a finite, non-zero time between steps",
                    self.rotation_hz
                ),
            ));
        }
        if !(self.min_range >= 0.0 && self.min_range.is_finite()) {
            return Err(bad(
                "min_range",
                format!("{} must be finite and >= 0", self.min_range),
            ));
        }
        if !(self.max_range > self.min_range && self.max_range.is_finite()) {
            return Err(bad(
                "max_range",
                format!(
                    "{} must be finite and > min_range ({})",
                    self.max_range, self.min_range
                ),
            ));
        }
        // Rings: beams sorted by elevation (stable, so ties keep table order).
        let mut ring: Vec<usize> = (0..n).collect();
        ring.sort_by(|&a, &b| self.elevations_deg[a].total_cmp(&self.elevations_deg[b]));
        Ok(Sensor {
            name: self.name.unwrap_or_else(|| "custom".to_string()),
            elevations_deg: ring.iter().map(|&i| self.elevations_deg[i]).collect(),
            azimuth_offsets_deg: ring.iter().map(|&i| offsets[i]).collect(),
            steps_per_rotation: steps,
            rotation_hz: self.rotation_hz,
            min_range: self.min_range,
            max_range: self.max_range,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_match_the_datasheets() {
        let v = Sensor::preset("vlp16").unwrap();
        assert_eq!(v.beams(), 16);
        assert_eq!(v.elevations_deg[0], -15.0);
        assert_eq!(v.elevations_deg[1], -13.0);
        assert_eq!(v.elevations_deg[15], 15.0);
        let h = Sensor::preset("hdl32").unwrap();
        assert_eq!(h.beams(), 32);
        assert!((h.elevations_deg[1] - h.elevations_deg[0] - 4.0 / 3.0).abs() < 1e-3);
        let o = Sensor::preset("os1-64").unwrap();
        assert_eq!((o.elevations_deg[0], o.elevations_deg[63]), (-16.6, 16.6));
        assert!(Sensor::preset("hdl64").is_none());
    }

    #[test]
    fn errors_name_the_field() {
        let e = Sensor::from_json(
            r#"{"elevations_deg": [0, 1, 2, 95], "points_per_rotation": 10,
                "rotation_hz": 10, "min_range": 0, "max_range": 10}"#,
        )
        .unwrap_err();
        assert_eq!(e.0, "sensor.elevations_deg[3]: 95 is outside -90..90");
        let e = Sensor::from_json(r#"{"elevations_deg": [0], "rotation_hz": 10}"#).unwrap_err();
        assert!(e.0.starts_with("sensor: missing field"), "{e}");
        let e = Sensor::from_json(
            r#"{"name": "x\u001b[31m", "elevations_deg": [0], "points_per_rotation": 10,
                "rotation_hz": 10, "min_range": 0, "max_range": 10}"#,
        )
        .unwrap_err();
        assert_eq!(
            e.0,
            r#"sensor.name: must not hold control characters, got "x\u{1b}[31m""#
        );
        // 1e-300 printed whole is 300 digits; the message keeps 28 of them.
        let e = Sensor::from_json(
            r#"{"elevations_deg": [0], "azimuth_resolution_deg": 1e-300,
                "rotation_hz": 10, "min_range": 0, "max_range": 10}"#,
        )
        .unwrap_err();
        assert!(e.0.len() < 200 && e.0.contains("more)"), "{e}");
        let e = Sensor::from_json(r#"{"elevations_deg": ["a"]}"#).unwrap_err();
        assert!(
            e.0.starts_with("sensor.elevations_deg[0]: invalid type"),
            "{e}"
        );
    }

    #[test]
    fn rings_sort_by_elevation() {
        let s = Sensor::from_json(
            r#"{"elevations_deg": [3, -1, 1], "azimuth_offsets_deg": [30, 10, 20],
                "azimuth_resolution_deg": 0.5, "rotation_hz": 20, "min_range": 0.1,
                "max_range": 50}"#,
        )
        .unwrap();
        assert_eq!(s.elevations_deg, [-1.0, 1.0, 3.0]);
        assert_eq!(s.azimuth_offsets_deg, [10.0, 20.0, 30.0]);
        assert_eq!(s.steps_per_rotation, 720);
    }
}

//! The AOV table: everything cylaov knows about each AOV in one place, so that the EXR
//! writer, the header and camera JSON, the per-AOV layout, the Mitsuba reference, the
//! comparison and the README's AOV table all read it instead of spelling names by string.
//!
//! Adding an AOV means one [`Aov`] variant, one row of [`AOV_TABLE`], its computation in
//! the tracer and its test.

use crate::scene::camera::Projection;
use serde::{Deserialize, Serialize};

crate::choice_enum! {
    /// One AOV ([`AOV_TABLE`] says what each stores).
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    pub enum Aov {
        /// Euclidean distance from the camera origin to the hit.
        Distance = "distance",
        /// Planar depth: camera-space z of the hit.
        Depth = "depth",
        /// World-space unit outward normal (normal.X/Y/Z).
        Normal = "normal",
        /// World-space hit point (position.X/Y/Z).
        Position = "position",
        /// u32 id of the hit cylinder (0 = miss).
        ShapeId = "shape_id",
        /// u32 part of the hit cylinder: 0 miss, 1 side seen from outside, 2 side seen from
        /// inside (the wall's inner face, e.g. through an open end), 3 bottom cap (at `p0`),
        /// 4 top cap (at `p1`). With `shape_id` it is the pixel identity verification uses.
        Part = "part",
        /// Camera-space unit outward normal, OpenCV axes: x right, y down, z forward
        /// (normal_camera.X/Y/Z).
        NormalCamera = "normal_camera",
        /// u32 label of the hit cylinder (its `label`, the user's class; 0 = miss or none):
        /// class masks beside `shape_id`'s instance masks.
        Label = "label",
        /// Surface coordinates as Mitsuba 3's cylinder reports them (uv.U, uv.V): on the
        /// side the turn around the axis in `[0, 1)` and the axial fraction from `p0`; on a
        /// cap the same turn and the distance from the axis over the radius.
        Uv = "uv",
    }
}

impl Aov {
    /// Every AOV, in the order outputs list them: the table's order.
    pub const ALL: [Aov; AOV_TABLE.len()] = {
        let mut all = [Aov::Distance; AOV_TABLE.len()];
        let mut i = 0;
        while i < all.len() {
            all[i] = AOV_TABLE[i].aov;
            i += 1;
        }
        all
    };

    /// The AOV's name as scene files and the command line spell it.
    pub fn name(self) -> &'static str {
        self.spec().name
    }

    /// Whether the AOV is stored as u32 samples (ids), not float32.
    pub fn is_u32(self) -> bool {
        self.spec().sample == SampleType::U32
    }

    /// The AOV named `s` (as [`Aov::name`] spells it), or `None`.
    pub fn parse(s: &str) -> Option<Aov> {
        Aov::ALL.into_iter().find(|a| a.name() == s)
    }

    /// `list` in its order with repeats dropped: an AOV asked for twice is stored once (an
    /// EXR's channels and attributes, a per-AOV file, must each be unique).
    pub fn without_repeats(list: &[Aov]) -> Vec<Aov> {
        let mut out: Vec<Aov> = Vec::with_capacity(list.len());
        for &a in list {
            if !out.contains(&a) {
                out.push(a);
            }
        }
        out
    }
}

/// How an AOV's samples are stored in the layered EXR and handed to Python.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    /// float32 samples.
    F32,
    /// u32 samples (ids).
    U32,
}

impl SampleType {
    /// The short name the README's AOV table and `cylaov aovs` print.
    pub fn name(self) -> &'static str {
        match self {
            SampleType::F32 => "f32",
            SampleType::U32 => "u32",
        }
    }
}

/// What `compare` (and so `verify`) judges an AOV by.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CompareMetric {
    /// Relative error `|a − b| / max(|a|, |b|)` per pixel (the `--rel` tolerance).
    Relative,
    /// Angle between the two unit vectors, in degrees (the `--normal-deg` tolerance).
    AngleDeg,
    /// Euclidean distance between the two points, absolute and relative to `distance`.
    PointDistance,
    /// Pixel identity: equal labels or a classified mismatch (silhouette, seam, interior).
    Identity,
    /// Absolute error of `u` modulo 1 (a turn: 0.999 and 0.001 are 0.002 apart) and of
    /// `v`, on pixels both images hit on the same cylinder's side.
    Periodic,
    /// Not compared (it follows from another AOV that is).
    None,
}

impl CompareMetric {
    /// What `cylaov aovs` prints for the metric.
    pub fn describe(self) -> &'static str {
        match self {
            CompareMetric::Relative => "relative error",
            CompareMetric::AngleDeg => "angle (degrees)",
            CompareMetric::PointDistance => "point distance, relative to `distance`",
            CompareMetric::Identity => "pixel identity",
            CompareMetric::Periodic => "u modulo 1 and v, absolute, side pixels",
            CompareMetric::None => "not compared",
        }
    }
}

/// Where a Mitsuba reference takes an AOV from: an entry of the `aov` integrator
/// (`prefix:mitsuba_aov`), always or only when a check asks for the AOV, or derived from
/// other AOVs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MitsubaSource {
    /// Every reference renders this entry (the exported scene's integrator lists it).
    Rendered(&'static str),
    /// Rendered when a check asks for the AOV: the reference script adds the entry to the
    /// integrator's list (the exported XML and the committed references stay as they are).
    OnRequest(&'static str),
    /// Computed from the other AOVs and the scene.
    Derived,
}

impl MitsubaSource {
    /// The integrator entry, if Mitsuba renders one.
    pub fn entry(self) -> Option<&'static str> {
        match self {
            MitsubaSource::Rendered(e) | MitsubaSource::OnRequest(e) => Some(e),
            MitsubaSource::Derived => None,
        }
    }
}

/// One AOV's row of the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AovSpec {
    /// The AOV this row describes.
    pub aov: Aov,
    /// Its name in scene files, on the command line and as a Python key.
    pub name: &'static str,
    /// Its channels in the layered EXR, in order: one (`NAME`) or two or three
    /// (`NAME.X/Y/Z`, `NAME.U/V`); one to three, as the per-AOV layout can store them.
    pub channels: &'static [&'static str],
    /// Its sample type in the layered EXR.
    pub sample: SampleType,
    /// Its samples on a miss, as the header and camera JSON write it.
    pub miss: &'static str,
    /// What it holds, as the EXR header (`cylaov:channel:NAME`) and camera JSON write it.
    pub meaning: &'static str,
    /// Where a Mitsuba reference takes it from.
    pub mitsuba: MitsubaSource,
    /// What `compare` judges it by.
    pub metric: CompareMetric,
}

impl AovSpec {
    /// Its channel names in the per-AOV layout, by channel count: `Y`; `R, G`; `R, G, B`
    /// (the names OpenCV and imageio map to grey, two-channel and colour images).
    pub const fn per_aov_channels(&self) -> &'static [&'static str] {
        match self.channels.len() {
            1 => &["Y"],
            2 => &["R", "G"],
            3 => &["R", "G", "B"],
            // `AOV_TABLE` holds no other row: checked when it is compiled (below).
            _ => &[],
        }
    }

    /// The meaning under `projection`: the table's, except `depth` under a camera whose
    /// depth is not planar everywhere (an equirectangular or fisheye camera), which says
    /// what it holds there.
    pub fn meaning_under(&self, projection: &Projection) -> String {
        match (self.aov, projection.depth_kind()) {
            (Aov::Depth, kind) if kind != "planar" => {
                format!("{kind} depth: {}, world units", projection.depth_meaning())
            }
            _ => self.meaning.to_string(),
        }
    }

    /// The `cylaov:channel:NAME` header text: channels, meaning under `projection`
    /// ([`Self::meaning_under`]) and miss value.
    pub fn header_text_under(&self, projection: &Projection) -> String {
        format!(
            "{}: {}; miss = {}",
            self.channels.join(", "),
            self.meaning_under(projection),
            self.miss
        )
    }
}

/// Every AOV's row, in [`Aov::ALL`] order (so `AOV_TABLE[aov as usize]` is its row).
pub const AOV_TABLE: &[AovSpec] = &[
    AovSpec {
        aov: Aov::Distance,
        name: "distance",
        channels: &["distance"],
        sample: SampleType::F32,
        miss: "0",
        meaning: "Euclidean distance from the camera origin to the hit, world units",
        mitsuba: MitsubaSource::Derived,
        metric: CompareMetric::Relative,
    },
    AovSpec {
        aov: Aov::Depth,
        name: "depth",
        channels: &["depth"],
        sample: SampleType::F32,
        miss: "0",
        meaning: "planar depth: camera-space z of the hit (distance * cos theta), world units",
        mitsuba: MitsubaSource::Rendered("dd.y:depth"),
        metric: CompareMetric::Relative,
    },
    AovSpec {
        aov: Aov::Normal,
        name: "normal",
        channels: &["normal.X", "normal.Y", "normal.Z"],
        sample: SampleType::F32,
        miss: "[0,0,0]",
        meaning: "world-space unit outward normal, not flipped toward the camera",
        mitsuba: MitsubaSource::Rendered("nn:sh_normal"),
        metric: CompareMetric::AngleDeg,
    },
    AovSpec {
        aov: Aov::Position,
        name: "position",
        channels: &["position.X", "position.Y", "position.Z"],
        sample: SampleType::F32,
        miss: "[0,0,0]",
        meaning: "world-space hit point",
        mitsuba: MitsubaSource::Rendered("pp:position"),
        metric: CompareMetric::PointDistance,
    },
    AovSpec {
        aov: Aov::ShapeId,
        name: "shape_id",
        channels: &["shape_id"],
        sample: SampleType::U32,
        miss: "0",
        meaning: "u32 id of the hit cylinder (scene 'id', default 1-based index)",
        mitsuba: MitsubaSource::Rendered("ii:shape_index"),
        metric: CompareMetric::Identity,
    },
    AovSpec {
        aov: Aov::Part,
        name: "part",
        channels: &["part"],
        sample: SampleType::U32,
        miss: "0",
        meaning: "u32 part of the hit cylinder: 1 side seen from outside, 2 side seen from inside, 3 bottom cap (at p0), 4 top cap (at p1)",
        mitsuba: MitsubaSource::Derived,
        metric: CompareMetric::Identity,
    },
    AovSpec {
        aov: Aov::NormalCamera,
        name: "normal_camera",
        channels: &["normal_camera.X", "normal_camera.Y", "normal_camera.Z"],
        sample: SampleType::F32,
        miss: "[0,0,0]",
        meaning: "camera-space unit outward normal, OpenCV axes (x right, y down, z forward), not flipped toward the camera",
        mitsuba: MitsubaSource::Derived,
        metric: CompareMetric::None,
    },
    AovSpec {
        aov: Aov::Label,
        name: "label",
        channels: &["label"],
        sample: SampleType::U32,
        miss: "0",
        meaning: "u32 label of the hit cylinder (scene 'label', the class; 0 when none)",
        mitsuba: MitsubaSource::Derived,
        metric: CompareMetric::Identity,
    },
    AovSpec {
        aov: Aov::Uv,
        name: "uv",
        channels: &["uv.U", "uv.V"],
        sample: SampleType::F32,
        miss: "[0,0]",
        meaning: "surface coordinates as Mitsuba's cylinder: u = angle around the axis / 2pi in [0, 1) (Mitsuba's frame from p0 to p1), v = axial fraction from p0 on the side, distance from the axis / radius on a cap",
        mitsuba: MitsubaSource::OnRequest("uv:uv"),
        metric: CompareMetric::Periodic,
    },
];

/// Every row stores one to three channels, each named `NAME` (one) or `NAME.SUFFIX`
/// (several): what the per-AOV layout, numpy's `(H, W)` / `(H, W, C)` arrays and the
/// channel lookups rely on. Checked when the crate compiles.
const _: () = {
    let mut i = 0;
    while i < AOV_TABLE.len() {
        let n = AOV_TABLE[i].channels.len();
        assert!(n >= 1 && n <= 3, "an AOV has one to three channels");
        i += 1;
    }
};

impl Aov {
    /// This AOV's row of [`AOV_TABLE`].
    pub fn spec(self) -> &'static AovSpec {
        &AOV_TABLE[self as usize]
    }

    /// The AOV whose layered-EXR channels include `channel`, if any.
    pub fn of_channel(channel: &str) -> Option<Aov> {
        AOV_TABLE
            .iter()
            .find(|s| s.channels.contains(&channel))
            .map(|s| s.aov)
    }
}

/// The Mitsuba `aov` integrator's `aovs` list a reference renders (`prefix:aov`, comma
/// separated, in table order).
pub fn mitsuba_aov_list() -> String {
    AOV_TABLE
        .iter()
        .filter_map(|s| match s.mitsuba {
            MitsubaSource::Rendered(e) => Some(e),
            _ => None,
        })
        .collect::<Vec<_>>()
        .join(",")
}

/// The README's AOV table (what `cylaov aovs` prints): Markdown, one row per AOV.
pub fn markdown_table() -> String {
    let mut s = String::from(
        "| AOV | EXR channels | per-AOV file (f32) | type | meaning | on a miss | Mitsuba reference | compared by |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for a in AOV_TABLE {
        // `normal.X/Y/Z`: the shared prefix once, then each channel's suffix.
        let channels = match a.channels {
            [one] => format!("`{one}`"),
            many => {
                let suffixes: Vec<&str> = many
                    .iter()
                    .map(|c| c.rsplit_once('.').map_or(*c, |(_, s)| s))
                    .collect();
                format!("`{}.{}`", a.name, suffixes.join("/"))
            }
        };
        s.push_str(&format!(
            "| `{}` | {channels} | `{}` | {} | {} | {} | {} | {} |\n",
            a.name,
            a.per_aov_channels().join(", "),
            a.sample.name(),
            a.meaning,
            a.miss,
            match a.mitsuba {
                MitsubaSource::Derived => "derived".to_string(),
                MitsubaSource::Rendered(e) =>
                    format!("`{}`", e.split(':').next_back().unwrap_or(e)),
                MitsubaSource::OnRequest(e) =>
                    format!("`{}` (when checked)", e.split(':').next_back().unwrap_or(e)),
            },
            a.metric.describe(),
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table is indexed by the enum: each row sits at its AOV's position, under the
    /// name the command line parses, with channels that name no other AOV.
    #[test]
    fn rows_follow_the_enum() {
        for (k, a) in Aov::ALL.into_iter().enumerate() {
            let s = &AOV_TABLE[k];
            assert_eq!(s.aov, a);
            assert_eq!(a as usize, k);
            assert_eq!(Aov::parse(s.name), Some(a));
            for c in s.channels {
                assert_eq!(Aov::of_channel(c), Some(a), "{c}");
            }
            // One channel is the AOV's name; several are NAME.SUFFIX, one per-AOV name each.
            match s.channels {
                [one] => assert_eq!(*one, s.name),
                many => {
                    assert_eq!(s.per_aov_channels().len(), many.len(), "{}", s.name);
                    for c in many {
                        assert!(c.starts_with(&format!("{}.", s.name)), "{c}");
                    }
                }
            }
        }
        assert_eq!(Aov::of_channel("Y"), None);
    }

    /// The header text of the table is the text files have always carried.
    #[test]
    fn header_text_is_the_files_text() {
        assert_eq!(
            Aov::Normal
                .spec()
                .header_text_under(&Projection::Perspective),
            "normal.X, normal.Y, normal.Z: world-space unit outward normal, not flipped \
             toward the camera; miss = [0,0,0]"
        );
        assert_eq!(
            Aov::Depth
                .spec()
                .header_text_under(&Projection::Perspective),
            "depth: planar depth: camera-space z of the hit (distance * cos theta), world \
             units; miss = 0"
        );
        // An equirectangular camera's depth is the distance: its header says so.
        let equirect = Projection::Lens(crate::scene::camera::lens::Lens::Equirectangular {
            width: 8,
            height: 4,
        });
        assert_eq!(
            Aov::Depth.spec().header_text_under(&equirect),
            "depth: euclidean depth: the hit's Euclidean distance from the camera centre (as \
             distance), world units; miss = 0"
        );
        assert_eq!(
            Aov::Normal.spec().header_text_under(&equirect),
            Aov::Normal
                .spec()
                .header_text_under(&Projection::Perspective)
        );
    }

    #[test]
    fn the_markdown_table_has_a_row_per_aov() {
        let t = markdown_table();
        assert_eq!(t.lines().count(), 2 + Aov::ALL.len());
        assert!(t.contains(
            "| `normal` | `normal.X/Y/Z` | `R, G, B` | f32 | world-space unit outward normal, \
             not flipped toward the camera | [0,0,0] | `sh_normal` | angle (degrees) |\n"
        ));
        assert!(t.contains("| `uv` | `uv.U/V` | `R, G` | f32 |"));
        assert!(t.contains("| `uv` (when checked) | u modulo 1 and v, absolute, side pixels |\n"));
    }
}

//! Mitsuba 3 scene XML for a [`Scene`]: the reference renderer's view of the same scene.
//!
//! | element | what it says | why |
//! |---|---|---|
//! | `<scene version="3.0.0">` | Mitsuba 3 scene syntax | loads with `mitsuba.load_file` |
//! | `integrator type="aov"` | `dd.y:depth,nn:sh_normal,pp:position,ii:shape_index` | AOVs only: with only AOVs requested the film holds just those channels |
//! | `sensor type="perspective"` (`orthographic` for an orthographic camera), one per camera in file order | `lookat` `to_world` (after a `scale` by half `ortho_width`), `fov`, `fov_axis`, `near_clip`, `far_clip` | the scene's look-at camera(s); `scene.sensors()[k]` is camera `k`; the lens models have no Mitsuba sensor and are refused |
//! | `sampler type="stratified"` | `sample_count` 1, `jitter` false | one ray through each pixel centre |
//! | `film type="hdrfilm"` | width, height, float32, box `rfilter` | no float16 rounding, no filter blur |
//! | `shape type="cylinder"` | `p0` = base, `p1` = top, `radius` | Mitsuba's cylinder is an open tube |
//! | `shape type="disk"` (caps only) | explicit `to_world` matrix | bottom: normal `-axis` at base; top: `+axis` at top |
//!
//! **Shape order and identity** (what `compare` needs to tell cylinders apart). Per cylinder, in file order: its side, then (if
//! `caps`) its bottom and its top disk. Mitsuba's `shape_index` AOV is 1 + the index in
//! that list, and [`shape_ids`] gives our `shape_id` for each index. Each shape also
//! carries it in its XML `id`: `c<INDEX>_id<SHAPE_ID>_<side|bottom|top>` (`INDEX` is the
//! 0-based position in the scene file, which keeps ids unique even when `shape_id`s repeat),
//! so a reader can recover the mapping from a loaded scene's `shape.id()` alone; the
//! reference script does exactly that.
//!
//! Numbers are written as the shortest decimal that round-trips the f64. Mitsuba's scalar
//! variants parse them into float32, so scene values that are not float32-representable
//! differ by up to half an f32 ulp (relative 3e-8) between the two renderers: far below the
//! comparison floor (Mitsuba's own float32 output: ~8e-6 relative distance, 0.031° measured
//! against an independent float64 tracer on a 200-cylinder scene).

use crate::geometry::Cylinder;
use crate::geometry::cylinder::orthonormal_basis;
use crate::scene::Scene;
use crate::scene::camera::{CameraSpec, Projection};
use glam::{DMat4, DVec3};
use quick_xml::Writer;
use quick_xml::events::{BytesDecl, BytesText, Event};
use std::io;

/// The AOV list of the exported integrator: Mitsuba channel prefixes `dd`, `nn`, `pp`, `ii`.
pub const AOV_LIST: &str = "dd.y:depth,nn:sh_normal,pp:position,ii:shape_index";

/// Which surface of a cylinder a Mitsuba shape is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// The open tube between base and top (Mitsuba `cylinder`).
    Side,
    /// The cap disk at the base, normal `-axis`.
    Bottom,
    /// The cap disk at `base + height·axis`, normal `+axis`.
    Top,
}

impl Part {
    /// The part's word in the shape's XML `id`: `side`, `bottom` or `top`.
    pub fn name(self) -> &'static str {
        match self {
            Part::Side => "side",
            Part::Bottom => "bottom",
            Part::Top => "top",
        }
    }
}

/// One Mitsuba shape of the export: which cylinder (0-based file index) and which part.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExportedShape {
    /// Index of the cylinder in the scene file (0-based), not its `shape_id`.
    pub cylinder: usize,
    /// Which surface of that cylinder.
    pub part: Part,
}

/// The Mitsuba shapes of `scene` in export order: side, then bottom and top cap if `caps`.
pub fn shapes(scene: &Scene) -> Vec<ExportedShape> {
    let mut out = Vec::new();
    for (cylinder, c) in scene.cylinders.iter().enumerate() {
        out.push(ExportedShape {
            cylinder,
            part: Part::Side,
        });
        if c.caps {
            for part in [Part::Bottom, Part::Top] {
                out.push(ExportedShape { cylinder, part });
            }
        }
    }
    out
}

/// Our `shape_id` for each Mitsuba shape index: `shape_ids(scene)[k]` is the id of the
/// cylinder that Mitsuba's `shape_index` `k + 1` belongs to (its `shape_index` 0 is a miss).
pub fn shape_ids(scene: &Scene) -> Vec<u32> {
    shapes(scene)
        .iter()
        .map(|s| scene.cylinders[s.cylinder].id)
        .collect()
}

/// The XML `id` attribute of an exported shape.
pub fn shape_xml_id(scene: &Scene, s: ExportedShape) -> String {
    format!(
        "c{}_id{}_{}",
        s.cylinder,
        scene.cylinders[s.cylinder].id,
        s.part.name()
    )
}

/// `to_world` of a cap disk. Mitsuba's `disk` is the unit disk in local xy with normal +z;
/// this scales it uniformly by `r`, turns local (x, y, z) onto `(u, v, n_out)` with
/// `u × v = n_out`, and moves it to the cap centre. Bottom: centre `base`, `n_out = -axis`;
/// top: centre `base + height·axis`, `n_out = +axis` (the outward cap normals). The matrix is a similarity,
/// so its normal transform (inverse transpose) maps +z to exactly `n_out` after normalising.
pub fn cap_to_world(c: &Cylinder, part: Part) -> DMat4 {
    let (centre, n_out) = match part {
        Part::Bottom => (c.base, -c.axis),
        Part::Top => (c.top(), c.axis),
        Part::Side => (c.base, c.axis),
    };
    let (u, v) = orthonormal_basis(n_out);
    let r = c.radius;
    DMat4::from_cols(
        (u * r).extend(0.0),
        (v * r).extend(0.0),
        (n_out * r).extend(0.0),
        centre.extend(1.0),
    )
}

/// Shortest round-trip decimal; `-0` is written as `0` (same value, easier to read).
fn num(x: f64) -> String {
    (x + 0.0).to_string()
}

fn vec3(v: DVec3) -> String {
    format!("{}, {}, {}", num(v.x), num(v.y), num(v.z))
}

/// Row-major, as Mitsuba's `<matrix value=...>` reads it.
fn matrix(m: DMat4) -> String {
    let rows = m.transpose().to_cols_array();
    rows.iter().map(|&x| num(x)).collect::<Vec<_>>().join(" ")
}

/// `s` made safe inside an XML comment. XML 1.0 (`Comment ::= '<!--' ((Char - '-') |
/// ('-' (Char - '-')))* '-->'`) forbids `--` anywhere in the text and a `-` at its end, and
/// only allows `Char`s: a space goes between consecutive dashes (`---` → `- - -`), after a
/// trailing dash, and control characters other than tab/newline/CR, U+FFFE and U+FFFF become U+FFFD. One
/// pass, so no `--` can survive (unlike a single `replace("--", "- -")`, which leaves
/// `- --` from `---`).
fn comment_safe(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    for c in s.chars() {
        if c == '-' && out.ends_with('-') {
            out.push(' ');
        }
        // U+FFFE and U+FFFF are no XML `Char` either.
        let valid = matches!(c, '\t' | '\n' | '\r')
            || !(c.is_control() || matches!(c, '\u{fffe}' | '\u{ffff}'));
        out.push(if valid { c } else { '\u{fffd}' });
    }
    if out.ends_with('-') {
        out.push(' ');
    }
    out
}

/// A camera Mitsuba 3 has no sensor for: the lens models (OpenCV, fisheye,
/// equirectangular). Exporting such a scene is refused rather than written with a
/// different camera.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NoSensor {
    /// `camera` or `cameras[K]`.
    pub field: String,
    /// The scene-file model name.
    pub model: &'static str,
}

impl std::fmt::Display for NoSensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}.model: Mitsuba 3 has no \"{}\" sensor (only the pinhole `perspective` and \
             `orthographic`), so this camera cannot be exported or verified against Mitsuba",
            self.field, self.model
        )
    }
}

impl std::error::Error for NoSensor {}

/// Whether every camera of `scene` has a Mitsuba 3 sensor.
pub fn check_sensors(scene: &Scene) -> Result<(), NoSensor> {
    let several = scene.cameras.len() > 1;
    for (k, c) in scene.cameras.iter().enumerate() {
        if let Projection::Lens(_) = c.projection {
            return Err(NoSensor {
                field: if several {
                    format!("cameras[{k}]")
                } else {
                    "camera".into()
                },
                model: c.projection.model().name(),
            });
        }
    }
    Ok(())
}

/// The Mitsuba 3 scene XML of `scene`; `source_name` (e.g. the scene file's path) is named
/// in a comment at the top. Pure: same scene, same bytes. Refused for a camera Mitsuba
/// has no sensor for ([`check_sensors`]).
pub fn to_xml(scene: &Scene, source_name: &str) -> Result<String, NoSensor> {
    check_sensors(scene)?;
    let mut buf = Vec::new();
    // Writing into a Vec cannot fail; an io::Error here would be a quick-xml bug.
    write_xml(&mut buf, scene, source_name).expect("writing XML into memory");
    let mut s = String::from_utf8(buf).expect("quick-xml writes UTF-8");
    s.push('\n');
    Ok(s)
}

fn write_xml(buf: &mut Vec<u8>, scene: &Scene, source_name: &str) -> io::Result<()> {
    let mut w = Writer::new_with_indent(buf, b' ', 4);
    let exported = shapes(scene);
    w.write_event(Event::Decl(BytesDecl::new("1.0", Some("utf-8"), None)))?;
    let header = format!(
        " Mitsuba 3 scene exported by cylaov {} from {}: {} cylinder(s) as {} shape(s).\n     \
         Shape order: per cylinder, its side (cylinder), then its caps (disk bottom, disk top).\n     \
         Shape ids: c<file index>_id<shape_id>_<side|bottom|top>. Render with the scalar_rgb variant. ",
        env!("CARGO_PKG_VERSION"),
        comment_safe(source_name),
        scene.cylinders.len(),
        exported.len()
    );
    w.write_event(Event::Comment(BytesText::from_escaped(header)))?;
    w.create_element("scene")
        .with_attribute(("version", "3.0.0"))
        .write_inner_content(|w| {
            w.create_element("integrator")
                .with_attribute(("type", "aov"))
                .write_inner_content(|w| {
                    string(w, "aovs", AOV_LIST)?;
                    Ok(())
                })?;
            for cam in &scene.cameras {
                sensor(w, cam)?;
            }
            for s in &exported {
                let c = &scene.cylinders[s.cylinder];
                let id = shape_xml_id(scene, *s);
                match s.part {
                    Part::Side => {
                        w.create_element("shape")
                            .with_attribute(("type", "cylinder"))
                            .with_attribute(("id", id.as_str()))
                            .write_inner_content(|w| {
                                point(w, "p0", c.base)?;
                                point(w, "p1", c.top())?;
                                float(w, "radius", c.radius)?;
                                Ok(())
                            })?;
                    }
                    Part::Bottom | Part::Top => {
                        w.create_element("shape")
                            .with_attribute(("type", "disk"))
                            .with_attribute(("id", id.as_str()))
                            .write_inner_content(|w| {
                                w.create_element("transform")
                                    .with_attribute(("name", "to_world"))
                                    .write_inner_content(|w| {
                                        let m = matrix(cap_to_world(c, s.part));
                                        w.create_element("matrix")
                                            .with_attribute(("value", m.as_str()))
                                            .write_empty()?;
                                        Ok(())
                                    })?;
                                Ok(())
                            })?;
                    }
                }
            }
            Ok(())
        })?;
    Ok(())
}

/// One `perspective` sensor: the look-at camera with its own film and sampler. A scene
/// with several cameras gets one sensor per camera, in file order, so Mitsuba's
/// `scene.sensors()[k]` is camera `k`.
///
/// An orthographic camera is Mitsuba's `orthographic` sensor, which images x in [-1, 1]
/// and y in [-1/aspect, 1/aspect] of its own frame: `to_world` scales both by half the
/// image width before the look-at, so the film spans `ortho_width` world units.
fn sensor(w: &mut Writer<&mut Vec<u8>>, cam: &CameraSpec) -> io::Result<()> {
    let ortho = match cam.projection {
        Projection::Orthographic { half_width, .. } => Some(half_width),
        _ => None,
    };
    w.create_element("sensor")
        .with_attribute((
            "type",
            if ortho.is_some() {
                "orthographic"
            } else {
                "perspective"
            },
        ))
        .write_inner_content(|w| {
            if ortho.is_none() {
                string(w, "fov_axis", cam.fov_axis.name())?;
                float(w, "fov", cam.fov_deg)?;
            }
            float(w, "near_clip", cam.near_clip)?;
            float(w, "far_clip", cam.far_clip)?;
            w.create_element("transform")
                .with_attribute(("name", "to_world"))
                .write_inner_content(|w| {
                    if let Some(hw) = ortho {
                        let s = num(hw);
                        w.create_element("scale")
                            .with_attribute(("x", s.as_str()))
                            .with_attribute(("y", s.as_str()))
                            .write_empty()?;
                    }
                    w.create_element("lookat")
                        .with_attribute(("origin", vec3(cam.origin).as_str()))
                        .with_attribute(("target", vec3(cam.target).as_str()))
                        .with_attribute(("up", vec3(cam.up).as_str()))
                        .write_empty()?;
                    Ok(())
                })?;
            w.create_element("sampler")
                .with_attribute(("type", "stratified"))
                .write_inner_content(|w| {
                    integer(w, "sample_count", 1)?;
                    boolean(w, "jitter", false)?;
                    Ok(())
                })?;
            w.create_element("film")
                .with_attribute(("type", "hdrfilm"))
                .write_inner_content(|w| {
                    integer(w, "width", u64::from(cam.width))?;
                    integer(w, "height", u64::from(cam.height))?;
                    string(w, "pixel_format", "rgb")?;
                    string(w, "component_format", "float32")?;
                    w.create_element("rfilter")
                        .with_attribute(("type", "box"))
                        .write_empty()?;
                    Ok(())
                })?;
            Ok(())
        })?;
    Ok(())
}

/// `<TAG name="NAME" value="VALUE"/>`: every typed property below is one of these.
fn property(w: &mut Writer<&mut Vec<u8>>, tag: &str, name: &str, value: &str) -> io::Result<()> {
    w.create_element(tag)
        .with_attribute(("name", name))
        .with_attribute(("value", value))
        .write_empty()?;
    Ok(())
}

fn string(w: &mut Writer<&mut Vec<u8>>, name: &str, value: &str) -> io::Result<()> {
    property(w, "string", name, value)
}

fn float(w: &mut Writer<&mut Vec<u8>>, name: &str, value: f64) -> io::Result<()> {
    property(w, "float", name, &num(value))
}

fn integer(w: &mut Writer<&mut Vec<u8>>, name: &str, value: u64) -> io::Result<()> {
    property(w, "integer", name, &value.to_string())
}

fn boolean(w: &mut Writer<&mut Vec<u8>>, name: &str, value: bool) -> io::Result<()> {
    property(w, "boolean", name, if value { "true" } else { "false" })
}

fn point(w: &mut Writer<&mut Vec<u8>>, name: &str, p: DVec3) -> io::Result<()> {
    property(w, "point", name, &vec3(p))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene;

    /// The export renders exactly the AOVs the AOV table says every reference takes.
    #[test]
    fn the_aov_list_is_the_tables() {
        assert_eq!(crate::scene::aov::mitsuba_aov_list(), AOV_LIST);
    }

    const SCENE: &str = r#"{
      "camera": { "origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
                  "fov_deg": 40, "fov_axis": "y", "width": 64, "height": 48, "near_clip": 0.5 },
      "cylinders": [
        { "p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5 },
        { "center": [1, 2, 3], "axis": [0, 3, 4], "height": 2, "radius": 0.25, "caps": false, "id": 7 },
        { "p0": [-1, 0.5, 0], "p1": [2, -1, 1], "radius": 0.125, "id": 7 }
      ]
    }"#;

    fn scene() -> Scene {
        scene::parse(SCENE).expect("test scene is valid")
    }

    #[test]
    fn shapes_are_side_then_caps_per_cylinder() {
        let s = scene();
        let parts: Vec<_> = shapes(&s).iter().map(|e| (e.cylinder, e.part)).collect();
        assert_eq!(
            parts,
            vec![
                (0, Part::Side),
                (0, Part::Bottom),
                (0, Part::Top),
                (1, Part::Side),
                (2, Part::Side),
                (2, Part::Bottom),
                (2, Part::Top),
            ]
        );
        assert_eq!(shape_ids(&s), vec![1, 1, 1, 7, 7, 7, 7]);
    }

    #[test]
    fn xml_structure() {
        let xml = to_xml(&scene(), "tests/example.json").unwrap();
        assert!(xml.starts_with("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<!-- "));
        assert!(xml.contains("from tests/example.json"));
        assert!(xml.contains("<scene version=\"3.0.0\">"));
        assert!(xml.contains(&format!("<string name=\"aovs\" value=\"{AOV_LIST}\"/>")));
        assert!(xml.contains("<string name=\"fov_axis\" value=\"y\"/>"));
        assert!(xml.contains("<float name=\"fov\" value=\"40\"/>"));
        assert!(xml.contains("<float name=\"near_clip\" value=\"0.5\"/>"));
        assert!(xml.contains("<float name=\"far_clip\" value=\"10000\"/>"));
        assert!(
            xml.contains("<lookat origin=\"3, -5, 2.5\" target=\"0, 0, 0.6\" up=\"0, 0, 1\"/>")
        );
        assert!(xml.contains("<integer name=\"sample_count\" value=\"1\"/>"));
        assert!(xml.contains("<boolean name=\"jitter\" value=\"false\"/>"));
        assert!(xml.contains("<string name=\"component_format\" value=\"float32\"/>"));
        assert!(xml.contains("<rfilter type=\"box\"/>"));
        assert!(xml.contains("<integer name=\"width\" value=\"64\"/>"));
        assert!(xml.contains("<integer name=\"height\" value=\"48\"/>"));
        assert_eq!(xml.matches("<shape type=\"cylinder\"").count(), 3);
        assert_eq!(xml.matches("<shape type=\"disk\"").count(), 4);
        // Seed form: centre (1,2,3), unit axis (0,0.6,0.8), height 2 → top (1,3.2,4.6).
        assert!(xml.contains("<shape type=\"cylinder\" id=\"c1_id7_side\">"));
        assert!(xml.contains("<point name=\"p0\" value=\"1, 2, 3\"/>"));
        assert!(xml.contains("<point name=\"p1\" value=\"1, 3.2, 4.6\"/>"));
        // Indented, and the ids come in export order.
        assert!(xml.contains("\n    <integrator type=\"aov\">\n        <string"));
        let order: Vec<usize> = ["c0_id1_side", "c0_id1_bottom", "c0_id1_top", "c1_id7_side"]
            .iter()
            .map(|id| xml.find(id).expect("id present"))
            .collect();
        assert!(order.windows(2).all(|w| w[0] < w[1]));
        assert!(xml.ends_with("</scene>\n"));
    }

    #[test]
    fn comment_cannot_be_closed_by_source_name() {
        let xml = to_xml(&scene(), "a-->b").unwrap();
        assert!(xml.contains("a- ->b"));
    }

    /// The text between `<!--` and `-->` of the first comment in `xml`.
    fn comment_body(xml: &str) -> &str {
        let start = xml.find("<!--").expect("comment") + 4;
        let len = xml[start..].find("-->").expect("comment end");
        &xml[start..start + len]
    }

    #[test]
    fn comment_is_valid_xml_for_any_run_of_dashes() {
        for name in [
            "a---b.json",
            "a----b-",
            "-",
            "--",
            "---",
            "x-",
            "scenes/a---b-.json",
            "tab\there\u{1}",
        ] {
            let safe = comment_safe(name);
            assert!(!safe.contains("--"), "{name:?} -> {safe:?}");
            assert!(!safe.ends_with('-'), "{name:?} -> {safe:?}");
            assert!(!safe.contains('\u{1}'), "{name:?} -> {safe:?}");
            // Only spaces were added (and control characters replaced): dashes all kept.
            assert_eq!(
                safe.matches('-').count(),
                name.matches('-').count(),
                "{name:?}"
            );
            let xml = to_xml(&scene(), name).unwrap();
            let body = comment_body(&xml);
            assert!(!body.contains("--") && !body.ends_with('-'), "{body:?}");
            // The comment closes where we meant it to: the XML has exactly one.
            assert_eq!(xml.matches("-->").count(), 1, "{name:?}");
        }
        assert_eq!(comment_safe("a---b"), "a- - -b");
        assert_eq!(comment_safe("a-"), "a- ");
        assert_eq!(comment_safe("a-b"), "a-b");
        // Not XML `Char`s: a strict parser refuses them even in a comment.
        assert_eq!(
            comment_safe("n\u{fffe}\u{ffff}.json"),
            "n\u{fffd}\u{fffd}.json"
        );
    }

    #[test]
    fn cap_transforms_put_normals_and_rims_where_spec_says() {
        let s = scene();
        for c in &s.cylinders {
            for (part, centre, n_out) in [
                (Part::Bottom, c.base, -c.axis),
                (Part::Top, c.top(), c.axis),
            ] {
                let m = cap_to_world(c, part);
                // Local origin → cap centre.
                assert!(m.transform_point3(DVec3::ZERO).distance(centre) < 1e-12);
                // Local +z normal → outward normal (normal transform = inverse transpose).
                let nt = m
                    .inverse()
                    .transpose()
                    .transform_vector3(DVec3::Z)
                    .normalize();
                assert!(nt.distance(n_out) < 1e-12, "{part:?}: {nt} vs {n_out}");
                // The unit circle → a circle of radius r in the cap plane.
                for k in 0..8 {
                    let a = k as f64 * std::f64::consts::TAU / 8.0;
                    let p = m.transform_point3(DVec3::new(a.cos(), a.sin(), 0.0));
                    assert!(((p - centre).length() - c.radius).abs() < 1e-12);
                    assert!((p - centre).dot(c.axis).abs() < 1e-12);
                }
                // Right-handed (no mirror): determinant r³ > 0.
                assert!((m.determinant() - c.radius.powi(3)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn matrix_is_row_major() {
        let c = &scene().cylinders[0];
        let m = matrix(cap_to_world(c, Part::Top));
        let v: Vec<f64> = m.split(' ').map(|x| x.parse().expect("number")).collect();
        assert_eq!(v.len(), 16);
        // Translation in the last column: entries 3, 7, 11 = top centre (0, 0, 1.5).
        assert_eq!([v[3], v[7], v[11], v[15]], [0.0, 0.0, 1.5, 1.0]);
        assert_eq!([v[12], v[13], v[14]], [0.0, 0.0, 0.0]);
    }
}

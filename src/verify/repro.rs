//! A proven reference error as a script a Mitsuba maintainer can run: the one or two
//! cylinders involved, exported as `export-mitsuba` exports them, and the one float32 ray.
//!
//! A reference error is *proven* when Mitsuba's shape at a pixel (another cylinder, another
//! part, or hit vs miss) is not the exact answer's on the inputs Mitsuba was given: the
//! cylinders' `p0`, `p1` and `radius` rounded to float32, and the pixel ray rounded to
//! float32 (its origin moved to the near plane, where Mitsuba's camera rays start). The
//! render's own ray may differ from that ray in its last bits, so a proven error stands
//! only once the script ([`script`]), casting exactly that ray with `scene.ray_intersect`,
//! prints another shape than the exact one.

use crate::geometry::Cylinder;
use crate::output::format::mitsuba::{Part, cap_to_world};
use serde::Serialize;
use std::fmt::Write as _;

/// One answer along the reproduction's ray: which cylinder, which exported shape, where.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReproHit {
    /// The cylinder's `shape_id`.
    pub id: u32,
    /// The exported shape's part word: `side`, `bottom` or `top`.
    pub shape: &'static str,
    /// The ray parameter of the hit (from the ray's float32 origin, in units of its
    /// float32 direction).
    pub t: f64,
}

impl ReproHit {
    /// `id 3 side t 12.5`, as the report and the script print it.
    pub fn describe(hit: &Option<ReproHit>) -> String {
        match hit {
            None => "miss".into(),
            Some(h) => format!("id {} {} t {:?}", h.id, h.shape, h.t),
        }
    }
}

/// One cylinder of the reproduction, as Mitsuba parses the export: float32 end points and
/// radius, and its cap disks' float32 `to_world` matrices (row-major) when it has caps.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReproCylinder {
    /// Its 0-based position in the scene file (the `c<INDEX>` of the exported shape ids).
    pub index: usize,
    /// Its `shape_id`.
    pub id: u32,
    /// Base centre, float32.
    pub p0: [f32; 3],
    /// Top centre, float32.
    pub p1: [f32; 3],
    /// Radius, float32.
    pub radius: f32,
    /// Bottom and top cap `to_world`, row-major float32 (`None`: an open tube).
    pub caps: Option<[[f32; 16]; 2]>,
}

impl ReproCylinder {
    /// Cylinder `index` of the scene as the export writes it and Mitsuba parses it.
    pub fn new(index: usize, c: &Cylinder) -> ReproCylinder {
        let v = |p: glam::DVec3| p.as_vec3().to_array();
        let matrix = |part| {
            let rows = cap_to_world(c, part).transpose().to_cols_array();
            rows.map(|x| x as f32)
        };
        ReproCylinder {
            index,
            id: c.id,
            p0: v(c.base),
            p1: v(c.top()),
            radius: c.radius as f32,
            caps: c.caps.then(|| [matrix(Part::Bottom), matrix(Part::Top)]),
        }
    }
}

/// A proven reference error: the shapes, the ray, Mitsuba's answer in the render and the
/// exact answer on the same float32 inputs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Repro {
    /// Ray origin, float32 (on the near plane).
    pub origin: [f32; 3],
    /// Ray direction, float32 (not renormalised: `t` is in its units).
    pub dir: [f32; 3],
    /// Largest `t` counted (the far clip along the ray), float32.
    pub tmax: f32,
    /// The cylinders Mitsuba's and the exact answer's shapes belong to.
    pub cylinders: Vec<ReproCylinder>,
    /// Mitsuba's answer in the render (`t`: its distance less the near-plane offset).
    pub reference: Option<ReproHit>,
    /// The exact answer (double-double, rounded to f64) along this float32 ray on these
    /// float32 cylinders.
    pub exact: Option<ReproHit>,
}

/// The part word of an exported shape for a `part` value (1 and 2 are both the tube).
pub fn shape_word(part: u32) -> &'static str {
    match part {
        3 => "bottom",
        4 => "top",
        _ => "side",
    }
}

/// An f32 as the exact decimal of its value (Python parses it back to the same float32).
fn f(x: f32) -> String {
    format!("{:?}", f64::from(x))
}

fn v3(v: [f32; 3]) -> String {
    format!("{}, {}, {}", f(v[0]), f(v[1]), f(v[2]))
}

/// The shapes' XML: each cylinder's side, then its caps, with the export's shape ids.
fn shapes_xml(r: &Repro) -> String {
    let mut s = String::new();
    for c in &r.cylinders {
        let _ = write!(
            s,
            "    <shape type=\"cylinder\" id=\"c{}_id{}_side\">\n        <point name=\"p0\" value=\"{}\"/>\n        <point name=\"p1\" value=\"{}\"/>\n        <float name=\"radius\" value=\"{}\"/>\n    </shape>\n",
            c.index,
            c.id,
            v3(c.p0),
            v3(c.p1),
            f(c.radius)
        );
        for (word, m) in ["bottom", "top"].iter().zip(c.caps.iter().flatten()) {
            let m: Vec<String> = m.iter().map(|&x| f(x)).collect();
            let _ = write!(
                s,
                "    <shape type=\"disk\" id=\"c{}_id{}_{word}\">\n        <transform name=\"to_world\">\n            <matrix value=\"{}\"/>\n        </transform>\n    </shape>\n",
                c.index,
                c.id,
                m.join(" ")
            );
        }
    }
    s
}

fn py_hit(h: &Option<ReproHit>) -> String {
    match h {
        None => "None".into(),
        Some(h) => format!("({}, {:?}, {:?})", h.id, h.shape, h.t),
    }
}

/// A standalone Python script (imports `mitsuba` and `numpy` only) that loads the
/// reproduction's shapes, casts its ray with `scene.ray_intersect` in `scalar_rgb` and prints
/// Mitsuba's answer beside the exact one, then `REPRODUCED` (another shape than the exact
/// answer's) or `NOT REPRODUCED`, its exit status 0 either way.
pub fn script(r: &Repro, what: &str) -> String {
    // Inside the docstring: no line break, backslash or quote of the view's name ends it.
    let what = what
        .replace(['\n', '\r'], " ")
        .replace('\\', "\\\\")
        .replace('"', "\\\"");
    format!(
        r#"#!/usr/bin/env python3
"""{what}

A reproduction written by `cylaov verify --report`: the cylinders involved, as cylaov's
Mitsuba export writes them (float32 p0, p1, radius; caps as disks), and one float32 ray
cast with scene.ray_intersect. Prints Mitsuba's answer beside the exact answer (computed by
cylaov in double-double on the same float32 inputs, rounded to float64). The finding stands
only if the two shapes differ: run it with mitsuba==3.9.1 before filing it upstream.
Needs only mitsuba and numpy.
"""
import re
import sys

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")

SHAPES = """
{shapes}"""
ORIGIN = np.array([{origin}], dtype=np.float32)
DIRECTION = np.array([{dir}], dtype=np.float32)
TMAX = np.float32({tmax})
# (shape_id, shape, t) or None for a miss.
EXACT = {exact}
RENDER = {render}


def describe(hit):
    if hit is None:
        return "miss"
    return f"id {{hit[0]}} {{hit[1]}} t {{hit[2]!r}}"


scene = mi.load_string('<scene version="3.0.0">' + SHAPES + "</scene>")
ray = mi.Ray3f(mi.Point3f(*map(float, ORIGIN)), mi.Vector3f(*map(float, DIRECTION)))
ray.maxt = float(TMAX)
si = scene.ray_intersect(ray)
if si.is_valid():
    m = re.match(r"^c(\d+)_id(\d+)_(side|bottom|top)$", si.shape.id())
    if m is None:
        sys.exit(f"unexpected shape id {{si.shape.id()!r}}")
    mitsuba = (int(m.group(2)), m.group(3), float(si.t))
else:
    mitsuba = None
print(f"mitsuba {{mi.__version__}}: {{describe(mitsuba)}}")
print(f"exact: {{describe(EXACT)}}")
print(f"mitsuba in the render: {{describe(RENDER)}}")
same = (mitsuba is None) == (EXACT is None) and (
    mitsuba is None or mitsuba[:2] == EXACT[:2]
)
print("NOT REPRODUCED: Mitsuba gives the exact answer's shape on this ray" if same
      else "REPRODUCED: Mitsuba's shape differs from the exact answer's")
"#,
        shapes = shapes_xml(r),
        origin = v3(r.origin),
        dir = v3(r.dir),
        tmax = f(r.tmax),
        exact = py_hit(&r.exact),
        render = py_hit(&r.reference),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repro() -> Repro {
        let c = Cylinder {
            base: glam::DVec3::new(0.1, 0.0, 0.0),
            axis: glam::DVec3::Z,
            height: 2.0,
            radius: 0.5,
            caps: true,
            id: 7,
            label: 0,
        };
        Repro {
            origin: [0.1, -5.0, 1.0],
            dir: [0.0, 1.0, 0.0],
            tmax: 1e4,
            cylinders: vec![ReproCylinder::new(3, &c)],
            reference: None,
            exact: Some(ReproHit {
                id: 7,
                shape: "side",
                t: 4.5,
            }),
        }
    }

    /// The shapes carry the export's ids and exact float32 decimals; the answers are
    /// embedded as Python literals.
    #[test]
    fn script_holds_the_shapes_the_ray_and_both_answers() {
        let s = script(&repro(), "a view");
        for want in [
            "<shape type=\"cylinder\" id=\"c3_id7_side\">",
            "<shape type=\"disk\" id=\"c3_id7_bottom\">",
            "<shape type=\"disk\" id=\"c3_id7_top\">",
            // 0.1 as float32, exactly.
            "<point name=\"p0\" value=\"0.10000000149011612, 0.0, 0.0\"/>",
            "ORIGIN = np.array([0.10000000149011612, -5.0, 1.0], dtype=np.float32)",
            "EXACT = (7, \"side\", 4.5)",
            "RENDER = None",
            "mi.set_variant(\"scalar_rgb\")",
        ] {
            assert!(s.contains(want), "{want} missing from:\n{s}");
        }
        assert_eq!(ReproHit::describe(&repro().exact), "id 7 side t 4.5");
    }

    /// A view name with quotes, backslashes or a line break stays inside the docstring.
    #[test]
    fn a_view_name_cannot_end_the_docstring() {
        let s = script(&repro(), "a\"\"\"b\\\nimport os");
        let doc = s.lines().nth(1).expect("the docstring's first line");
        assert_eq!(doc, "\"\"\"a\\\"\\\"\\\"b\\\\ import os");
    }
}

//! The `label` AOV: the hit cylinder's class, beside `shape_id`'s instance.

use cylaov::render::{RenderOptions, render};
use cylaov::scene::{self, Aov};

/// Three cylinders, two sharing a label and one with none: every hit pixel's label is its
/// cylinder's, a miss and an unlabelled cylinder read 0, and each cylinder is seen.
#[test]
fn the_label_aov_is_the_hit_cylinders_label() {
    let scene = scene::parse(
        r#"{
  "camera": {"origin": [0, -10, 0], "target": [0, 0, 0], "up": [0, 0, 1],
             "fov_deg": 50, "width": 64, "height": 40},
  "cylinders": [
    {"p0": [-2.5, 0, 1.2], "p1": [-2.5, 0, 2.4], "radius": 0.8, "id": 7, "label": 3},
    {"p0": [2.2, 0, 1], "p1": [3.2, 0, 2.5], "radius": 0.3, "id": 8, "label": 3},
    {"p0": [-3, 0, -1.5], "p1": [-1.5, 0, -1.5], "radius": 0.4, "id": 9}
  ]
}"#,
    )
    .unwrap();
    let r = render(&scene, &RenderOptions::new(vec![Aov::ShapeId, Aov::Label]));
    let ids = r.image.u32_channel("shape_id").unwrap();
    let labels = r.image.u32_channel("label").unwrap();
    let mut seen = [0usize; 4];
    for (&id, &label) in ids.iter().zip(labels.iter()) {
        let want = match id {
            0 => 0,
            7 | 8 => 3,
            9 => 0,
            other => panic!("unexpected id {other}"),
        };
        assert_eq!(label, want, "id {id}");
        seen[match id {
            0 => 0,
            7 => 1,
            8 => 2,
            _ => 3,
        }] += 1;
    }
    assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
    assert_eq!(r.hits, seen[1] + seen[2] + seen[3]);
}

/// The table's row: one u32 channel named `label`, compared by identity.
#[test]
fn the_label_row() {
    let s = Aov::Label.spec();
    assert_eq!(s.channels, &["label"]);
    assert_eq!(s.per_aov_channels(), &["Y"]);
    assert_eq!(Aov::parse("label"), Some(Aov::Label));
    assert_eq!(s.metric, cylaov::scene::aov::CompareMetric::Identity);
}

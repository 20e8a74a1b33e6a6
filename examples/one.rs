//! Render one generated scene once (for profilers): `one N W H PREC FORMULA AOVS`.
use cylaov::bench::random_scene;
use cylaov::render::*;
use cylaov::scene::Aov;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(1000);
    let w: u32 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(480);
    let h: u32 = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(270);
    let p = if a.get(4).map(String::as_str) == Some("f32") {
        Precision::F32
    } else {
        Precision::F64
    };
    let f = if a.get(5).map(String::as_str) == Some("literal") {
        FormulaKind::Literal
    } else {
        FormulaKind::Stable
    };
    let aovs = if a.get(6).map(String::as_str) == Some("depth") {
        vec![Aov::Depth]
    } else {
        vec![Aov::Depth, Aov::Normal]
    };
    let sc = random_scene(n, 1, w, h);
    let r = render(
        &sc,
        &RenderOptions {
            aovs,
            precision: p,
            formula: f,
            accel: Accel::Tiles,
        },
    );
    println!("{}", r.hits);
}

use cylaov::bench::random_scene;
use cylaov::render::*;
use cylaov::scene::Aov;
use std::time::Instant;
fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000);
    let sc = random_scene(n, 1, 1920, 1080);
    for (p, f) in [
        (Precision::F64, FormulaKind::Stable),
        (Precision::F32, FormulaKind::Stable),
        (Precision::F64, FormulaKind::Literal),
        (Precision::F32, FormulaKind::Literal),
    ] {
        for aovs in [
            vec![Aov::Depth],
            vec![Aov::Depth, Aov::Normal],
            Aov::ALL.to_vec(),
        ] {
            let o = RenderOptions {
                aovs: aovs.clone(),
                precision: p,
                formula: f,
                accel: if std::env::var("BVH").is_ok() {
                    Accel::Bvh
                } else {
                    Accel::Tiles
                },
            };
            let _ = render(&sc, &o);
            let t = Instant::now();
            let r = render(&sc, &o);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            r.image
                .write_exr(
                    std::path::Path::new("/tmp/q.exr"),
                    cylaov::aov::Compression::None,
                )
                .unwrap();
            println!(
                "{p:?} {f:?} {:?}: render {ms:.1} ms hits {} write {:.1} ms",
                aovs.len(),
                r.hits,
                t.elapsed().as_secs_f64() * 1e3
            );
        }
    }
}

use cylaov::bench::random_scene;
use cylaov::camera::Camera;
use cylaov::tiles::Tiles;
fn main() {
    for n in [1usize, 100, 1000, 10000, 100000] {
        let sc = random_scene(n, 1, 1920, 1080);
        let cam = Camera::new(sc.camera);
        let t = std::time::Instant::now();
        let tiles = Tiles::build(&cam, &sc.cylinders);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let mut covers = 0u64;
        let mut listed = 0u64;
        for ty in 0..tiles.tiles_y {
            for tx in 0..tiles.tiles_x {
                let c = tiles.tile(tx, ty);
                listed += c.len() as u64;
                for j in ty * 16..(ty * 16 + 16).min(1080) {
                    for i in tx * 16..(tx * 16 + 16).min(1920) {
                        covers += c.iter().filter(|k| k.covers(i, j)).count() as u64;
                    }
                }
            }
        }
        println!(
            "n={n}: build {ms:.1} ms, entries {}, avg list/tile {:.1}, avg covering/pixel {:.2}",
            tiles.entries(),
            listed as f64 / (tiles.tiles_x * tiles.tiles_y) as f64,
            covers as f64 / (1920.0 * 1080.0)
        );
    }
}

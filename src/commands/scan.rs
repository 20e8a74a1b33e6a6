//! `cylaov scan`: a scene, a sensor (a preset or a JSON table) and its pose or trajectory
//! → one rotation's points as LAS, PLY or `.npz` (see [`crate::scan`]).

use crate::output::store::atomic::{NewDirs, stage_bytes};

use crate::output::pipeline::scan_files::ScanFormat;
use crate::output::store::targets::check_outputs;
use crate::scan::{Motion, Noise, Pose, ScanOptions, Sensor, Trajectory};
use crate::scene;
use anyhow::{Context, Result, anyhow};
use std::path::{Path, PathBuf};

/// Everything `scan` needs from the command line.
#[derive(Clone, Debug)]
pub struct ScanArgs {
    /// The scene file.
    pub scene: PathBuf,
    /// A preset name or a sensor JSON file.
    pub sensor: String,
    /// The point file (`-o`): `.las`, `.ply` or `.npz`.
    pub out: PathBuf,
    /// The fixed pose (ignored with a trajectory).
    pub pose: Pose,
    /// A trajectory CSV, when the sensor moves.
    pub trajectory: Option<PathBuf>,
    /// Most returns per beam.
    pub returns: u32,
    /// Range noise and dropout.
    pub noise: Noise,
}

/// The sensor named `what`: a preset, else a JSON file of that path.
pub fn load_sensor(what: &str) -> Result<Sensor> {
    if let Some(s) = Sensor::preset(what) {
        return Ok(s);
    }
    let path = Path::new(what);
    if !path.exists() {
        let names: Vec<&str> = crate::scan::sensor::PRESETS.iter().map(|p| p.0).collect();
        return Err(anyhow!(
            "--sensor {what:?}: neither a preset ({}) nor an existing JSON file",
            names.join(", ")
        ));
    }
    let text = read_small(path).with_context(|| format!("--sensor {}", path.display()))?;
    Sensor::from_json(&text).map_err(|e| anyhow!("{}: {e}", path.display()))
}

/// A small text file (a sensor, a trajectory): at most 64 MiB.
fn read_small(path: &Path) -> Result<String> {
    use std::io::Read;
    const MAX: u64 = 64 << 20;
    let f = std::fs::File::open(path)?;
    let mut text = String::new();
    f.take(MAX + 1).read_to_string(&mut text)?;
    if text.len() as u64 > MAX {
        return Err(anyhow!("more than {MAX} bytes"));
    }
    Ok(text)
}

/// Scan and write the point file; returns the one-line summary. Nothing is written
/// unless the scan succeeds.
pub fn run(args: &ScanArgs) -> Result<String> {
    let format = ScanFormat::of(&args.out).map_err(|e| anyhow!("-o {e}"))?;
    let mut inputs = vec![args.scene.as_path()];
    let sensor_path = Path::new(&args.sensor);
    if Sensor::preset(&args.sensor).is_none() {
        inputs.push(sensor_path);
    }
    if let Some(t) = &args.trajectory {
        inputs.push(t.as_path());
    }
    let (scene, table) =
        scene::load_with_table(&args.scene).with_context(|| format!("{}", args.scene.display()))?;
    inputs.extend(table.as_deref());
    check_outputs(&[("-o", &args.out)], &inputs)?;
    let sensor = load_sensor(&args.sensor)?;
    let motion = match &args.trajectory {
        Some(path) => {
            let text =
                read_small(path).with_context(|| format!("--trajectory {}", path.display()))?;
            Motion::Path(
                Trajectory::from_csv(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?,
            )
        }
        None => Motion::Fixed(args.pose),
    };
    let opts = ScanOptions {
        sensor,
        motion,
        returns: args.returns,
        noise: args.noise,
    };
    // Every number it checks is a flag's.
    opts.validate().map_err(super::Usage)?;
    crate::mem::check_memory(
        &format!("a scan of up to {} points", opts.most_points()),
        opts.memory(),
    )?;
    let points = crate::scan::scan(&scene, &opts).map_err(|e| anyhow!(e))?;
    let comment = format!(
        "cylaov {} scan of {} by {}",
        env!("CARGO_PKG_VERSION"),
        args.scene.display(),
        opts.sensor.name
    );
    let bytes = format
        .encode(&points, &comment)
        .map_err(|e| anyhow!("{}: {e}", args.out.display()))?;
    let mut dirs = NewDirs::default();
    dirs.create_parent(&args.out)
        .with_context(|| format!("-o {}", args.out.display()))?;
    stage_bytes(&args.out, &bytes)
        .and_then(|s| s.commit())
        .with_context(|| format!("writing {}", args.out.display()))?;
    dirs.keep();
    let beams = opts.sensor.beams() * opts.sensor.steps_per_rotation as usize;
    Ok(format!(
        "{}: {} from {} beams of {} ({} x {} steps), up to {} a beam",
        args.out.display(),
        crate::output::console::count(points.len(), "point"),
        beams,
        opts.sensor.name,
        opts.sensor.beams(),
        opts.sensor.steps_per_rotation,
        crate::output::console::count(opts.returns as usize, "return"),
    ))
}

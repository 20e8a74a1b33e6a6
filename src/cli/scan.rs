//! `cylaov scan`: one rotation of a simulated LiDAR.

use crate::cli::common::{say, set_threads, threads};
use clap::Args;
use cylaov::commands;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct ScanCli {
    /// Scene file (JSON, see docs/scene-format.md); its cameras are not used.
    scene: PathBuf,
    /// A preset (vlp16, hdl32, os1-64) or a sensor JSON file (docs/scan.md).
    #[arg(long, value_name = "NAME|SENSOR.json")]
    sensor: String,
    /// The point file: .las, .ply or .npz.
    #[arg(short, long, value_name = "OUT.{las,ply,npz}")]
    out: PathBuf,
    /// The sensor's position and (optional) yaw, pitch, roll in degrees.
    #[arg(
        long,
        value_name = "X,Y,Z[,YAW,PITCH,ROLL]",
        default_value = "0,0,0",
        allow_hyphen_values = true
    )]
    pose: String,
    /// Poses over time (CSV: time,x,y,z,yaw,pitch,roll), interpolated at each beam's time
    /// (position linearly, rotation by slerp); replaces --pose.
    #[arg(long, value_name = "FILE", conflicts_with = "pose")]
    trajectory: Option<PathBuf>,
    /// Most returns per beam, 1 to 15.
    #[arg(long, default_value_t = 1, value_name = "N")]
    returns: u32,
    /// Standard deviation of Gaussian noise on the range, world units (along the beam).
    #[arg(long, default_value_t = 0.0, value_name = "SIGMA")]
    range_noise: f64,
    /// Probability that a return is dropped, 0 to 1.
    #[arg(long, default_value_t = 0.0, value_name = "P")]
    dropout: f64,
    /// Seed of the noise and dropout (same seed, same points, any thread count).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, value_parser = threads)]
    threads: Option<usize>,
}

pub fn run(a: ScanCli) -> anyhow::Result<ExitCode> {
    set_threads(a.threads)?;
    let pose = cylaov::scan::Pose::parse(&a.pose, "--pose").map_err(cylaov::commands::Usage)?;
    let args = commands::scan::ScanArgs {
        scene: a.scene,
        sensor: a.sensor,
        out: a.out,
        pose,
        trajectory: a.trajectory,
        returns: a.returns,
        noise: cylaov::scan::Noise {
            range_sigma: a.range_noise,
            dropout: a.dropout,
            seed: a.seed,
        },
    };
    say(&commands::scan::run(&args)?)?;
    Ok(ExitCode::SUCCESS)
}

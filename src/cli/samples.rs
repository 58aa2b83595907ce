//! `jetpilot samples`: synthetic road frames for trying the daemon without a camera.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use jetpilot::camera::synthetic::{render_road, sample_view};

#[derive(Debug, clap::Args)]
pub struct SamplesArgs {
    /// Folder to write `road_NNN.jpg` into (created if missing).
    #[arg(short, long, value_name = "DIR")]
    out: PathBuf,
    /// Number of frames (one left-right sweep).
    #[arg(long, default_value_t = 32)]
    count: usize,
    /// Frame width; the height is 3/4 of it.
    #[arg(long, default_value_t = 224)]
    width: u32,
}

pub fn main(args: SamplesArgs) -> anyhow::Result<ExitCode> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let (w, h) = (args.width.max(16), (args.width.max(16) * 3 / 4));
    for i in 0..args.count {
        let rgb = render_road(w, h, sample_view(i, args.count));
        let path = args.out.join(format!("road_{i:03}.jpg"));
        image::save_buffer(&path, &rgb, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    println!(
        "wrote {} frames ({w}x{h}) to {}",
        args.count,
        args.out.display()
    );
    Ok(ExitCode::SUCCESS)
}

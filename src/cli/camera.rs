//! `jetpilot camera list` and `jetpilot camera snap`: find the camera, and check what it
//! sees before driving.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use jetpilot::camera::convert::write_image;
use jetpilot::clock::{Clock, MonotonicClock};
use jetpilot::config::{CameraSource, Config};
use jetpilot::drive::setup::open_source;

/// Frames a live camera (v4l2, pipe) delivers before the one `snap` keeps, while its auto
/// exposure and white balance settle.
const LIVE_WARMUP_FRAMES: usize = 10;

#[derive(Debug, clap::Subcommand)]
pub enum CameraCommand {
    /// List the V4L2 cameras (/dev/video*): driver, card, bus, pixel formats, frame sizes
    /// and frame rates, with the `camera.format` value for each format jetpilot reads.
    List,
    /// Take one frame from the configured camera (any `camera.source`) and write it as
    /// PNG or JPEG (by the output's extension).
    Snap {
        /// Config file whose `[camera]` section names the source.
        #[arg(short, long, value_name = "FILE")]
        config: PathBuf,
        /// Image to write: .png, .jpg or .jpeg.
        #[arg(short, long, value_name = "FILE")]
        output: PathBuf,
    },
}

pub fn main(cmd: CameraCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        CameraCommand::List => list(),
        CameraCommand::Snap { config, output } => snap(&config, &output),
    }
}

#[cfg(feature = "v4l2")]
fn list() -> anyhow::Result<ExitCode> {
    let devices = jetpilot::camera::v4l2::list_devices();
    if devices.is_empty() {
        println!("no V4L2 devices found (/dev/video*)");
        println!(
            "a CSI camera (IMX219) on a Jetson is read with camera.source = \"pipe\" and \
             nvarguscamerasrc; see the docs of jetpilot::camera::pipe"
        );
        return Ok(ExitCode::SUCCESS);
    }
    for (i, device) in devices.iter().enumerate() {
        if i > 0 {
            println!();
        }
        print!("{device}");
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(not(feature = "v4l2"))]
fn list() -> anyhow::Result<ExitCode> {
    println!(
        "this jetpilot was built without the `v4l2` feature, so it cannot list V4L2 cameras; \
         rebuild with default features (cargo build --release)"
    );
    Ok(ExitCode::FAILURE)
}

fn snap(config: &Path, output: &Path) -> anyhow::Result<ExitCode> {
    let ext = output
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
        anyhow::bail!(
            "cannot write {}: name it .png, .jpg or .jpeg",
            output.display()
        );
    }
    let cfg = Config::load(config)?;
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock::new());
    let mut source = open_source(&cfg, clock).context("cannot open the camera")?;
    let description = source.describe();
    let skip = match cfg.camera.source {
        CameraSource::V4l2 | CameraSource::Pipe => LIVE_WARMUP_FRAMES,
        CameraSource::Folder => 0,
    };
    let mut kept = None;
    for _ in 0..=skip {
        match source
            .next_frame()
            .with_context(|| format!("capturing from {description}"))?
        {
            Some(frame) => kept = Some(frame),
            None => break,
        }
    }
    let frame = kept.with_context(|| format!("{description} ended before delivering a frame"))?;
    write_image(output, frame.width, frame.height, &frame.rgb)?;
    println!(
        "wrote frame {} ({}x{}) from {description} to {}",
        frame.seq,
        frame.width,
        frame.height,
        output.display()
    );
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(subcommand)]
        cmd: CameraCommand,
    }

    #[test]
    fn parses() {
        let cli = Cli::try_parse_from(["t", "snap", "-c", "a.toml", "-o", "b.png"]).unwrap();
        assert!(
            matches!(cli.cmd, CameraCommand::Snap { ref config, ref output }
            if config == Path::new("a.toml") && output == Path::new("b.png"))
        );
        assert!(matches!(
            Cli::try_parse_from(["t", "list"]).unwrap().cmd,
            CameraCommand::List
        ));
    }

    #[test]
    fn snap_from_a_pipe_source() {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("cam.toml");
        // 16x16 grey frames of value 7, forever.
        std::fs::write(
            &config,
            "[camera]\nsource = \"pipe\"\nformat = \"grey\"\nwidth = 16\nheight = 16\n\
             command = \"while :; do head -c 256 /dev/zero | tr '\\\\000' '\\\\007'; done\"\n",
        )
        .unwrap();
        let out = dir.path().join("snap.png");
        let code = snap(&config, &out).unwrap();
        assert_eq!(code, ExitCode::SUCCESS);
        let img = image::open(&out).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (16, 16));
        assert!(img.pixels().all(|p| p.0 == [7, 7, 7]));
        let err = snap(&config, &dir.path().join("x.bmp")).unwrap_err();
        assert!(err.to_string().contains(".png"), "{err}");
    }
}

//! `jetpilot image install`: put jetpilot into a JetBot SD card image file before flashing.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use jetpilot::image::plan::KITS;
use jetpilot::image::{InstallOptions, install};

#[derive(Debug, Subcommand)]
pub enum ImageCommand {
    /// Install jetpilot into an SD card image file (JetBot's, or any Jetson image with an
    /// ext4 root partition named APP): the aarch64 binary, ONNX Runtime, the configs with
    /// the kit's as /etc/jetpilot/jetpilot.toml, the systemd units (enabled), the udev
    /// rule, the model, and optional Wi-Fi. Needs e2fsprogs (debugfs); no root, no mount.
    /// Every input is checked before the first write; a failure leaves the image as it was.
    Install(InstallArgs),
}

#[derive(Debug, Args)]
pub struct InstallArgs {
    /// The SD card image file. A .zip, .xz, .gz or .zst download is first unpacked beside
    /// itself (the archive is left as it is) and the install goes into the unpacked .img.
    #[arg(long, value_name = "FILE.img")]
    image: PathBuf,
    /// The kit: jetbot, waveshare, yahboom, l298n-nano (the configs shipped in config/).
    #[arg(long, default_value = "jetbot", conflicts_with = "config")]
    kit: String,
    /// Your own config instead of a shipped kit's (installed as /etc/jetpilot/jetpilot.toml).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// The ONNX model, installed where the config's model.path says (/var/lib/jetpilot/model.onnx).
    #[arg(long, value_name = "FILE")]
    model: PathBuf,
    /// The aarch64 jetpilot binary (scripts/build-aarch64.sh builds it).
    #[arg(
        long,
        value_name = "FILE",
        default_value = "target/aarch64-unknown-linux-gnu/release/jetpilot"
    )]
    binary: PathBuf,
    /// The aarch64 libonnxruntime.so.1.23.2 (from the onnxruntime==1.23.2 manylinux aarch64 wheel).
    #[arg(long, value_name = "FILE")]
    onnxruntime: PathBuf,
    /// GPT partition number of the root filesystem, when it is not named APP.
    #[arg(long, value_name = "N")]
    partition: Option<u32>,
    /// Wi-Fi network to join at boot (NetworkManager keyfile, mode 0600).
    #[arg(long, value_name = "SSID")]
    wifi_ssid: Option<String>,
    /// WPA password for --wifi-ssid (or set JETPILOT_WIFI_PASSWORD, which keeps it out of
    /// the shell history).
    #[arg(long, value_name = "PASSWORD")]
    wifi_password: Option<String>,
    /// Check everything and list what would be written; the image is not touched.
    #[arg(long)]
    dry_run: bool,
}

pub fn main(cmd: ImageCommand) -> anyhow::Result<ExitCode> {
    let ImageCommand::Install(a) = cmd;
    let config = match &a.config {
        Some(p) => (
            p.display().to_string(),
            std::fs::read_to_string(p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
        ),
        None => {
            let (name, text) = KITS.iter().find(|(k, _)| *k == a.kit).ok_or_else(|| {
                let kits: Vec<&str> = KITS.iter().map(|(k, _)| *k).collect();
                anyhow::anyhow!(
                    "--kit {}: no such kit; the kits are {}",
                    a.kit,
                    kits.join(", ")
                )
            })?;
            (format!("config/{name}.toml"), text.to_string())
        }
    };
    // A compressed download is unpacked beside itself first (the archive stays as it is);
    // an image unpacked by an earlier run is used again.
    let head = jetpilot::image::inputs::head(&a.image, 16)?;
    let image = match jetpilot::image::inputs::compression(&head) {
        Some((kind, _)) => {
            let target = jetpilot::image::unpack::target(&a.image, kind)?;
            if target.exists() {
                eprintln!(
                    "using {}, unpacked from {} before",
                    target.display(),
                    a.image.display()
                );
                target
            } else if a.dry_run {
                anyhow::bail!(
                    "{} is {kind}-compressed: a dry run does not unpack it (that writes the whole \
                     image, as {}); run without --dry-run, or unpack it first",
                    a.image.display(),
                    target.display()
                );
            } else {
                eprintln!(
                    "unpacking {} ({kind}) to {} ...",
                    a.image.display(),
                    target.display()
                );
                jetpilot::image::unpack::unpack(&a.image, kind)?
            }
        }
        None => a.image.clone(),
    };
    let opts = InstallOptions {
        image: image.clone(),
        partition: a.partition,
        binary: a.binary,
        onnxruntime: a.onnxruntime,
        model: a.model,
        config,
        wifi: match (
            a.wifi_ssid,
            a.wifi_password
                .or_else(|| std::env::var("JETPILOT_WIFI_PASSWORD").ok()),
        ) {
            (Some(ssid), Some(psk)) => Some((ssid, psk)),
            (Some(_), None) => anyhow::bail!(
                "--wifi-ssid needs a password: --wifi-password or JETPILOT_WIFI_PASSWORD"
            ),
            (None, _) => None,
        },
        dry_run: a.dry_run,
        fail_after_write: false,
    };
    let report = install(&opts)?;
    println!(
        "{}: partition {} at byte {}; {:.1} MiB to write, {:.1} MiB free",
        image.display(),
        report.partition,
        report.offset,
        report.needed_bytes as f64 / 1048576.0,
        report.free_bytes as f64 / 1048576.0
    );
    for line in &report.actions {
        println!("  {line}");
    }
    if a.dry_run {
        println!("dry run: nothing was written");
    } else {
        println!(
            "done: flash {} and boot; the daemon starts on its own",
            image.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

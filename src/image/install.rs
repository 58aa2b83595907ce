//! The install itself: check every input, make the plan, compare it with what the image
//! holds, check free space, then write through debugfs with an undo file, read everything
//! back, run `e2fsck -fn`, and undo on any failure.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::debugfs::{Entry, Fs, lookup};
use super::plan::{Plan, PlanInputs, Source};
use super::{ImageError, ext4, gpt, inputs};
use crate::config::{CameraSource, Config, MotorBackend};

/// What to install where.
#[derive(Debug, Clone)]
pub struct InstallOptions {
    pub image: PathBuf,
    /// GPT partition number; `None`: the partition named `APP`.
    pub partition: Option<u32>,
    /// The aarch64 jetpilot binary.
    pub binary: PathBuf,
    /// The aarch64 `libonnxruntime.so.1.23.2`.
    pub onnxruntime: PathBuf,
    pub model: PathBuf,
    /// The kit config (its file name, for errors, and its text).
    pub config: (String, String),
    /// Wi-Fi SSID and WPA password.
    pub wifi: Option<(String, String)>,
    pub dry_run: bool,
    /// For tests of the rollback: fail after the write, as a failed read-back would.
    #[doc(hidden)]
    pub fail_after_write: bool,
}

/// What was (or, with `--dry-run`, would be) done.
#[derive(Debug, Clone, Default)]
pub struct InstallReport {
    pub partition: String,
    pub offset: u64,
    /// One line per action: `mkdir /etc/jetpilot`, `write /usr/bin/jetpilot (0755, ...)`.
    pub actions: Vec<String>,
    pub needed_bytes: u64,
    pub free_bytes: u64,
}

fn input_err(path: &Path, reason: impl Into<String>) -> ImageError {
    ImageError::Input {
        path: path.display().to_string(),
        reason: reason.into(),
    }
}

fn file_size(path: &Path) -> Result<u64, ImageError> {
    let m = std::fs::metadata(path).map_err(|e| input_err(path, e.to_string()))?;
    if !m.is_file() {
        return Err(input_err(path, "not a regular file"));
    }
    Ok(m.len())
}

/// The root partition and its filesystem, after checking the image.
fn open_image(opts: &InstallOptions) -> Result<(gpt::Partition, ext4::Superblock), ImageError> {
    let path = opts.image.display().to_string();
    if path.contains('?') {
        // e2fsprogs reads `FILE?offset=N`: a `?` in the name would open another file.
        return Err(input_err(
            &opts.image,
            "the image's path has a `?`, which e2fsprogs takes for options: rename it",
        ));
    }
    let len = file_size(&opts.image)?;
    let head = inputs::head(&opts.image, 16)?;
    if let Some((kind, hint)) = inputs::compression(&head) {
        return Err(ImageError::Compressed {
            path,
            kind: kind.into(),
            hint: hint.replace("FILE", &opts.image.display().to_string()),
        });
    }
    let mut f =
        std::fs::File::open(&opts.image).map_err(|e| input_err(&opts.image, e.to_string()))?;
    let parts = gpt::parse(&path, len, |at, buf| {
        f.seek(SeekFrom::Start(at))?;
        f.read_exact(buf)
    })?;
    let part = gpt::find(&path, &parts, "APP", opts.partition)?.clone();
    let mut sb = [0u8; 1024];
    f.seek(SeekFrom::Start(part.offset() + 1024))
        .and_then(|_| f.read_exact(&mut sb))
        .map_err(|e| input_err(&opts.image, e.to_string()))?;
    let name = format!("{} ({})", part.number, part.name);
    let sb = ext4::parse(&sb, &path, &name, part.offset())?;
    Ok((part, sb))
}

/// The plan's inputs from the options, every one checked.
fn check_inputs(opts: &InstallOptions) -> Result<PlanInputs<'_>, ImageError> {
    inputs::require_aarch64(
        &opts.binary,
        "jetpilot binary",
        ": build it with scripts/build-aarch64.sh (target/aarch64-unknown-linux-gnu/release/jetpilot)",
    )?;
    inputs::require_aarch64(
        &opts.onnxruntime,
        "ONNX Runtime library",
        ": take libonnxruntime.so.1.23.2 from the onnxruntime==1.23.2 manylinux aarch64 wheel (docs/guides/install.md, \"Install on a JetBot\")",
    )?;
    let (cfg_name, cfg_text) = &opts.config;
    let cfg = Config::parse(cfg_text, cfg_name)
        .map_err(|e| input_err(Path::new(cfg_name), e.to_string()))?;
    let model_dest = cfg.model.path.display().to_string();
    if !cfg.model.path.is_absolute() {
        return Err(input_err(
            Path::new(cfg_name),
            format!(
                "model.path = {model_dest:?} must be absolute in a config installed into /etc/jetpilot"
            ),
        ));
    }
    // The destination goes into a debugfs command line: plain path characters only, and
    // nowhere but a state or data folder.
    let plain = model_dest
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || "/._-+".contains(c));
    let parts: Vec<&str> = model_dest.split('/').collect();
    if !plain
        || parts.iter().any(|p| *p == ".." || *p == ".")
        || !(model_dest.starts_with("/var/lib/") || model_dest.starts_with("/opt/"))
    {
        return Err(input_err(
            Path::new(cfg_name),
            format!(
                "model.path = {model_dest:?}: the installer writes the model under /var/lib/ or /opt/, \
                 with letters, digits and . _ - + only"
            ),
        ));
    }
    if cfg.motors.backend == MotorBackend::Log {
        return Err(input_err(
            Path::new(cfg_name),
            "motors.backend = \"log\" drives no motors: pick the kit's config",
        ));
    }
    let summary = crate::policy::onnx::inspect::inspect_file(&opts.model)
        .map_err(|e| input_err(&opts.model, e.to_string()))?;
    // One file goes onto the card: not a model whose weights live beside it, nor one
    // pre-optimised for the machine building the image (the robot would refuse it).
    if let Some(machine) = summary
        .metadata
        .get(crate::policy::optimize::META_OPTIMIZED_FOR)
    {
        return Err(input_err(
            &opts.model,
            format!(
                "it was pre-optimised for `{machine}` by `jetpilot model optimize`: install the original model and run `model optimize` on the robot"
            ),
        ));
    }
    if summary.external_initializers > 0 {
        return Err(input_err(
            &opts.model,
            format!(
                "{} of its initializers live in a separate data file, and the installer copies one model file",
                summary.external_initializers
            ),
        ));
    }
    let contract = summary
        .contract()
        .map_err(|e| input_err(&opts.model, e.to_string()))?;
    if contract.is_none() {
        tracing::warn!(
            model = %opts.model.display(),
            "the model carries no contract in its metadata; the config's [model] keys will describe it"
        );
    }
    let wifi = match &opts.wifi {
        Some((ssid, psk)) => Some(
            super::plan::wifi_keyfile(ssid, psk).map_err(|e| input_err(Path::new("--wifi"), e))?,
        ),
        None => None,
    };
    Ok(PlanInputs {
        binary: (opts.binary.clone(), file_size(&opts.binary)?),
        onnxruntime: (opts.onnxruntime.clone(), file_size(&opts.onnxruntime)?),
        model: (opts.model.clone(), file_size(&opts.model)?),
        model_dest,
        kit_config: cfg_text,
        csi_camera: cfg.camera.source == CameraSource::Pipe
            && cfg.camera.command.contains("nvarguscamerasrc"),
        gpio_motors: cfg.motors.backend == MotorBackend::Gpio,
        wifi,
    })
}

fn quote(p: &str) -> String {
    format!("\"{p}\"")
}

/// The debugfs commands that take the filesystem from `existing` to the plan, and the
/// report lines for them.
fn commands(
    plan: &Plan,
    dirs: &[String],
    existing: &std::collections::BTreeMap<String, Option<Vec<Entry>>>,
    sources: &[PathBuf],
) -> (Vec<String>, Vec<String>) {
    let mut cmds = Vec::new();
    let mut report = Vec::new();
    let present = |path: &str| lookup(existing, path);
    for d in dirs {
        if matches!(existing.get(d), Some(None)) {
            cmds.push(format!("mkdir {}", quote(d)));
            cmds.push(format!("sif {} mode 040755", quote(d)));
            report.push(format!("mkdir {d}"));
        }
    }
    for (f, src) in plan.files.iter().zip(sources) {
        let verb = match present(&f.dest) {
            Some(_) => {
                cmds.push(format!("rm {}", quote(&f.dest)));
                "replace"
            }
            None => "write",
        };
        cmds.push(format!(
            "write {} {}",
            quote(&src.display().to_string()),
            quote(&f.dest)
        ));
        cmds.push(format!(
            "sif {} mode 0{:o}",
            quote(&f.dest),
            0o100000 | f.mode
        ));
        cmds.push(format!("sif {} uid 0", quote(&f.dest)));
        cmds.push(format!("sif {} gid 0", quote(&f.dest)));
        report.push(format!(
            "{verb} {} ({:04o}, {} bytes)",
            f.dest, f.mode, f.size
        ));
    }
    for l in &plan.links {
        if present(&l.dest).is_some() {
            cmds.push(format!("rm {}", quote(&l.dest)));
        }
        cmds.push(format!("symlink {} {}", quote(&l.dest), quote(&l.target)));
        report.push(format!("symlink {} -> {}", l.dest, l.target));
    }
    (cmds, report)
}

/// `DIR/.NAME.jetpilot-undo` for the image `DIR/NAME`.
fn undo_path(image: &Path) -> PathBuf {
    let name = image
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "image".into());
    image
        .parent()
        .unwrap_or(Path::new("."))
        .join(format!(".{name}.jetpilot-undo"))
}

/// The partition's first 4 KiB: boot block and primary superblock, which e2undo does not
/// restore (debugfs writes the superblock around its undo manager).
fn read_head(image: &Path, offset: u64) -> std::io::Result<Vec<u8>> {
    let mut f = std::fs::File::open(image)?;
    f.seek(SeekFrom::Start(offset))?;
    let mut b = vec![0u8; 4096];
    f.read_exact(&mut b)?;
    Ok(b)
}

fn write_head(image: &Path, offset: u64, head: &[u8]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new().write(true).open(image)?;
    f.seek(SeekFrom::Start(offset))?;
    f.write_all(head)?;
    f.sync_all()
}

/// Reads every installed file back and compares it with its source; checks modes.
fn verify(fs: &Fs, plan: &Plan, sources: &[PathBuf], tmp: &Path) -> Result<(), String> {
    let listing = fs.list(&plan.dirs()).map_err(|e| e.to_string())?;
    for (i, (f, src)) in plan.files.iter().zip(sources).enumerate() {
        let entry = lookup(&listing, &f.dest)
            .ok_or_else(|| format!("{} is missing after the write", f.dest))?;
        if entry.mode != 0o100000 | f.mode || entry.uid != 0 || entry.gid != 0 {
            return Err(format!(
                "{}: mode {:o} owner {}:{}, wanted {:o} 0:0",
                f.dest,
                entry.mode,
                entry.uid,
                entry.gid,
                0o100000 | f.mode
            ));
        }
        let back = tmp.join(format!("back-{i}"));
        fs.dump(&f.dest, &back).map_err(|e| e.to_string())?;
        let read = |p: &Path| std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()));
        let same = read(&back)? == read(src)?;
        let _ = std::fs::remove_file(&back);
        if !same {
            return Err(format!(
                "{} reads back different from {}",
                f.dest,
                src.display()
            ));
        }
    }
    for l in &plan.links {
        let ok = lookup(&listing, &l.dest)
            .is_some_and(|e| e.mode & 0o170000 == 0o120000 && e.size == l.target.len() as u64);
        if !ok {
            return Err(format!(
                "{} is not a symlink to {} after the write",
                l.dest, l.target
            ));
        }
    }
    fs.fsck().map_err(|e| e.to_string())
}

/// Installs jetpilot into the image. See the module documentation.
pub fn install(opts: &InstallOptions) -> Result<InstallReport, ImageError> {
    let (part, sb) = open_image(opts)?;
    let inputs = check_inputs(opts)?;
    let plan = Plan::new(&inputs);
    let fs = Fs {
        image: opts.image.clone(),
        offset: part.offset(),
    };
    let dirs = plan.dirs();
    let existing = fs.list(&dirs)?;
    let bs = sb.block_size;
    let new_dirs = existing.values().filter(|v| v.is_none()).count() as u64;
    let needed: u64 = plan
        .files
        .iter()
        .map(|f| f.size.div_ceil(bs) * bs + bs)
        .sum::<u64>()
        + (new_dirs + plan.links.len() as u64) * bs;
    // Files installed before are removed first: their blocks come back (a second install
    // fits where the first did).
    let replaced: u64 = plan
        .files
        .iter()
        .filter_map(|f| {
            lookup(&existing, &f.dest)
                .filter(|e| !e.is_dir())
                .map(|e| e.size.div_ceil(bs) * bs)
        })
        .sum();
    let needed = needed.saturating_sub(replaced);
    let part_name = format!("{} ({})", part.number, part.name);
    if needed > sb.free_bytes()
        || plan.files.len() as u64 + new_dirs + 2 > u64::from(sb.free_inodes)
    {
        return Err(ImageError::Full {
            path: opts.image.display().to_string(),
            partition: part_name,
            needed_mib: needed as f64 / 1048576.0,
            free_mib: sb.free_bytes() as f64 / 1048576.0,
        });
    }
    let tmp =
        tempfile::tempdir().map_err(|e| input_err(Path::new("temporary folder"), e.to_string()))?;
    // Text sources become files debugfs can copy.
    // Every source gets a plain name in the scratch folder (a link to the user's file, or
    // the text written out), so no user-chosen path reaches debugfs's command line.
    let scratch = tmp.path().display().to_string();
    if scratch.contains(['"', '\n', '\r']) {
        return Err(input_err(
            tmp.path(),
            "the temporary folder's path has quotes or line breaks: set TMPDIR",
        ));
    }
    let mut sources = Vec::new();
    for (i, f) in plan.files.iter().enumerate() {
        let p = tmp.path().join(format!("src-{i}"));
        match &f.source {
            Source::File(src) => {
                let abs = std::fs::canonicalize(src).map_err(|e| input_err(src, e.to_string()))?;
                std::os::unix::fs::symlink(&abs, &p).map_err(|e| input_err(&p, e.to_string()))?
            }
            Source::Bytes(b) => std::fs::write(&p, b).map_err(|e| input_err(&p, e.to_string()))?,
        }
        sources.push(p);
    }
    let (cmds, actions) = commands(&plan, &dirs, &existing, &sources);
    let mut report = InstallReport {
        partition: part_name,
        offset: part.offset(),
        actions,
        needed_bytes: needed,
        free_bytes: sb.free_bytes(),
    };
    if opts.dry_run {
        return Ok(report);
    }
    // An image that is already damaged is reported as such, not as a failed write.
    fs.fsck().map_err(|e| ImageError::Unclean {
        path: opts.image.display().to_string(),
        partition: report.partition.clone(),
        offset: part.offset(),
        what: format!("e2fsck -fn finds problems before the install: {e}"),
    })?;
    let head =
        read_head(&opts.image, part.offset()).map_err(|e| input_err(&opts.image, e.to_string()))?;
    // Beside the image, so an interrupted install (power cut, kill) can still be undone.
    let undo = undo_path(&opts.image);
    let _ = std::fs::remove_file(&undo);
    tracing::info!(
        undo = %undo.display(),
        "writing; if this is interrupted, undo with `e2undo -o {} {} {}` and restore the \
         partition's first 4 KiB",
        part.offset(),
        undo.display(),
        opts.image.display()
    );
    let written = fs
        .run(&cmds, Some(&undo))
        .map_err(|e| e.to_string())
        .and_then(|_| {
            if opts.fail_after_write {
                return Err("injected failure after the write (test)".to_string());
            }
            verify(&fs, &plan, &sources, tmp.path())
        });
    if let Err(reason) = written {
        let outcome =
            match fs.undo(&undo).map_err(|e| e.to_string()).and_then(|_| {
                write_head(&opts.image, part.offset(), &head).map_err(|e| e.to_string())
            }) {
                Ok(()) => {
                    let _ = std::fs::remove_file(&undo);
                    "the image was put back as it was".to_string()
                }
                Err(e) => format!(
                    "undoing failed too ({e}); the undo file is {}: `e2undo -o {} {} {}`",
                    undo.display(),
                    part.offset(),
                    undo.display(),
                    opts.image.display()
                ),
            };
        return Err(ImageError::Write {
            path: opts.image.display().to_string(),
            reason,
            outcome,
        });
    }
    let _ = std::fs::remove_file(&undo);
    report
        .actions
        .push("verified: every file reads back the same; e2fsck -fn clean".into());
    Ok(report)
}

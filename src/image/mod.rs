//! `jetpilot image install`: jetpilot put into a JetBot SD card image file before it is
//! flashed, so the first boot already drives. No loop mount, no chroot, no root: the GPT
//! is read here ([`gpt`]), the root partition's ext4 is written with e2fsprogs' debugfs at
//! its byte offset ([`debugfs`]).
//!
//! All or nothing: every input is checked (image, partition table, filesystem, binary and
//! library architecture, model contract, config, free space) before the first write; the
//! write records an undo file and any failure after it (a debugfs error, a read-back that
//! differs, an unclean `e2fsck -fn`) puts the filesystem back byte for byte.

pub mod debugfs;
pub mod ext4;
pub mod gpt;
pub mod inputs;
pub mod install;
pub mod plan;
pub mod unpack;

pub use install::{InstallOptions, InstallReport, install};

/// Why an image was refused or could not be written. Each names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}: not a disk image: {reason}")]
    NotDiskImage { path: String, reason: String },
    #[error("{path} is {kind}-compressed: {hint}")]
    Compressed {
        path: String,
        kind: String,
        hint: String,
    },
    #[error("{path}: no GPT partition table: {detail}")]
    NoGpt { path: String, detail: String },
    #[error("{path}: no partition {wanted} (partitions: {found}); pick one with --partition N")]
    NoPartition {
        path: String,
        wanted: String,
        found: String,
    },
    #[error("{path}: partition {partition} is not an ext4 filesystem")]
    NotExt4 { path: String, partition: String },
    #[error(
        "{path}: partition {partition}: {what}; repair it first: `e2fsck -fy '{path}?offset={offset}'`"
    )]
    Unclean {
        path: String,
        partition: String,
        offset: u64,
        what: String,
    },
    #[error(
        "{path}: partition {partition} is full: the install needs {needed_mib:.1} MiB, {free_mib:.1} MiB are free (grow it with resize2fs, or free space)"
    )]
    Full {
        path: String,
        partition: String,
        needed_mib: f64,
        free_mib: f64,
    },
    #[error("{path}: the {what} is {found}, the JetBot needs aarch64{hint}")]
    WrongArch {
        path: String,
        what: String,
        found: String,
        hint: String,
    },
    #[error("{path}: {reason}")]
    Input { path: String, reason: String },
    #[error("{tool}: {reason}")]
    Tool { tool: String, reason: String },
    #[error("{path}: writing failed: {reason}; {outcome}")]
    Write {
        path: String,
        reason: String,
        outcome: String,
    },
}

//! USB cameras through V4L2 (`camera.source = "v4l2"`), with the `v4l` crate's mmap
//! streaming.
//!
//! [`V4l2Source::open`] opens `camera.device`, asks for `width` x `height` at `fps` in
//! `format` and maps 4 buffers. `format = "auto"` takes MJPEG for frames of at least
//! 640x480 pixels (less USB bandwidth), else YUYV, else RGB3, BGR3, GREY (MJPEG last);
//! a format the device does not offer is an error listing the ones it does. The driver
//! may answer with the nearest size it has: that is logged and used. Every frame is
//! converted to RGB8 ([`super::convert`]) into a pooled buffer, stamped with the daemon's
//! clock and numbered with no gaps.
//!
//! A corrupt or cut-short MJPEG frame (USB hiccups, the first frames after power-up) is
//! skipped and counted ([`V4l2Source::skipped_corrupt`]); 30 in a row count as losing
//! the camera.
//!
//! # When the camera goes away
//!
//! The device vanishing (USB unplug: `ENODEV`; `EIO`; no frame for 2 s, or for 5 frame
//! periods at low rates) is an error from `next_frame` the first time, so the daemon
//! stops the motors at once. The following `next_frame` calls reopen it with backoff
//! (0.5 s, doubling to 5 s): each call waits for its try (at most 5 s) and either resumes
//! with the next frame (sequence numbers carry on) or returns the failed try's error, so
//! a capture loop can stop between calls. The backoff is the pure state machine [`Link`]
//! / [`Reconnect`]; the loop runs against a `Backend` trait, tested with a scripted fake.
//!
//! # Troubleshooting
//!
//! - **Permission denied**: device nodes belong to the `video` group. Add yourself:
//!   `sudo usermod -aG video $USER`, then log out and in (or reboot); check with `id`.
//!   Under systemd, give the service `SupplementaryGroups=video`.
//! - **Device or resource busy**: one program at a time can stream from a camera; stop
//!   the other one (another jetpilot, a browser tab, `cheese`, a GStreamer pipeline).
//!   `fuser -v /dev/video0` shows who holds it.
//! - **No such device**: `jetpilot camera list` shows the cameras there are; a USB camera
//!   may come back under another number after replugging; `dmesg | tail` tells why
//!   it dropped (often power: use a powered hub or a shorter cable).
//! - **Not a video capture device**: UVC cameras create two nodes (`/dev/video0` for
//!   frames, `/dev/video1` for metadata); use the one `camera list` shows with formats.
//! - **CSI cameras** (IMX219 / Raspberry Pi camera v2 on a Jetson): their `/dev/video0`
//!   gives raw Bayer (RG10) without the ISP. Use `camera.source = "pipe"` with
//!   GStreamer's `nvarguscamerasrc` (see [`super::pipe`]).
//! - **Many skipped frames or a low frame rate**: USB 2 bandwidth; use MJPEG, a smaller
//!   size, no hub. In dim light UVC cameras lengthen the exposure and drop the rate
//!   (`v4l2-ctl -d /dev/video0 -l` lists the exposure controls).

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use v4l::buffer::{Flags as BufFlags, Type as BufType};
use v4l::capability::Flags as CapFlags;
use v4l::frameinterval::FrameIntervalEnum;
use v4l::framesize::FrameSizeEnum;
use v4l::io::traits::{CaptureStream, Stream as _};
use v4l::prelude::{Device, MmapStream};
use v4l::video::Capture;
use v4l::video::capture::Parameters;
use v4l::{Format, FourCC, Fraction};

use super::convert::{self, RgbPool};
use super::{CameraError, Frame, FrameSource, Result};
use crate::clock::Clock;
use crate::config::{CameraConfig, PixelFormat};

/// Mapped buffers asked of the driver.
const BUFFERS: u32 = 4;
/// Corrupt frames in a row that count as losing the camera.
const MAX_BAD_IN_A_ROW: u32 = 30;
/// Frames `snap` throws away while the camera's auto exposure settles.
const SNAP_WARMUP_FRAMES: usize = 5;
/// RGB buffers kept for reuse (the latest-frame slot, the consumer, one being filled, spare).
const POOL_BUFFERS: usize = 4;

// Linux errno values (no libc here).
const EIO: i32 = 5;
const ENXIO: i32 = 6;
const EBUSY: i32 = 16;
const ENODEV: i32 = 19;

/// Backoff before the next try at reopening a lost camera: the first try 0.5 s after the
/// loss, then 1, 2, 4, 5, 5, ... s after each failed one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reconnect {
    /// Failed tries so far.
    pub attempts: u32,
    pub next_try: Instant,
}

impl Reconnect {
    pub const FIRST_DELAY: Duration = Duration::from_millis(500);
    pub const MAX_DELAY: Duration = Duration::from_secs(5);

    /// The wait before the next try after `attempts` failed ones.
    pub fn delay(attempts: u32) -> Duration {
        Self::FIRST_DELAY
            .saturating_mul(1u32 << attempts.min(16))
            .min(Self::MAX_DELAY)
    }

    pub fn after_loss(now: Instant) -> Self {
        Self {
            attempts: 0,
            next_try: now + Self::delay(0),
        }
    }

    /// How long until the next try (zero when it is due).
    pub fn wait(&self, now: Instant) -> Duration {
        self.next_try.saturating_duration_since(now)
    }

    pub fn failed(&mut self, now: Instant) {
        self.attempts = self.attempts.saturating_add(1);
        self.next_try = now + Self::delay(self.attempts);
    }
}

/// Whether the camera is streaming, or lost and waiting for its next reopen try.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    Up,
    Down(Reconnect),
}

impl Link {
    /// The camera failed: the caller reports this one error, later calls reopen.
    pub fn lost(&mut self, now: Instant) {
        *self = Link::Down(Reconnect::after_loss(now));
    }

    /// A reopen try failed: the next one waits longer. Returns the tries so far.
    pub fn reopen_failed(&mut self, now: Instant) -> u32 {
        match self {
            Link::Down(r) => {
                r.failed(now);
                r.attempts
            }
            Link::Up => {
                let mut r = Reconnect::after_loss(now);
                r.failed(now);
                *self = Link::Down(r);
                r.attempts
            }
        }
    }

    pub fn reopened(&mut self) {
        *self = Link::Up;
    }
}

/// The format in use, as the driver granted it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Negotiated {
    pub format: PixelFormat,
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    /// Bytes per row (`bytesperline`); 0 for MJPEG.
    pub stride: usize,
    /// Frames per second the driver accepted, when it says.
    pub fps: Option<f32>,
}

impl fmt::Display for Negotiated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {}x{}",
            convert::format_name(self.format),
            self.width,
            self.height
        )?;
        if let Some(fps) = self.fps {
            write!(f, " @ {fps:.4} fps")?;
        }
        Ok(())
    }
}

/// The jetpilot format behind a V4L2 four-character code.
pub fn fourcc_format(fourcc: [u8; 4]) -> Option<PixelFormat> {
    match &fourcc {
        b"YUYV" => Some(PixelFormat::Yuyv),
        b"MJPG" | b"JPEG" => Some(PixelFormat::Mjpeg),
        b"RGB3" => Some(PixelFormat::Rgb3),
        b"BGR3" => Some(PixelFormat::Bgr3),
        b"GREY" => Some(PixelFormat::Grey),
        _ => None,
    }
}

/// The format to ask for: `requested` when offered; for `Auto`, MJPEG at 640x480 pixels
/// and more, else YUYV, then RGB3, BGR3, GREY (and MJPEG last for small frames).
pub fn choose_format(
    requested: PixelFormat,
    offered: &[PixelFormat],
    width: u32,
    height: u32,
) -> Option<PixelFormat> {
    use PixelFormat::*;
    match requested {
        Auto => {
            let large = width as u64 * height as u64 >= 640 * 480;
            let order: &[PixelFormat] = if large {
                &[Mjpeg, Yuyv, Rgb3, Bgr3, Grey]
            } else {
                &[Yuyv, Rgb3, Bgr3, Grey, Mjpeg]
            };
            order.iter().copied().find(|f| offered.contains(f))
        }
        f => offered.contains(&f).then_some(f),
    }
}

/// One dequeued buffer: the bytes the driver filled, and whether it flagged them bad.
pub(crate) struct RawFrame<'a> {
    data: &'a [u8],
    flagged: bool,
}

/// The device side of the source, so the capture and reconnect logic is tested without
/// a camera.
pub(crate) trait Backend: Send {
    type Capture: Send;
    /// Opens and configures the device, ready to stream. The error is a full sentence.
    fn open(&mut self) -> std::result::Result<Self::Capture, String>;
    fn negotiated(&self, cap: &Self::Capture) -> Negotiated;
    /// Blocks for the next filled buffer.
    fn next<'a>(&mut self, cap: &'a mut Self::Capture) -> io::Result<RawFrame<'a>>;
    /// After `next` was interrupted (EINTR): bring the buffer queue back in step.
    fn resync(&mut self, cap: &mut Self::Capture) -> io::Result<()>;
    fn now(&self) -> Instant;
    fn sleep(&mut self, d: Duration);
}

/// The capture loop: conversion, numbering, skipping corrupt frames, losing and
/// reopening the device.
pub(crate) struct Core<B: Backend> {
    backend: B,
    device: String,
    cap: Option<B::Capture>,
    neg: Negotiated,
    link: Link,
    clock: Arc<dyn Clock>,
    pool: RgbPool,
    seq: u64,
    skipped_corrupt: u64,
    bad_in_a_row: u32,
    reopens: u64,
}

impl<B: Backend> Core<B> {
    pub(crate) fn open(mut backend: B, device: String, clock: Arc<dyn Clock>) -> Result<Self> {
        let cap = backend.open().map_err(CameraError::Other)?;
        let neg = backend.negotiated(&cap);
        Ok(Self {
            backend,
            device,
            cap: Some(cap),
            neg,
            link: Link::Up,
            clock,
            pool: RgbPool::new(POOL_BUFFERS),
            seq: 0,
            skipped_corrupt: 0,
            bad_in_a_row: 0,
            reopens: 0,
        })
    }

    /// Drops the capture (stopping the stream) and starts the backoff.
    fn lose(&mut self, why: String) -> CameraError {
        self.cap = None;
        self.link.lost(self.backend.now());
        tracing::warn!(device = %self.device, "camera lost: {why}");
        CameraError::Other(format!(
            "camera {}: {why}; trying to reopen it in {:.1} s",
            self.device,
            Reconnect::FIRST_DELAY.as_secs_f32()
        ))
    }

    fn lose_io(&mut self, e: io::Error) -> CameraError {
        let why = match e.raw_os_error() {
            Some(ENODEV) | Some(ENXIO) => format!("the camera disappeared (unplugged?): {e}"),
            Some(EIO) => format!("I/O error (USB cable or power?): {e}"),
            _ if e.kind() == io::ErrorKind::TimedOut => {
                "no frame arrived in time (the camera stalled)".to_string()
            }
            _ => format!("capture failed: {e}"),
        };
        self.lose(why)
    }

    pub(crate) fn next_frame(&mut self) -> Result<Option<Frame>> {
        loop {
            if let Link::Down(r) = self.link {
                let wait = r.wait(self.backend.now());
                if !wait.is_zero() {
                    self.backend.sleep(wait);
                }
                match self.backend.open() {
                    Ok(cap) => {
                        self.neg = self.backend.negotiated(&cap);
                        self.cap = Some(cap);
                        self.link.reopened();
                        self.bad_in_a_row = 0;
                        self.reopens += 1;
                        tracing::info!(device = %self.device, format = %self.neg, "camera reopened");
                    }
                    Err(e) => {
                        let now = self.backend.now();
                        let tries = self.link.reopen_failed(now);
                        let next = match self.link {
                            Link::Down(r) => r.wait(now),
                            Link::Up => Duration::ZERO,
                        };
                        return Err(CameraError::Other(format!(
                            "{e} (reopen try {tries} failed; next try in {:.1} s)",
                            next.as_secs_f32()
                        )));
                    }
                }
            }
            let Some(cap) = self.cap.as_mut() else {
                // Up without a capture cannot happen; recover the same way as a loss.
                self.link.lost(self.backend.now());
                continue;
            };
            let neg = self.neg;
            match self.backend.next(cap) {
                Ok(raw) => {
                    let converted = if raw.flagged {
                        Err("the driver flagged the buffer as corrupt".to_string())
                    } else {
                        self.pool
                            .fill(|dst| {
                                convert::to_rgb(
                                    neg.format, neg.width, neg.height, neg.stride, raw.data, dst,
                                )
                            })
                            .map_err(|e| e.to_string())
                    };
                    match converted {
                        Ok(rgb) => {
                            self.bad_in_a_row = 0;
                            let frame = Frame {
                                seq: self.seq,
                                captured_at: self.clock.now(),
                                width: neg.width,
                                height: neg.height,
                                rgb,
                            };
                            self.seq += 1;
                            return Ok(Some(frame));
                        }
                        Err(why) => {
                            self.skipped_corrupt += 1;
                            self.bad_in_a_row += 1;
                            if self.skipped_corrupt == 1 || self.skipped_corrupt % 100 == 0 {
                                tracing::warn!(
                                    device = %self.device,
                                    skipped = self.skipped_corrupt,
                                    "skipping a corrupt frame: {why}"
                                );
                            } else {
                                tracing::debug!(device = %self.device, "skipping a corrupt frame: {why}");
                            }
                            if self.bad_in_a_row >= MAX_BAD_IN_A_ROW {
                                let n = self.bad_in_a_row;
                                return Err(
                                    self.lose(format!("{n} corrupt frames in a row (last: {why})"))
                                );
                            }
                        }
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {
                    if let Err(e) = self.backend.resync(cap) {
                        return Err(self.lose_io(e));
                    }
                }
                Err(e) => return Err(self.lose_io(e)),
            }
        }
    }
}

/// A V4L2 camera as a [`FrameSource`].
pub struct V4l2Source {
    core: Core<V4l2Backend>,
}

impl V4l2Source {
    /// Opens `cfg.device` and negotiates `cfg.width` x `cfg.height` at `cfg.fps` in
    /// `cfg.format`. Errors name the device and say what to do.
    pub fn open(cfg: &CameraConfig, clock: Arc<dyn Clock>) -> Result<Self> {
        let backend = V4l2Backend {
            device: cfg.device.clone(),
            width: cfg.width,
            height: cfg.height,
            fps: cfg.fps,
            format: cfg.format,
            card: String::new(),
        };
        let core = Core::open(backend, cfg.device.display().to_string(), clock)?;
        tracing::info!(
            device = %cfg.device.display(),
            card = %core.backend.card,
            format = %core.neg,
            "camera open"
        );
        Ok(Self { core })
    }

    /// Frames skipped because their data was corrupt or cut short.
    pub fn skipped_corrupt(&self) -> u64 {
        self.core.skipped_corrupt
    }

    /// Times the camera was reopened after being lost.
    pub fn reopens(&self) -> u64 {
        self.core.reopens
    }

    /// The format in use (the last one negotiated).
    pub fn negotiated(&self) -> Negotiated {
        self.core.neg
    }
}

impl FrameSource for V4l2Source {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        self.core.next_frame()
    }

    /// An unplugged camera is reopened with backoff: the daemon stops the motors on the
    /// first error and keeps asking.
    fn recoverable(&self) -> bool {
        true
    }

    fn describe(&self) -> String {
        let card = &self.core.backend.card;
        format!(
            "v4l2 {}{} ({}, {BUFFERS} mmap buffers)",
            self.core.device,
            if card.is_empty() {
                String::new()
            } else {
                format!(" [{card}]")
            },
            self.core.neg
        )
    }
}

struct V4l2Backend {
    device: PathBuf,
    width: u32,
    height: u32,
    fps: f32,
    format: PixelFormat,
    /// The card name from the last open, for logs.
    card: String,
}

/// An open, configured device with its mapped buffers.
struct V4l2Capture {
    /// `Option` so `Drop` can stop the stream before the `v4l` crate's own drop runs.
    stream: Option<MmapStream<'static>>,
    _device: Device,
    neg: Negotiated,
}

impl Drop for V4l2Capture {
    fn drop(&mut self) {
        if let Some(mut stream) = self.stream.take() {
            // The v4l crate's Stream and buffer arena panic in their Drop when stopping
            // fails with anything but ENODEV. Stop here first: when that fails otherwise,
            // leak the stream (a few mappings and a file descriptor) instead of panicking.
            match stream.stop() {
                Ok(()) => drop(stream),
                Err(e) if e.raw_os_error() == Some(ENODEV) => drop(stream),
                Err(e) => {
                    tracing::warn!("cannot stop the camera stream ({e}); leaking its buffers");
                    std::mem::forget(stream);
                }
            }
        }
    }
}

/// Runs a call into the `v4l` crate, turning its panics on unexpected driver data
/// (invalid UTF-8 in names, unknown colorspace codes) into errors.
fn guarded<T>(what: &str, f: impl FnOnce() -> io::Result<T>) -> io::Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|_| {
        Err(io::Error::other(format!(
            "{what}: the driver returned data the v4l crate cannot parse"
        )))
    })
}

/// An I/O error from opening or configuring `device`, with what to do about it.
fn explain(device: &Path, step: &str, e: &io::Error) -> String {
    let d = device.display();
    match (e.kind(), e.raw_os_error()) {
        (io::ErrorKind::PermissionDenied, _) => format!(
            "camera {d}: permission denied ({step}): add your user to the `video` group \
             (`sudo usermod -aG video $USER`, then log out and in)"
        ),
        (io::ErrorKind::NotFound, _) | (_, Some(ENODEV)) | (_, Some(ENXIO)) => format!(
            "camera {d}: no such device ({step}: {e}); `jetpilot camera list` shows the cameras \
             there are"
        ),
        (_, Some(EBUSY)) => format!(
            "camera {d}: device busy ({step}): another program is streaming from it \
             (another jetpilot, a browser, cheese, GStreamer); `fuser -v {d}` shows which"
        ),
        (_, Some(EIO)) => format!(
            "camera {d}: I/O error ({step}): check the USB cable and power (`dmesg | tail`)"
        ),
        _ => format!("camera {d}: {step}: {e}"),
    }
}

fn fraction_for(fps: f32) -> Fraction {
    if (fps - fps.round()).abs() < 1e-3 {
        Fraction::new(1, fps.round().max(1.0) as u32)
    } else {
        Fraction::new(1000, (fps * 1000.0).round().max(1.0) as u32)
    }
}

fn fps_of(interval: Fraction) -> Option<f32> {
    (interval.numerator > 0 && interval.denominator > 0)
        .then(|| interval.denominator as f32 / interval.numerator as f32)
}

fn fourcc_str(fourcc: [u8; 4]) -> String {
    fourcc
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
        .collect::<String>()
        .trim_end()
        .to_string()
}

impl V4l2Backend {
    fn open_capture(&mut self) -> std::result::Result<V4l2Capture, String> {
        let path = &self.device;
        let d = path.display();
        if path.as_os_str().as_encoded_bytes().contains(&0) {
            return Err(format!("camera {d}: the device path contains a NUL byte"));
        }
        let dev =
            guarded("open", || Device::with_path(path)).map_err(|e| explain(path, "open", &e))?;
        let caps = guarded("VIDIOC_QUERYCAP", || dev.query_caps())
            .map_err(|e| explain(path, "query capabilities", &e))?;
        self.card = caps.card.clone();
        let flags = caps.capabilities;
        if !flags.is_empty() && !flags.contains(CapFlags::VIDEO_CAPTURE) {
            return Err(format!(
                "camera {d} ({}, driver {}) is not a video capture device; UVC cameras also \
                 create a metadata node: `jetpilot camera list` shows the one with formats",
                caps.card, caps.driver
            ));
        }
        if !flags.is_empty() && !flags.contains(CapFlags::STREAMING) {
            return Err(format!(
                "camera {d} ({}, driver {}) does not support streaming I/O",
                caps.card, caps.driver
            ));
        }
        let descs = guarded("VIDIOC_ENUM_FMT", || dev.enum_formats())
            .map_err(|e| explain(path, "list formats", &e))?;
        let offered: Vec<(PixelFormat, FourCC)> = descs
            .iter()
            .filter_map(|f| fourcc_format(f.fourcc.repr).map(|p| (p, f.fourcc)))
            .collect();
        let kinds: Vec<PixelFormat> = offered.iter().map(|(p, _)| *p).collect();
        let Some(chosen) = choose_format(self.format, &kinds, self.width, self.height) else {
            let list = if descs.is_empty() {
                "none".to_string()
            } else {
                descs
                    .iter()
                    .map(|f| format!("{} ({})", fourcc_str(f.fourcc.repr), f.description))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let csi = kinds.is_empty()
                && (caps.driver.contains("tegra") || caps.card.contains("vi-output"));
            return Err(format!(
                "camera {d} ({}) does not offer {}; it offers: {list}. {}",
                caps.card,
                match self.format {
                    PixelFormat::Auto =>
                        "any format jetpilot reads (YUYV, MJPEG, RGB3, BGR3, GREY)".to_string(),
                    f => convert::format_name(f).to_string(),
                },
                if csi {
                    "This looks like a CSI camera: use camera.source = \"pipe\" with \
                     nvarguscamerasrc (see the docs of jetpilot::camera::pipe)"
                } else {
                    "Set camera.format to one of those (or \"auto\")"
                }
            ));
        };
        let fourcc = offered
            .iter()
            .find(|(p, _)| *p == chosen)
            .map(|(_, f)| *f)
            .unwrap_or_else(|| FourCC::new(b"YUYV"));
        let want = Format::new(self.width, self.height, fourcc);
        let got = guarded("VIDIOC_S_FMT", || dev.set_format(&want))
            .map_err(|e| explain(path, "set the format", &e))?;
        if got.fourcc != fourcc {
            return Err(format!(
                "camera {d}: asked for {}, the driver set {}",
                fourcc_str(fourcc.repr),
                fourcc_str(got.fourcc.repr)
            ));
        }
        if got.width == 0 || got.height == 0 {
            return Err(format!(
                "camera {d}: the driver set an empty frame size {}x{}",
                got.width, got.height
            ));
        }
        if (got.width, got.height) != (self.width, self.height) {
            tracing::warn!(
                "camera {d}: asked for {}x{}, the driver gave {}x{} (the nearest it has)",
                self.width,
                self.height,
                got.width,
                got.height
            );
        }
        let mut fps = None;
        if self.fps.is_finite() && self.fps > 0.0 {
            match guarded("VIDIOC_S_PARM", || {
                dev.set_params(&Parameters::new(fraction_for(self.fps)))
            }) {
                Ok(p) => {
                    fps = fps_of(p.interval);
                    if let Some(f) = fps
                        && (f - self.fps).abs() > 0.5
                    {
                        tracing::warn!(
                            "camera {d}: asked for {} fps, the driver set {f:.2}",
                            self.fps
                        );
                    }
                }
                Err(e) => tracing::warn!("camera {d}: cannot set the frame rate: {e}"),
            }
        }
        let mut stream = MmapStream::with_buffers(&dev, BufType::VideoCapture, BUFFERS)
            .map_err(|e| explain(path, "map buffers", &e))?;
        let period = fps.map(|f| 1.0 / f).unwrap_or(1.0 / 30.0);
        stream.set_timeout(Duration::from_secs_f32((5.0 * period).clamp(2.0, 60.0)));
        let stride = if chosen == PixelFormat::Mjpeg {
            0
        } else {
            got.stride as usize
        };
        Ok(V4l2Capture {
            stream: Some(stream),
            _device: dev,
            neg: Negotiated {
                format: chosen,
                fourcc: fourcc.repr,
                width: got.width,
                height: got.height,
                stride,
                fps,
            },
        })
    }
}

impl Backend for V4l2Backend {
    type Capture = V4l2Capture;

    fn open(&mut self) -> std::result::Result<V4l2Capture, String> {
        self.open_capture()
    }

    fn negotiated(&self, cap: &V4l2Capture) -> Negotiated {
        cap.neg
    }

    fn next<'a>(&mut self, cap: &'a mut V4l2Capture) -> io::Result<RawFrame<'a>> {
        let Some(stream) = cap.stream.as_mut() else {
            return Err(io::Error::other("the stream is closed"));
        };
        let (buf, meta) = CaptureStream::next(stream)?;
        let used = meta.bytesused as usize;
        let data = if used == 0 || used > buf.len() {
            buf
        } else {
            &buf[..used]
        };
        Ok(RawFrame {
            data,
            flagged: meta.flags.contains(BufFlags::ERROR),
        })
    }

    fn resync(&mut self, cap: &mut V4l2Capture) -> io::Result<()> {
        // `next` queued the previous buffer and was interrupted waiting for a filled one;
        // dequeue one (dropping it) so the following `next` re-queues the right buffer.
        let Some(stream) = cap.stream.as_mut() else {
            return Err(io::Error::other("the stream is closed"));
        };
        loop {
            match CaptureStream::dequeue(stream) {
                Ok(_) => return Ok(()),
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
    }

    fn now(&self) -> Instant {
        Instant::now()
    }

    fn sleep(&mut self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// Frame rates of one frame size.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameRates {
    /// Frames per second, as listed by the driver.
    Discrete(Vec<f32>),
    /// Any rate in the range (frames per second).
    Range { min: f32, max: f32 },
    /// The driver does not say.
    Unknown,
}

/// Frame sizes of one format.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameSizes {
    Discrete(Vec<(u32, u32, FrameRates)>),
    /// Any size in the range, in steps.
    Stepwise {
        min: (u32, u32),
        max: (u32, u32),
        step: (u32, u32),
    },
    Unknown,
}

/// One pixel format a device offers.
#[derive(Debug, Clone, PartialEq)]
pub struct FormatInfo {
    pub fourcc: String,
    pub description: String,
    /// The `camera.format` value for it, when jetpilot reads it.
    pub format: Option<PixelFormat>,
    pub sizes: FrameSizes,
}

/// A `/dev/video*` node and what it offers.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    pub path: PathBuf,
    pub driver: String,
    pub card: String,
    pub bus: String,
    /// Whether it captures video (UVC metadata nodes do not).
    pub capture: bool,
    pub formats: Vec<FormatInfo>,
    /// Why it could not be opened or queried.
    pub error: Option<String>,
}

fn fmt_fps(v: f32) -> String {
    if (v - v.round()).abs() < 0.01 {
        format!("{}", v.round() as u32)
    } else {
        format!("{v:.2}")
    }
}

impl fmt::Display for FrameRates {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameRates::Discrete(v) if v.is_empty() => write!(f, "? fps"),
            FrameRates::Discrete(v) => {
                let list: Vec<String> = v.iter().map(|x| fmt_fps(*x)).collect();
                write!(f, "{} fps", list.join(", "))
            }
            FrameRates::Range { min, max } => {
                write!(f, "{}-{} fps", fmt_fps(*min), fmt_fps(*max))
            }
            FrameRates::Unknown => write!(f, "? fps"),
        }
    }
}

impl fmt::Display for DeviceInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.path.display())?;
        if !self.card.is_empty() {
            write!(f, ": {} (driver {}, {})", self.card, self.driver, self.bus)?;
        }
        writeln!(f)?;
        if let Some(e) = &self.error {
            return writeln!(f, "  cannot query it: {e}");
        }
        if !self.capture {
            return writeln!(f, "  not a video capture node (metadata or output)");
        }
        if self.formats.is_empty() {
            writeln!(f, "  no formats")?;
        }
        for fmt_info in &self.formats {
            let usable = match fmt_info.format {
                Some(p) => format!("format = \"{}\"", format!("{p:?}").to_lowercase()),
                None => "not read by jetpilot".to_string(),
            };
            writeln!(
                f,
                "  {} ({}) [{usable}]",
                fmt_info.fourcc, fmt_info.description
            )?;
            match &fmt_info.sizes {
                FrameSizes::Discrete(sizes) => {
                    for (w, h, rates) in sizes {
                        writeln!(f, "    {w}x{h}: {rates}")?;
                    }
                }
                FrameSizes::Stepwise { min, max, step } => writeln!(
                    f,
                    "    {}x{} to {}x{} in steps of {}x{}",
                    min.0, min.1, max.0, max.1, step.0, step.1
                )?,
                FrameSizes::Unknown => writeln!(f, "    sizes unknown")?,
            }
        }
        Ok(())
    }
}

fn rates_of(dev: &Device, fourcc: FourCC, w: u32, h: u32) -> FrameRates {
    match guarded("VIDIOC_ENUM_FRAMEINTERVALS", || {
        dev.enum_frameintervals(fourcc, w, h)
    }) {
        Ok(list) if !list.is_empty() => {
            let mut discrete = Vec::new();
            for iv in list {
                match iv.interval {
                    FrameIntervalEnum::Discrete(frac) => discrete.extend(fps_of(frac)),
                    FrameIntervalEnum::Stepwise(s) => {
                        // The longest interval is the lowest rate.
                        if let (Some(min), Some(max)) = (fps_of(s.max), fps_of(s.min)) {
                            return FrameRates::Range { min, max };
                        }
                    }
                }
            }
            FrameRates::Discrete(discrete)
        }
        _ => FrameRates::Unknown,
    }
}

fn query_device(path: &Path) -> DeviceInfo {
    let mut info = DeviceInfo {
        path: path.to_path_buf(),
        driver: String::new(),
        card: String::new(),
        bus: String::new(),
        capture: false,
        formats: Vec::new(),
        error: None,
    };
    let dev = match guarded("open", || Device::with_path(path)) {
        Ok(d) => d,
        Err(e) => {
            info.error = Some(explain(path, "open", &e));
            return info;
        }
    };
    match guarded("VIDIOC_QUERYCAP", || dev.query_caps()) {
        Ok(caps) => {
            info.capture =
                caps.capabilities.is_empty() || caps.capabilities.contains(CapFlags::VIDEO_CAPTURE);
            info.driver = caps.driver;
            info.card = caps.card;
            info.bus = caps.bus;
        }
        Err(e) => {
            info.error = Some(explain(path, "query capabilities", &e));
            return info;
        }
    }
    if !info.capture {
        return info;
    }
    let descs = match guarded("VIDIOC_ENUM_FMT", || dev.enum_formats()) {
        Ok(d) => d,
        Err(e) => {
            info.error = Some(explain(path, "list formats", &e));
            return info;
        }
    };
    for desc in descs {
        let fourcc = desc.fourcc;
        let sizes = match guarded("VIDIOC_ENUM_FRAMESIZES", || dev.enum_framesizes(fourcc)) {
            Ok(list) if !list.is_empty() => {
                let mut discrete = Vec::new();
                let mut stepwise = None;
                for fs in list {
                    match fs.size {
                        FrameSizeEnum::Discrete(s) => discrete.push((
                            s.width,
                            s.height,
                            rates_of(&dev, fourcc, s.width, s.height),
                        )),
                        // Never expand a stepwise range into sizes: 1..4096 in steps of 1
                        // is millions of them.
                        FrameSizeEnum::Stepwise(s) => {
                            stepwise = Some(FrameSizes::Stepwise {
                                min: (s.min_width, s.min_height),
                                max: (s.max_width, s.max_height),
                                step: (s.step_width, s.step_height),
                            })
                        }
                    }
                }
                match stepwise {
                    Some(s) if discrete.is_empty() => s,
                    _ => FrameSizes::Discrete(discrete),
                }
            }
            _ => FrameSizes::Unknown,
        };
        info.formats.push(FormatInfo {
            fourcc: fourcc_str(fourcc.repr),
            description: desc.description,
            format: fourcc_format(fourcc.repr),
            sizes,
        });
    }
    info
}

/// The `/dev/video<N>` nodes in `dir`, in number order.
fn video_nodes(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut nodes: Vec<(u32, PathBuf)> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name();
            let n = name.to_str()?.strip_prefix("video")?.parse::<u32>().ok()?;
            Some((n, e.path()))
        })
        .collect();
    nodes.sort();
    nodes.into_iter().map(|(_, p)| p).collect()
}

/// Every `/dev/video*` node with its driver, card, bus, formats, sizes and rates
/// (VIDIOC_QUERYCAP, ENUM_FMT, ENUM_FRAMESIZES, ENUM_FRAMEINTERVALS). Nodes that cannot
/// be opened are listed with the reason.
pub fn list_devices() -> Vec<DeviceInfo> {
    video_nodes(Path::new("/dev"))
        .iter()
        .map(|p| query_device(p))
        .collect()
}

/// Takes one frame from the V4L2 camera `cfg` names (after a few frames for the auto
/// exposure to settle) and writes it to `out` as PNG or JPEG, by its extension.
pub fn snap(cfg: &CameraConfig, out: &Path) -> Result<Frame> {
    let clock: Arc<dyn Clock> = Arc::new(crate::clock::MonotonicClock::new());
    let mut src = V4l2Source::open(cfg, clock)?;
    let mut kept = None;
    for _ in 0..=SNAP_WARMUP_FRAMES {
        match src.next_frame()? {
            Some(f) => kept = Some(f),
            None => break,
        }
    }
    let frame = kept
        .ok_or_else(|| CameraError::Other(format!("camera {}: no frame", cfg.device.display())))?;
    convert::write_image(out, frame.width, frame.height, &frame.rgb)?;
    Ok(frame)
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use super::*;
    use crate::clock::SimClock;

    #[test]
    fn backoff_doubles_from_half_a_second_to_five() {
        let t0 = Instant::now();
        let mut link = Link::Up;
        link.lost(t0);
        let Link::Down(r) = link else { panic!() };
        assert_eq!(r.attempts, 0);
        assert_eq!(r.wait(t0), Duration::from_millis(500));
        assert_eq!(r.wait(t0 + Duration::from_secs(1)), Duration::ZERO);
        let mut now = t0;
        let mut waits = Vec::new();
        for _ in 0..7 {
            now += Duration::from_secs(10);
            link.reopen_failed(now);
            let Link::Down(r) = link else { panic!() };
            waits.push(r.wait(now).as_millis());
        }
        assert_eq!(waits, vec![1000, 2000, 4000, 5000, 5000, 5000, 5000]);
        link.reopened();
        assert_eq!(link, Link::Up);
        // A new loss starts over at 0.5 s.
        link.lost(now);
        assert_eq!(link, Link::Down(Reconnect::after_loss(now)));
        assert_eq!(Reconnect::delay(u32::MAX), Reconnect::MAX_DELAY);
    }

    #[test]
    fn auto_format_choice() {
        use PixelFormat::*;
        let uvc = [Yuyv, Mjpeg];
        assert_eq!(choose_format(Auto, &uvc, 640, 480), Some(Mjpeg));
        assert_eq!(choose_format(Auto, &uvc, 1280, 720), Some(Mjpeg));
        assert_eq!(choose_format(Auto, &uvc, 320, 240), Some(Yuyv));
        assert_eq!(choose_format(Auto, &[Mjpeg], 320, 240), Some(Mjpeg));
        assert_eq!(choose_format(Auto, &[Yuyv], 1280, 720), Some(Yuyv));
        assert_eq!(choose_format(Auto, &[Grey, Bgr3], 640, 480), Some(Bgr3));
        assert_eq!(choose_format(Auto, &[], 640, 480), None);
        assert_eq!(choose_format(Yuyv, &uvc, 1280, 720), Some(Yuyv));
        assert_eq!(choose_format(Rgb3, &uvc, 1280, 720), None);
        assert_eq!(fourcc_format(*b"MJPG"), Some(Mjpeg));
        assert_eq!(fourcc_format(*b"JPEG"), Some(Mjpeg));
        assert_eq!(fourcc_format(*b"RG10"), None);
        let frac = |f: Fraction| (f.numerator, f.denominator);
        assert_eq!(frac(fraction_for(30.0)), (1, 30));
        assert_eq!(frac(fraction_for(7.5)), (1000, 7500));
        assert_eq!(fps_of(Fraction::new(1001, 30000)), Some(30000.0 / 1001.0));
        assert_eq!(fps_of(Fraction::new(0, 30)), None);
    }

    #[test]
    fn errors_say_what_to_do() {
        let p = Path::new("/dev/video7");
        let e = explain(p, "open", &io::Error::from(io::ErrorKind::PermissionDenied));
        assert!(
            e.contains("/dev/video7") && e.contains("`video` group"),
            "{e}"
        );
        let e = explain(p, "open", &io::Error::from(io::ErrorKind::NotFound));
        assert!(
            e.contains("no such device") && e.contains("jetpilot camera list"),
            "{e}"
        );
        let e = explain(p, "open", &io::Error::from_raw_os_error(ENODEV));
        assert!(e.contains("jetpilot camera list"), "{e}");
        let e = explain(p, "map buffers", &io::Error::from_raw_os_error(EBUSY));
        assert!(e.contains("busy") && e.contains("fuser"), "{e}");
    }

    #[test]
    fn opening_a_missing_device_names_it() {
        let cfg = CameraConfig {
            device: PathBuf::from("/dev/video-jetpilot-test-none"),
            ..CameraConfig::default()
        };
        let err = V4l2Source::open(&cfg, Arc::new(SimClock::new()))
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("/dev/video-jetpilot-test-none") && err.contains("camera list"),
            "{err}"
        );
        let err = snap(&cfg, Path::new("/tmp/x.png"))
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("no such device"), "{err}");
    }

    #[test]
    fn listing_finds_nodes_in_number_order() {
        let dir = tempfile::tempdir().unwrap();
        for n in ["video10", "video2", "video0", "videox", "vbi0", "video"] {
            std::fs::write(dir.path().join(n), b"").unwrap();
        }
        let names: Vec<String> = video_nodes(dir.path())
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, vec!["video0", "video2", "video10"]);
        // A plain file is not a device: reported, not a panic.
        let info = query_device(&dir.path().join("video0"));
        assert!(info.error.is_some(), "{info:?}");
        assert!(info.to_string().contains("cannot query"), "{info}");
        // On this machine: whatever is there, no panic.
        let _ = list_devices();
    }

    #[test]
    fn device_info_display() {
        let info = DeviceInfo {
            path: PathBuf::from("/dev/video0"),
            driver: "uvcvideo".into(),
            card: "USB Camera".into(),
            bus: "usb-70090000.xusb-2.1".into(),
            capture: true,
            formats: vec![
                FormatInfo {
                    fourcc: "MJPG".into(),
                    description: "Motion-JPEG".into(),
                    format: Some(PixelFormat::Mjpeg),
                    sizes: FrameSizes::Discrete(vec![
                        (640, 480, FrameRates::Discrete(vec![30.0, 15.0])),
                        (
                            1280,
                            720,
                            FrameRates::Range {
                                min: 5.0,
                                max: 29.97,
                            },
                        ),
                    ]),
                },
                FormatInfo {
                    fourcc: "RG10".into(),
                    description: "10-bit Bayer".into(),
                    format: None,
                    sizes: FrameSizes::Stepwise {
                        min: (32, 32),
                        max: (3264, 2464),
                        step: (2, 2),
                    },
                },
            ],
            error: None,
        };
        let s = info.to_string();
        assert!(
            s.starts_with("/dev/video0: USB Camera (driver uvcvideo"),
            "{s}"
        );
        assert!(s.contains("MJPG (Motion-JPEG) [format = \"mjpeg\"]"), "{s}");
        assert!(s.contains("640x480: 30, 15 fps"), "{s}");
        assert!(s.contains("1280x720: 5-29.97 fps"), "{s}");
        assert!(s.contains("not read by jetpilot"), "{s}");
        assert!(s.contains("32x32 to 3264x2464 in steps of 2x2"), "{s}");
    }

    // --- The capture loop against a scripted backend -------------------------------

    enum Ev {
        Data(Vec<u8>),
        Flagged(Vec<u8>),
        Fail(io::Error),
    }

    struct Fake {
        opens: VecDeque<std::result::Result<(), String>>,
        events: VecDeque<Ev>,
        neg: Negotiated,
        base: Instant,
        elapsed: Duration,
        slept: Vec<Duration>,
        resyncs: u32,
    }

    struct FakeCap {
        current: Vec<u8>,
    }

    impl Backend for Fake {
        type Capture = FakeCap;
        fn open(&mut self) -> std::result::Result<FakeCap, String> {
            self.opens
                .pop_front()
                .unwrap_or_else(|| Err("camera /dev/fake: no such device".into()))
                .map(|()| FakeCap {
                    current: Vec::new(),
                })
        }
        fn negotiated(&self, _: &FakeCap) -> Negotiated {
            self.neg
        }
        fn next<'a>(&mut self, cap: &'a mut FakeCap) -> io::Result<RawFrame<'a>> {
            self.elapsed += Duration::from_millis(33);
            match self.events.pop_front() {
                Some(Ev::Data(d)) => {
                    cap.current = d;
                    Ok(RawFrame {
                        data: &cap.current,
                        flagged: false,
                    })
                }
                Some(Ev::Flagged(d)) => {
                    cap.current = d;
                    Ok(RawFrame {
                        data: &cap.current,
                        flagged: true,
                    })
                }
                Some(Ev::Fail(e)) => Err(e),
                None => Err(io::Error::from_raw_os_error(ENODEV)),
            }
        }
        fn resync(&mut self, _: &mut FakeCap) -> io::Result<()> {
            self.resyncs += 1;
            Ok(())
        }
        fn now(&self) -> Instant {
            self.base + self.elapsed
        }
        fn sleep(&mut self, d: Duration) {
            self.slept.push(d);
            self.elapsed += d;
        }
    }

    fn fake(format: PixelFormat, opens: usize, events: Vec<Ev>) -> Fake {
        Fake {
            opens: (0..opens).map(|_| Ok(())).collect(),
            events: events.into(),
            neg: Negotiated {
                format,
                fourcc: *b"TEST",
                width: 2,
                height: 2,
                stride: 0,
                fps: Some(30.0),
            },
            base: Instant::now(),
            elapsed: Duration::ZERO,
            slept: Vec::new(),
            resyncs: 0,
        }
    }

    fn grey(v: u8) -> Ev {
        Ev::Data(vec![v; 4])
    }

    fn core(backend: Fake) -> (Core<Fake>, Arc<SimClock>) {
        let clock = Arc::new(SimClock::new());
        let c = Core::open(backend, "/dev/fake".into(), clock.clone()).unwrap();
        (c, clock)
    }

    #[test]
    fn frames_are_converted_stamped_and_numbered() {
        let (mut c, clock) = core(fake(PixelFormat::Grey, 1, vec![grey(10), grey(20)]));
        let f0 = c.next_frame().unwrap().unwrap();
        clock.advance(Duration::from_millis(40));
        let f1 = c.next_frame().unwrap().unwrap();
        assert_eq!((f0.seq, f1.seq), (0, 1));
        assert_eq!((f0.width, f0.height), (2, 2));
        assert_eq!(*f0.rgb, vec![10; 12]);
        assert_eq!(*f1.rgb, vec![20; 12]);
        assert_eq!(f1.captured_at - f0.captured_at, Duration::from_millis(40));
    }

    #[test]
    fn corrupt_mjpeg_is_skipped_and_counted_without_gaps() {
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode(&[200; 12], 2, 2, image::ExtendedColorType::Rgb8)
            .unwrap();
        let events = vec![
            Ev::Data(jpeg.clone()),
            Ev::Data(jpeg[..jpeg.len() / 2].to_vec()), // truncated
            Ev::Data(b"garbage".to_vec()),
            Ev::Flagged(jpeg.clone()), // the driver says it is bad
            Ev::Fail(io::Error::from(io::ErrorKind::Interrupted)),
            Ev::Data(jpeg.clone()),
        ];
        let (mut c, _) = core(fake(PixelFormat::Mjpeg, 1, events));
        let a = c.next_frame().unwrap().unwrap();
        let b = c.next_frame().unwrap().unwrap();
        assert_eq!((a.seq, b.seq), (0, 1));
        assert!(
            b.rgb.iter().all(|&v| (v as i32 - 200).abs() <= 3),
            "{:?}",
            b.rgb
        );
        assert_eq!(c.skipped_corrupt, 3);
        assert_eq!(c.backend.resyncs, 1);
    }

    #[test]
    fn lost_device_errors_once_then_reopens_with_backoff() {
        let events = vec![
            grey(1),
            Ev::Fail(io::Error::from_raw_os_error(ENODEV)),
            grey(2),
        ];
        let mut f = fake(PixelFormat::Grey, 1, events);
        // The first reopen fails, the second works.
        f.opens
            .push_back(Err("camera /dev/fake: no such device".into()));
        f.opens.push_back(Ok(()));
        let (mut c, _) = core(f);
        assert_eq!(c.next_frame().unwrap().unwrap().seq, 0);
        let err = c.next_frame().unwrap_err().to_string();
        assert!(
            err.contains("/dev/fake") && err.contains("disappeared") && err.contains("reopen"),
            "{err}"
        );
        assert!(c.backend.slept.is_empty(), "the loss is reported at once");
        let err = c.next_frame().unwrap_err().to_string();
        assert!(
            err.contains("reopen try 1 failed") && err.contains("next try in 1.0 s"),
            "{err}"
        );
        let f = c.next_frame().unwrap().unwrap();
        assert_eq!((f.seq, f.rgb[0]), (1, 2), "numbering carries on");
        assert_eq!(
            c.backend.slept,
            vec![Duration::from_millis(500), Duration::from_millis(1000)]
        );
        assert_eq!(c.reopens, 1);
        assert_eq!(c.link, Link::Up);
    }

    #[test]
    fn a_run_of_corrupt_frames_counts_as_a_loss() {
        let mut events: Vec<Ev> = (0..MAX_BAD_IN_A_ROW).map(|_| Ev::Data(vec![1])).collect();
        events.push(grey(5));
        let (mut c, _) = core(fake(PixelFormat::Grey, 2, events));
        let err = c.next_frame().unwrap_err().to_string();
        assert!(err.contains("30 corrupt frames in a row"), "{err}");
        assert!(err.contains("GREY 2x2"), "{err}");
        let f = c.next_frame().unwrap().unwrap();
        assert_eq!((f.seq, f.rgb[0]), (0, 5));
        assert_eq!(c.skipped_corrupt, MAX_BAD_IN_A_ROW as u64);
    }

    #[test]
    fn a_stall_is_a_loss() {
        let events = vec![Ev::Fail(io::Error::new(
            io::ErrorKind::TimedOut,
            "VIDIOC_DQBUF",
        ))];
        let (mut c, _) = core(fake(PixelFormat::Grey, 1, events));
        let err = c.next_frame().unwrap_err().to_string();
        assert!(err.contains("stalled"), "{err}");
        assert!(matches!(c.link, Link::Down(_)));
    }
}

//! Raw frames from a command's standard output (`camera.source = "pipe"`): the way to
//! use a Jetson CSI camera, whose ISP only GStreamer's `nvarguscamerasrc` reaches.
//!
//! `camera.command` runs under `sh -c`; each frame is exactly `width * height * bpp`
//! bytes of `camera.format` (`rgb3`, `bgr3`: 3; `yuyv`: 2; `grey`: 1; YUYV rows of an
//! odd width are padded to whole pixel pairs) with no header. Frames are converted to
//! RGB8 ([`super::convert`]), stamped with the daemon's clock when their last byte
//! arrives and numbered from 0. The command sets the pace; the pipe holds less than one
//! frame, so frames are never much older than the command made them.
//!
//! The command ending, or its output ending in the middle of a frame, is an error naming
//! the command with its exit status and the last line it wrote to standard error (which
//! is also logged at debug level); later calls return the same error. A command that
//! stalls without ending blocks `next_frame`; the daemon's watchdog stops the motors when
//! fresh commands stop coming.
//!
//! # Jetson CSI camera (IMX219, Raspberry Pi camera v2)
//!
//! ```toml
//! [camera]
//! source = "pipe"
//! format = "bgr3"
//! width = 224
//! height = 224
//! command = "gst-launch-1.0 -q nvarguscamerasrc sensor-id=0 ! 'video/x-raw(memory:NVMM),width=1280,height=720,framerate=30/1' ! nvvidconv ! 'video/x-raw,width=224,height=224,format=BGRx' ! videoconvert ! 'video/x-raw,format=BGR' ! fdsink fd=3 3>&1 1>&2"
//! ```
//!
//! `nvvidconv` scales in hardware but cannot write 3-byte BGR, hence `BGRx` then
//! `videoconvert`. The frames go to file descriptor 3, which `3>&1 1>&2` points at the
//! pipe while the command's own standard output goes to standard error: the Argus
//! plugin prints `GST_ARGUS: ...` lines with `printf`, which would corrupt frames written
//! with `fdsink fd=1` (the plain form works when nothing else prints). Width, height and
//! `format` in the config must match the last caps of the pipeline. `sensor-id` picks the
//! camera on boards with two; add `flip-method=2` to `nvvidconv` for a camera mounted
//! upside down. If frames stop with `Failed to create CaptureSession`, restart the Argus
//! daemon: `sudo systemctl restart nvargus-daemon`.
//!
//! Any other program works the same way, e.g. `ffmpeg -loglevel error -f v4l2 -i
//! /dev/video0 -vf scale=224:224 -pix_fmt rgb24 -f rawvideo -` with `format = "rgb3"`.
//!
//! # Stopping
//!
//! The command runs in its own process group (so a Ctrl-C in the terminal reaches
//! jetpilot, which stops the motors first, not the camera). When the source is dropped,
//! jetpilot closes the pipe and sends SIGINT to the group (gst-launch shuts its pipeline
//! down; `nvargus-daemon` copes badly with clients killed outright), waits up to 1 s,
//! then sends SIGKILL to whatever is left.

use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::CommandExt;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::convert::{self, RgbPool};
use super::{CameraError, Frame, FrameSource, Result};
use crate::clock::Clock;
use crate::config::{CameraConfig, PixelFormat};

/// How long a dropped source waits after SIGINT before SIGKILL.
const STOP_GRACE: Duration = Duration::from_secs(1);
/// How long to wait for the exit status and last stderr line once the output has ended.
const END_GRACE: Duration = Duration::from_secs(2);
/// Longest stderr line kept for error messages.
const MAX_LINE: usize = 300;

pub struct PipeSource {
    command: String,
    format: PixelFormat,
    width: u32,
    height: u32,
    frame_len: usize,
    child: Child,
    stdout: Option<ChildStdout>,
    stderr_last: Arc<Mutex<Option<String>>>,
    stderr_thread: Option<JoinHandle<()>>,
    raw: Vec<u8>,
    pool: RgbPool,
    clock: Arc<dyn Clock>,
    seq: u64,
    /// Set once the output has ended: the error every later call returns.
    ended: Option<String>,
}

fn pipe_err(msg: String) -> CameraError {
    CameraError::Other(msg)
}

impl PipeSource {
    /// Starts `cfg.command` with `sh -c`, reading `cfg.width` x `cfg.height` frames of
    /// `cfg.format` from its standard output.
    pub fn open(cfg: &CameraConfig, clock: Arc<dyn Clock>) -> Result<Self> {
        let command = cfg.command.trim().to_string();
        if command.is_empty() {
            return Err(pipe_err(
                "pipe source: camera.command is empty; give the command line that writes raw \
                 frames to its standard output"
                    .into(),
            ));
        }
        let frame_len = convert::packed_frame_len(cfg.format, cfg.width, cfg.height)
            .filter(|&n| n > 0)
            .ok_or_else(|| {
                pipe_err(format!(
                    "pipe source `{command}`: camera.format = \"{}\" at {}x{} cannot be read \
                     from a pipe: use rgb3, bgr3, yuyv or grey and a non-empty size",
                    format!("{:?}", cfg.format).to_lowercase(),
                    cfg.width,
                    cfg.height
                ))
            })?;
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(&command)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .process_group(0)
            .spawn()
            .map_err(|e| pipe_err(format!("pipe source: cannot start `sh -c {command}`: {e}")))?;
        let stdout = child.stdout.take();
        let stderr_last = Arc::new(Mutex::new(None));
        let stderr_thread = child.stderr.take().and_then(|stderr| {
            let last = stderr_last.clone();
            std::thread::Builder::new()
                .name("camera-pipe-stderr".into())
                .spawn(move || {
                    for line in BufReader::new(stderr).split(b'\n') {
                        let Ok(line) = line else { break };
                        let text = String::from_utf8_lossy(&line);
                        let text = text.trim();
                        if text.is_empty() {
                            continue;
                        }
                        tracing::debug!(target: "jetpilot::camera::pipe", "command: {text}");
                        let mut kept: String = text.chars().take(MAX_LINE).collect();
                        if kept.len() < text.len() {
                            kept.push_str("...");
                        }
                        if let Ok(mut slot) = last.lock() {
                            *slot = Some(kept);
                        }
                    }
                })
                .ok()
        });
        tracing::info!(command = %command, "camera pipe started (pid {})", child.id());
        Ok(Self {
            command,
            format: cfg.format,
            width: cfg.width,
            height: cfg.height,
            frame_len,
            child,
            stdout,
            stderr_last,
            stderr_thread,
            raw: Vec::new(),
            pool: RgbPool::new(4),
            clock,
            seq: 0,
            ended: None,
        })
    }

    /// Once the output has ended: the exit status and last stderr line, waiting a little
    /// for both.
    fn end_details(&mut self) -> String {
        let deadline = Instant::now() + END_GRACE;
        let status = loop {
            match self.child.try_wait() {
                Ok(Some(s)) => break Some(s),
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                _ => break None,
            }
        };
        while self
            .stderr_thread
            .as_ref()
            .is_some_and(|t| !t.is_finished())
            && Instant::now() < deadline
        {
            std::thread::sleep(Duration::from_millis(10));
        }
        let mut details = match status {
            Some(s) => {
                let hint = match s.code() {
                    Some(127) => " (command not found)",
                    Some(126) => " (not executable)",
                    _ => "",
                };
                format!(" ({s}{hint})")
            }
            None => " (still running with its output closed)".to_string(),
        };
        if let Some(line) = self.stderr_last.lock().ok().and_then(|l| l.clone()) {
            details.push_str(&format!("; its last error output: {line}"));
        }
        details
    }

    fn signal_group(&self, signal: &str) {
        // No libc here: the shell's `kill` reaches a whole process group.
        let _ = Command::new("sh")
            .args(["-c", "kill -s \"$1\" -- -\"$2\"", "sh", signal])
            .arg(self.child.id().to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status();
    }

    /// Whether any live (non-zombie) process is left in the command's process group.
    fn group_alive(&self) -> bool {
        let pgid = self.child.id().to_string();
        let Ok(entries) = std::fs::read_dir("/proc") else {
            return false;
        };
        entries.filter_map(|e| e.ok()).any(|e| {
            let name = e.file_name();
            let Some(name) = name.to_str() else {
                return false;
            };
            if !name.bytes().all(|b| b.is_ascii_digit()) {
                return false;
            }
            let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
                return false;
            };
            // pid (comm) state ppid pgrp ...; comm may hold spaces and parentheses.
            let Some(rest) = stat.rfind(')').map(|i| &stat[i + 1..]) else {
                return false;
            };
            let mut fields = rest.split_whitespace();
            let state = fields.next();
            let pgrp = fields.nth(1);
            state != Some("Z") && state != Some("X") && pgrp == Some(pgid.as_str())
        })
    }
}

impl FrameSource for PipeSource {
    fn next_frame(&mut self) -> Result<Option<Frame>> {
        if let Some(msg) = &self.ended {
            return Err(pipe_err(msg.clone()));
        }
        self.raw.resize(self.frame_len, 0);
        let mut got = 0;
        let mut read_error = None;
        if let Some(stdout) = self.stdout.as_mut() {
            while got < self.frame_len {
                match stdout.read(&mut self.raw[got..]) {
                    Ok(0) => break,
                    Ok(n) => got += n,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(e) => {
                        read_error = Some(e);
                        break;
                    }
                }
            }
        }
        if got < self.frame_len {
            let details = self.end_details();
            let what = match (&read_error, got) {
                (Some(e), _) => format!("reading its output failed: {e}"),
                (None, 0) => format!("ended after {} frames", self.seq),
                (None, n) => format!(
                    "ended in the middle of frame {}: {n} of {} bytes ({}x{} {})",
                    self.seq,
                    self.frame_len,
                    self.width,
                    self.height,
                    convert::format_name(self.format)
                ),
            };
            let msg = format!("pipe command `{}` {what}{details}", self.command);
            self.stdout = None;
            self.ended = Some(msg.clone());
            return Err(pipe_err(msg));
        }
        let (format, width, height, raw) = (self.format, self.width, self.height, &self.raw);
        let rgb = self
            .pool
            .fill(|dst| convert::to_rgb(format, width, height, 0, raw, dst))
            .map_err(|e| pipe_err(format!("pipe command `{}`: {e}", self.command)))?;
        let frame = Frame {
            seq: self.seq,
            captured_at: self.clock.now(),
            width,
            height,
            rgb,
        };
        self.seq += 1;
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        format!(
            "pipe `{}` ({}x{} {})",
            self.command,
            self.width,
            self.height,
            convert::format_name(self.format)
        )
    }
}

impl Drop for PipeSource {
    fn drop(&mut self) {
        // Closing the pipe first makes a writer fail (EPIPE) even if it ignores SIGINT.
        self.stdout = None;
        if matches!(self.child.try_wait(), Ok(None)) || self.group_alive() {
            self.signal_group("INT");
            let deadline = Instant::now() + STOP_GRACE;
            while Instant::now() < deadline {
                let _ = self.child.try_wait();
                if !self.group_alive() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            if self.group_alive() {
                self.signal_group("KILL");
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::SimClock;

    fn cfg(format: PixelFormat, w: u32, h: u32, command: &str) -> CameraConfig {
        CameraConfig {
            source: crate::config::CameraSource::Pipe,
            format,
            width: w,
            height: h,
            command: command.into(),
            ..CameraConfig::default()
        }
    }

    fn open(c: &CameraConfig) -> PipeSource {
        PipeSource::open(c, Arc::new(SimClock::new())).unwrap()
    }

    #[test]
    fn two_rgb3_frames_then_an_error_naming_the_command() {
        // Two 2x1 RGB frames: (1,2,3)(4,5,6) and (7,8,9)(10,11,12).
        let cmd = r"printf '\001\002\003\004\005\006\007\010\011\012\013\014'";
        let mut src = open(&cfg(PixelFormat::Rgb3, 2, 1, cmd));
        let a = src.next_frame().unwrap().unwrap();
        let b = src.next_frame().unwrap().unwrap();
        assert_eq!((a.seq, a.width, a.height), (0, 2, 1));
        assert_eq!(*a.rgb, vec![1, 2, 3, 4, 5, 6]);
        assert_eq!((b.seq, &**b.rgb), (1, &[7u8, 8, 9, 10, 11, 12][..]));
        let err = src.next_frame().unwrap_err().to_string();
        assert!(
            err.contains(cmd)
                && err.contains("ended after 2 frames")
                && err.contains("exit status: 0"),
            "{err}"
        );
        // And again, without blocking.
        assert_eq!(src.next_frame().unwrap_err().to_string(), err);
        assert!(src.describe().contains("2x1 RGB3"), "{}", src.describe());
    }

    #[test]
    fn bgr3_yuyv_and_grey_are_converted() {
        let mut src = open(&cfg(PixelFormat::Bgr3, 1, 1, r"printf '\001\002\003'"));
        assert_eq!(*src.next_frame().unwrap().unwrap().rgb, vec![3, 2, 1]);
        // YUYV 2x1 white (Y=235 U=V=128), then 2x1 black.
        let cmd = r"printf '\353\200\353\200\020\200\020\200'";
        let mut src = open(&cfg(PixelFormat::Yuyv, 2, 1, cmd));
        assert_eq!(*src.next_frame().unwrap().unwrap().rgb, vec![255; 6]);
        assert_eq!(*src.next_frame().unwrap().unwrap().rgb, vec![0; 6]);
        let mut src = open(&cfg(PixelFormat::Grey, 2, 2, r"printf '\012\024\036\050'"));
        let f = src.next_frame().unwrap().unwrap();
        assert_eq!(*f.rgb, vec![10, 10, 10, 20, 20, 20, 30, 30, 30, 40, 40, 40]);
    }

    #[test]
    fn random_frames_have_the_right_size() {
        let cmd = "head -c 301056 /dev/urandom"; // two 224x224 BGR frames
        let mut src = open(&cfg(PixelFormat::Bgr3, 224, 224, cmd));
        for seq in 0..2 {
            let f = src.next_frame().unwrap().unwrap();
            assert_eq!((f.seq, f.rgb.len()), (seq, 224 * 224 * 3));
        }
        assert!(src.next_frame().is_err());
    }

    #[test]
    fn a_short_frame_names_the_bytes_and_stderr() {
        let cmd =
            r"printf '\001\002\003\004\005\006\007\010\011'; echo 'camera exploded' >&2; exit 3";
        let mut src = open(&cfg(PixelFormat::Rgb3, 2, 1, cmd));
        src.next_frame().unwrap().unwrap();
        let err = src.next_frame().unwrap_err().to_string();
        assert!(
            err.contains("middle of frame 1: 3 of 6 bytes (2x1 RGB3)")
                && err.contains("exit status: 3")
                && err.contains("camera exploded"),
            "{err}"
        );
    }

    #[test]
    fn a_missing_command_is_named() {
        let mut src = open(&cfg(
            PixelFormat::Rgb3,
            2,
            1,
            "jetpilot-no-such-command --flag",
        ));
        let err = src.next_frame().unwrap_err().to_string();
        assert!(
            err.contains("jetpilot-no-such-command")
                && err.contains("127")
                && err.contains("command not found"),
            "{err}"
        );
    }

    #[test]
    fn bad_configs_are_refused() {
        let clock: Arc<dyn Clock> = Arc::new(SimClock::new());
        for c in [
            cfg(PixelFormat::Mjpeg, 2, 1, "true"),
            cfg(PixelFormat::Auto, 2, 1, "true"),
            cfg(PixelFormat::Rgb3, 0, 1, "true"),
            cfg(PixelFormat::Rgb3, 2, 1, "  "),
        ] {
            let err = PipeSource::open(&c, clock.clone())
                .err()
                .unwrap()
                .to_string();
            assert!(err.contains("pipe source"), "{err}");
        }
    }

    fn alive(pid: u32) -> bool {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .map(|s| {
                let state = s
                    .rfind(')')
                    .and_then(|i| s[i + 1..].split_whitespace().next());
                state != Some("Z")
            })
            .unwrap_or(false)
    }

    #[test]
    fn drop_stops_the_whole_command() {
        let dir = tempfile::tempdir().unwrap();
        let pidfile = dir.path().join("pid");
        // A background grandchild that ignores SIGINT (as async commands of `sh` do) and
        // a foreground one that keeps writing frames.
        let cmd = format!(
            "sleep 30 & echo $! > {}; while :; do printf '\\001\\002\\003'; sleep 0.01; done",
            pidfile.display()
        );
        let mut src = open(&cfg(PixelFormat::Rgb3, 1, 1, &cmd));
        assert_eq!(*src.next_frame().unwrap().unwrap().rgb, vec![1, 2, 3]);
        let sh = src.child.id();
        let sleeper: u32 = std::fs::read_to_string(&pidfile)
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        assert!(alive(sleeper));
        let t = Instant::now();
        drop(src);
        assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
        let deadline = Instant::now() + Duration::from_secs(2);
        while alive(sleeper) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert!(!alive(sleeper), "the grandchild outlived the source");
        assert!(!alive(sh));
    }
}

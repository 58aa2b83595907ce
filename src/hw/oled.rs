//! The status display: an SSD1306 128x32 OLED on I2C (address 0x3C on the JetBot's bus 1,
//! `/dev/i2c-1`, the panel NVIDIA's and Yahboom's JetBot stats service uses), driven through
//! the `ssd1306` crate in buffered graphics mode with `embedded-graphics` text.
//!
//! Four lines of [`FONT_5X8`] (25 characters each) fill the 128x32 panel. What they say is
//! the pure function [`layout`]; [`Oled`] only draws them, and redraws only when a line
//! changed, so a once-a-second refresh of an unchanged status costs no bus traffic. A full
//! redraw is two addressing commands and 512 data bytes (32 writes of 16) on the bus the
//! motor HAT shares; the kernel interleaves the motor writes between them.
//!
//! An absent display is not a fault: [`Oled::init`] fails with
//! [`DisplayError::NotFound`] ("no SSD1306 at 0x3C on /dev/i2c-1 ..."), which the caller
//! logs as a warning before going on with [`NoDisplay`].
//!
//! [`primary_ip`] finds the address to show (the interface of the default route first), from
//! `ip -4 -o addr`, or from `/proc/net` when `ip` is missing.

use std::net::Ipv4Addr;
use std::sync::{Arc, Mutex};

use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::FONT_5X8;
use embedded_graphics::pixelcolor::BinaryColor;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Baseline, Text};
use embedded_hal::i2c::{Error as _, ErrorKind, I2c, Operation};
use ssd1306::mode::BufferedGraphicsMode;
use ssd1306::prelude::{DisplayConfig, DisplayRotation, DisplaySize128x32, I2CInterface};
use ssd1306::{I2CDisplayInterface, Ssd1306};

/// The JetBot's OLED address (7-bit).
pub const DEFAULT_ADDRESS: u8 = 0x3C;
/// Characters per line with [`FONT_5X8`] on 128 pixels.
pub const LINE_CHARS: usize = 25;
/// Lines on a 32-pixel panel with an 8-pixel font.
pub const LINES: usize = 4;

/// Errors from a status display.
#[derive(Debug, thiserror::Error)]
pub enum DisplayError {
    /// Nothing answered the first command: no display, wrong address, or wrong bus.
    #[error(
        "no SSD1306 at 0x{address:02X} on {bus} ({detail}); a robot without the OLED runs without it; `i2cdetect -y -r 1` lists what is on the bus"
    )]
    NotFound {
        address: u8,
        bus: String,
        detail: String,
    },
    /// The display answered before, then a write failed.
    #[error("SSD1306 at 0x{address:02X} on {bus}: I2C write failed: {detail}")]
    Bus {
        address: u8,
        bus: String,
        detail: String,
    },
    #[error("SSD1306: show()/clear() before init()")]
    NotInitialised,
}

/// What the display shows. Every field is the caller's latest value.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Status {
    /// Drive mode, e.g. `user`, `auto`, `stopped` (cut to 13 characters).
    pub mode: String,
    /// Frames per second through the pipeline.
    pub fps: f32,
    /// Speed command, -1..=1.
    pub speed: f32,
    /// Steering command, -1..=1.
    pub steering: f32,
    /// Interventions counted in this run.
    pub interventions: u32,
    /// `(1 - interventions * 6 s / seconds) * 100`.
    pub autonomy_percent: f32,
    /// The robot's address, from [`primary_ip`]; `None` when it has none.
    pub ip: Option<String>,
}

/// Something that shows a [`Status`]: the OLED, or nothing.
pub trait StatusDisplay: Send {
    /// Shows `status` (may skip the bus when nothing visible changed).
    fn show(&mut self, status: &Status) -> Result<(), DisplayError>;
    /// Blanks the display.
    fn clear(&mut self) -> Result<(), DisplayError>;
}

/// A robot without a display.
#[derive(Debug, Default, Clone, Copy)]
pub struct NoDisplay;

impl StatusDisplay for NoDisplay {
    fn show(&mut self, _status: &Status) -> Result<(), DisplayError> {
        Ok(())
    }
    fn clear(&mut self) -> Result<(), DisplayError> {
        Ok(())
    }
}

/// The four lines for `status`, each at most [`LINE_CHARS`] ASCII characters:
///
/// ```text
/// auto           29.8 fps
/// spd +0.25  str -0.10
/// int 3   auto 97.0%
/// ip 192.168.1.23
/// ```
///
/// Non-finite numbers show as `--`; characters outside printable ASCII as `?`.
pub fn layout(status: &Status) -> [String; LINES] {
    let mode = if status.mode.trim().is_empty() {
        "-".to_string()
    } else {
        ascii(status.mode.trim()).chars().take(13).collect()
    };
    let ip = match &status.ip {
        Some(ip) if !ip.trim().is_empty() => format!("ip {}", ascii(ip.trim())),
        _ => "ip -- (no network)".to_string(),
    };
    [
        format!("{mode:<13}{:>6} fps", fixed(status.fps, 1)),
        format!(
            "spd {}  str {}",
            signed(status.speed),
            signed(status.steering)
        ),
        format!(
            "int {:<3} auto {}%",
            status.interventions,
            fixed(status.autonomy_percent, 1)
        ),
        ip,
    ]
    .map(|line| line.chars().take(LINE_CHARS).collect::<String>())
}

fn ascii(s: &str) -> String {
    s.chars()
        .map(|c| if (' '..='~').contains(&c) { c } else { '?' })
        .collect()
}

fn fixed(v: f32, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "--".to_string()
    }
}

fn signed(v: f32) -> String {
    if v.is_finite() {
        // -0.001 would print as "-0.00"; show a clean zero.
        let v = if v.abs() < 0.005 { 0.0 } else { v };
        format!("{v:+.2}")
    } else {
        "--".to_string()
    }
}

/// What the bus wrapper saw: whether any write was acknowledged, and the last error.
#[derive(Debug, Default)]
struct BusLog {
    acknowledged: bool,
    last_error: Option<ErrorKind>,
}

/// Passes every call to the bus and records the outcome, so that errors (which the
/// display-interface layer flattens to "bus write error") can name what went wrong.
struct Tracked<I2C> {
    inner: I2C,
    log: Arc<Mutex<BusLog>>,
}

impl<I2C: I2c> Tracked<I2C> {
    fn note<T>(&self, r: Result<T, I2C::Error>) -> Result<T, I2C::Error> {
        let mut log = self.log.lock().unwrap_or_else(|e| e.into_inner());
        match &r {
            Ok(_) => log.acknowledged = true,
            Err(e) => log.last_error = Some(e.kind()),
        }
        r
    }
}

impl<I2C: I2c> embedded_hal::i2c::ErrorType for Tracked<I2C> {
    type Error = I2C::Error;
}

impl<I2C: I2c> I2c for Tracked<I2C> {
    fn read(&mut self, address: u8, read: &mut [u8]) -> Result<(), Self::Error> {
        let r = self.inner.read(address, read);
        self.note(r)
    }
    fn write(&mut self, address: u8, write: &[u8]) -> Result<(), Self::Error> {
        let r = self.inner.write(address, write);
        self.note(r)
    }
    fn write_read(
        &mut self,
        address: u8,
        write: &[u8],
        read: &mut [u8],
    ) -> Result<(), Self::Error> {
        let r = self.inner.write_read(address, write, read);
        self.note(r)
    }
    fn transaction(
        &mut self,
        address: u8,
        operations: &mut [Operation<'_>],
    ) -> Result<(), Self::Error> {
        let r = self.inner.transaction(address, operations);
        self.note(r)
    }
}

type Panel<I2C> =
    Ssd1306<I2CInterface<Tracked<I2C>>, DisplaySize128x32, BufferedGraphicsMode<DisplaySize128x32>>;

/// An SSD1306 128x32 on an embedded-hal I2C bus.
pub struct Oled<I2C: I2c> {
    /// `None` only while [`Oled::destroy`] takes the bus back.
    panel: Option<Panel<I2C>>,
    log: Arc<Mutex<BusLog>>,
    address: u8,
    bus_name: String,
    initialised: bool,
    /// The lines on the panel now; `None` = unknown (never drawn, cleared, or a write failed).
    shown: Option<[String; LINES]>,
}

impl<I2C: I2c> Oled<I2C> {
    /// Takes the bus; nothing is sent until [`Oled::init`]. `address` is 0x3C on the JetBot
    /// ([`DEFAULT_ADDRESS`]); 0x3D on some modules.
    pub fn new(i2c: I2C, address: u8) -> Self {
        let log = Arc::new(Mutex::new(BusLog::default()));
        let tracked = Tracked {
            inner: i2c,
            log: log.clone(),
        };
        let panel = Ssd1306::new(
            I2CDisplayInterface::new_custom_address(tracked, address),
            DisplaySize128x32,
            DisplayRotation::Rotate0,
        )
        .into_buffered_graphics_mode();
        Self {
            panel: Some(panel),
            log,
            address,
            bus_name: "/dev/i2c-1".to_string(),
            initialised: false,
            shown: None,
        }
    }

    /// The bus name used in messages (default `/dev/i2c-1`, the JetBot's).
    pub fn with_bus_name(mut self, name: impl Into<String>) -> Self {
        self.bus_name = name.into();
        self
    }

    pub fn address(&self) -> u8 {
        self.address
    }

    /// Sends the SSD1306 init sequence for a 128x32 panel (display off, clock, multiplex 31,
    /// offset, start line, charge pump, horizontal addressing, COM pins sequential,
    /// segment remap, COM scan reversed, precharge, contrast, VCOMH, resume, no invert, no
    /// scroll, display on) and blanks the panel. A display that does not acknowledge the
    /// first command is [`DisplayError::NotFound`]: a warning for the caller, not a fault.
    pub fn init(&mut self) -> Result<(), DisplayError> {
        let Some(panel) = self.panel.as_mut() else {
            return Err(DisplayError::NotInitialised);
        };
        let r = panel.init();
        self.initialised = r.is_ok();
        r.map_err(|_| self.error())?;
        self.shown = None;
        self.draw(&Default::default())
    }

    /// Turns the panel off (best effort, when it was initialised) and hands the bus back.
    pub fn destroy(mut self) -> Option<I2C> {
        let mut panel = self.panel.take()?;
        if self.initialised
            && let Err(e) = panel.set_display_on(false)
        {
            tracing::debug!(error = ?e, "could not turn the OLED off before giving the bus back");
        }
        Some(panel.release().release().inner)
    }

    /// Draws `lines` and sends the frame.
    fn draw(&mut self, lines: &[String; LINES]) -> Result<(), DisplayError> {
        let panel = match self.panel.as_mut() {
            Some(p) if self.initialised => p,
            _ => return Err(DisplayError::NotInitialised),
        };
        panel.clear_buffer();
        let style = MonoTextStyle::new(&FONT_5X8, BinaryColor::On);
        for (row, line) in lines.iter().enumerate() {
            // Drawing into the frame buffer cannot fail; the bus is only used by flush().
            let _ = Text::with_baseline(line, Point::new(0, 8 * row as i32), style, Baseline::Top)
                .draw(panel);
        }
        self.shown = None;
        panel.flush().map_err(|_| self.error())?;
        self.shown = Some(lines.clone());
        Ok(())
    }

    /// The error for a failed display operation, from what the bus wrapper recorded.
    fn error(&self) -> DisplayError {
        let log = self.log.lock().unwrap_or_else(|e| e.into_inner());
        let detail = match log.last_error {
            Some(ErrorKind::NoAcknowledge(_)) => "no acknowledge",
            Some(ErrorKind::Bus) => "bus error",
            Some(ErrorKind::ArbitrationLoss) => "arbitration lost",
            Some(ErrorKind::Overrun) => "overrun",
            // linux-embedded-hal reports EREMOTEIO (Tegra's "nothing answered") as Other.
            Some(_) => "I/O error",
            None => "write failed",
        }
        .to_string();
        if log.acknowledged {
            DisplayError::Bus {
                address: self.address,
                bus: self.bus_name.clone(),
                detail,
            }
        } else {
            DisplayError::NotFound {
                address: self.address,
                bus: self.bus_name.clone(),
                detail,
            }
        }
    }
}

impl<I2C: I2c + Send> StatusDisplay for Oled<I2C> {
    fn show(&mut self, status: &Status) -> Result<(), DisplayError> {
        if !self.initialised {
            return Err(DisplayError::NotInitialised);
        }
        let lines = layout(status);
        if self.shown.as_ref() == Some(&lines) {
            return Ok(());
        }
        self.draw(&lines)
    }

    fn clear(&mut self) -> Result<(), DisplayError> {
        self.draw(&Default::default())
    }
}

/// The robot's IPv4 address to show: the address on the default route's interface, else
/// the first on a Wi-Fi, then Ethernet, then any other interface (USB device-mode bridges
/// such as the Jetson's `l4tbr0`, then Docker bridges, last); never loopback. Read from
/// `ip -4 -o addr`, or from `/proc/net/fib_trie` + `/proc/net/route` when `ip` cannot run.
/// Spawns a process: call it every few seconds, not from the control loop.
pub fn primary_ip() -> Option<String> {
    let route = std::fs::read_to_string("/proc/net/route").unwrap_or_default();
    let default_iface = default_route_iface(&route);
    let addrs = match std::process::Command::new("ip")
        .args(["-4", "-o", "addr", "show"])
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
    {
        Ok(out) if out.status.success() => parse_ip_addr(&String::from_utf8_lossy(&out.stdout)),
        _ => {
            let trie = std::fs::read_to_string("/proc/net/fib_trie").unwrap_or_default();
            addrs_from_proc(&trie, &route)
        }
    };
    pick_primary(&addrs, default_iface.as_deref()).map(|a| a.to_string())
}

/// `(interface, address)` pairs from `ip -4 -o addr show` output, in order.
pub fn parse_ip_addr(output: &str) -> Vec<(String, Ipv4Addr)> {
    output
        .lines()
        .filter_map(|line| {
            let mut tokens = line.split_whitespace();
            let _index = tokens.next()?;
            let iface = tokens.next()?.split('@').next()?.trim_end_matches(':');
            let mut tokens = tokens.skip_while(|t| *t != "inet");
            tokens.next()?;
            let addr = tokens.next()?.split('/').next()?.parse().ok()?;
            Some((iface.to_string(), addr))
        })
        .collect()
}

/// One line of `/proc/net/route`.
#[derive(Debug, Clone, PartialEq)]
struct Route {
    iface: String,
    dest: Ipv4Addr,
    mask: Ipv4Addr,
    up: bool,
    metric: u32,
}

/// `/proc/net/route` prints each address as the hex of its in-memory (network order) u32,
/// read in host order: native-endian bytes give the address back.
fn proc_hex_addr(hex: &str) -> Option<Ipv4Addr> {
    u32::from_str_radix(hex, 16)
        .ok()
        .map(|v| Ipv4Addr::from(v.to_ne_bytes()))
}

fn parse_routes(route: &str) -> Vec<Route> {
    route
        .lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() < 8 {
                return None;
            }
            Some(Route {
                iface: f[0].to_string(),
                dest: proc_hex_addr(f[1])?,
                up: u32::from_str_radix(f[3], 16).ok()? & 0x1 != 0,
                metric: f[6].parse().ok()?,
                mask: proc_hex_addr(f[7])?,
            })
        })
        .collect()
}

/// The interface of the default route (lowest metric) in `/proc/net/route` text.
pub fn default_route_iface(route: &str) -> Option<String> {
    parse_routes(route)
        .into_iter()
        .filter(|r| r.up && r.dest.is_unspecified() && r.mask.is_unspecified())
        .min_by_key(|r| r.metric)
        .map(|r| r.iface)
}

/// The local addresses in `/proc/net/fib_trie` (`|-- a.b.c.d` followed by `/32 host
/// LOCAL`), each with the interface of the first non-default route whose subnet holds it.
pub fn addrs_from_proc(fib_trie: &str, route: &str) -> Vec<(String, Ipv4Addr)> {
    let routes = parse_routes(route);
    let mut out: Vec<(String, Ipv4Addr)> = Vec::new();
    let mut candidate: Option<Ipv4Addr> = None;
    for line in fib_trie.lines() {
        let t = line.trim();
        if let Some(a) = t.strip_prefix("|-- ") {
            candidate = a.trim().parse().ok();
        } else if t.starts_with("/32 host LOCAL") {
            if let Some(a) = candidate.take()
                && !out.iter().any(|(_, b)| *b == a)
            {
                let iface = routes
                    .iter()
                    .filter(|r| !r.mask.is_unspecified())
                    .find(|r| u32::from(a) & u32::from(r.mask) == u32::from(r.dest))
                    .map(|r| r.iface.clone())
                    .unwrap_or_else(|| if a.is_loopback() { "lo" } else { "?" }.to_string());
                out.push((iface, a));
            }
        } else if !t.starts_with('/') {
            candidate = None;
        }
    }
    out
}

/// The address to show among `addrs`; see [`primary_ip`] for the order.
pub fn pick_primary(addrs: &[(String, Ipv4Addr)], default_iface: Option<&str>) -> Option<Ipv4Addr> {
    let rank = |iface: &str| -> u8 {
        if Some(iface) == default_iface {
            0
        } else if iface.starts_with("wl") {
            1
        } else if iface.starts_with("eth") || iface.starts_with("en") {
            2
        } else if ["docker", "br-", "veth", "virbr"]
            .iter()
            .any(|p| iface.starts_with(p))
        {
            5
        } else if iface == "l4tbr0" || iface.starts_with("usb") || iface.starts_with("rndis") {
            4
        } else {
            3
        }
    };
    addrs
        .iter()
        .filter(|(iface, a)| !a.is_loopback() && !a.is_unspecified() && iface != "lo")
        .min_by_key(|(iface, _)| rank(iface))
        .map(|(_, a)| *a)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> Status {
        Status {
            mode: "auto".into(),
            fps: 29.84,
            speed: 0.25,
            steering: -0.1,
            interventions: 3,
            autonomy_percent: 97.0,
            ip: Some("192.168.1.23".into()),
        }
    }

    #[test]
    fn layout_worked_example() {
        assert_eq!(
            layout(&status()),
            [
                "auto           29.8 fps",
                "spd +0.25  str -0.10",
                "int 3   auto 97.0%",
                "ip 192.168.1.23",
            ]
        );
    }

    #[test]
    fn layout_fits_the_panel_whatever_the_values() {
        let wide = Status {
            mode: "a-very-long-mode-name-that-goes-on".into(),
            fps: 12345.678,
            speed: -123.456,
            steering: 99999.0,
            interventions: u32::MAX,
            autonomy_percent: -71569.9,
            ip: Some("255.255.255.255".into()),
        };
        for s in [wide, Status::default(), status()] {
            for line in layout(&s) {
                assert!(
                    line.len() <= LINE_CHARS,
                    "{line:?} is longer than {LINE_CHARS}"
                );
                assert!(line.is_ascii());
            }
        }
        let l = layout(&Status {
            mode: "a-very-long-mode-name".into(),
            ..status()
        });
        assert_eq!(l[0], "a-very-long-m  29.8 fps");
    }

    #[test]
    fn layout_of_missing_and_odd_values() {
        let s = Status {
            mode: "  ".into(),
            fps: f32::NAN,
            speed: -0.001,
            steering: f32::INFINITY,
            interventions: 0,
            autonomy_percent: 100.0,
            ip: None,
        };
        assert_eq!(
            layout(&s),
            [
                "-                -- fps",
                "spd +0.00  str --",
                "int 0   auto 100.0%",
                "ip -- (no network)",
            ]
        );
        let l = layout(&Status {
            mode: "manuel→auto".into(),
            ..status()
        });
        assert!(l[0].starts_with("manuel?auto "));
    }

    const IP_ADDR: &str = "\
1: lo    inet 127.0.0.1/8 scope host lo\\       valid_lft forever preferred_lft forever
3: docker0    inet 172.17.0.1/16 brd 172.17.255.255 scope global docker0\\       valid_lft forever preferred_lft forever
5: l4tbr0    inet 192.168.55.1/24 brd 192.168.55.255 scope global l4tbr0\\       valid_lft forever preferred_lft forever
7: eth0@if8    inet 10.0.0.5/24 brd 10.0.0.255 scope global eth0\\       valid_lft forever preferred_lft forever
9: wlan0    inet 192.168.1.23/24 brd 192.168.1.255 scope global dynamic noprefixroute wlan0\\       valid_lft 86313sec preferred_lft 86313sec
";

    #[test]
    fn parses_ip_addr_output() {
        let a = parse_ip_addr(IP_ADDR);
        assert_eq!(a.len(), 5);
        assert_eq!(a[0], ("lo".to_string(), Ipv4Addr::new(127, 0, 0, 1)));
        assert_eq!(a[3], ("eth0".to_string(), Ipv4Addr::new(10, 0, 0, 5)));
        assert_eq!(a[4], ("wlan0".to_string(), Ipv4Addr::new(192, 168, 1, 23)));
        assert!(parse_ip_addr("garbage\n\n2: x inet nope/3").is_empty());
    }

    fn hex(a: Ipv4Addr) -> String {
        format!("{:08X}", u32::from_ne_bytes(a.octets()))
    }

    fn route_text(rows: &[(&str, Ipv4Addr, Ipv4Addr, u32)]) -> String {
        let mut s =
            "Iface\tDestination\tGateway \tFlags\tRefCnt\tUse\tMetric\tMask\t\tMTU\tWindow\tIRTT\n"
                .to_string();
        for (iface, dest, mask, metric) in rows {
            s += &format!(
                "{iface}\t{}\t00000000\t0001\t0\t0\t{metric}\t{}\t0\t0\t0\n",
                hex(*dest),
                hex(*mask)
            );
        }
        s
    }

    #[test]
    fn default_route_and_primary_address() {
        let any = Ipv4Addr::UNSPECIFIED;
        let route = route_text(&[
            ("eth0", any, any, 100),
            ("wlan0", any, any, 600),
            (
                "wlan0",
                Ipv4Addr::new(192, 168, 1, 0),
                Ipv4Addr::new(255, 255, 255, 0),
                600,
            ),
        ]);
        assert_eq!(default_route_iface(&route).as_deref(), Some("eth0"));
        let addrs = parse_ip_addr(IP_ADDR);
        assert_eq!(
            pick_primary(&addrs, Some("eth0")),
            Some(Ipv4Addr::new(10, 0, 0, 5))
        );
        // No default route: Wi-Fi first, Docker and the USB bridge last.
        assert_eq!(
            pick_primary(&addrs, None),
            Some(Ipv4Addr::new(192, 168, 1, 23))
        );
        assert_eq!(
            pick_primary(&addrs[..3], None),
            Some(Ipv4Addr::new(192, 168, 55, 1))
        );
        assert_eq!(pick_primary(&addrs[..1], None), None);
        assert_eq!(default_route_iface(""), None);
    }

    #[test]
    fn addresses_from_proc_when_ip_is_missing() {
        let trie = "\
Main:
  +-- 0.0.0.0/0 3 0 5
     |-- 0.0.0.0
        /0 universe UNICAST
     +-- 127.0.0.0/8 2 0 2
        |-- 127.0.0.1
           /32 host LOCAL
     |-- 192.168.1.0
        /24 link UNICAST
     |-- 192.168.1.23
        /32 host LOCAL
Local:
  +-- 0.0.0.0/0 3 0 5
     |-- 192.168.1.23
        /32 host LOCAL
     |-- 192.168.1.255
        /32 link BROADCAST
";
        let any = Ipv4Addr::UNSPECIFIED;
        let route = route_text(&[
            ("wlan0", any, any, 600),
            (
                "wlan0",
                Ipv4Addr::new(192, 168, 1, 0),
                Ipv4Addr::new(255, 255, 255, 0),
                600,
            ),
        ]);
        let a = addrs_from_proc(trie, &route);
        assert_eq!(
            a,
            vec![
                ("lo".to_string(), Ipv4Addr::new(127, 0, 0, 1)),
                ("wlan0".to_string(), Ipv4Addr::new(192, 168, 1, 23)),
            ]
        );
        assert_eq!(
            pick_primary(&a, default_route_iface(&route).as_deref()),
            Some(Ipv4Addr::new(192, 168, 1, 23))
        );
    }

    #[test]
    fn primary_ip_on_this_machine_is_not_loopback() {
        if let Some(ip) = primary_ip() {
            let a: Ipv4Addr = ip.parse().expect("an IPv4 address");
            assert!(!a.is_loopback());
        }
    }
}

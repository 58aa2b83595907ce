//! The status panel: a thread that shows the daemon's [`DaemonStatus`] on the OLED at 2 Hz
//! and beeps on mode changes, off the control path (its I2C writes and GPIO toggles never
//! delay a motor command). A display or buzzer that cannot be opened is a warning.

use std::sync::Arc;
use std::time::Duration;

use jetpilot::clock::Clock;
use jetpilot::config::Config;
use jetpilot::drive::DaemonStatus;
use jetpilot::hw::buzzer::{self, BeepPattern, Buzzer, NoBuzzer};
use jetpilot::hw::oled::{NoDisplay, Status, StatusDisplay, primary_ip};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

fn open_display(cfg: &Config) -> Box<dyn StatusDisplay> {
    if !cfg.oled.enabled {
        return Box::new(NoDisplay);
    }
    #[cfg(feature = "linux-hal")]
    {
        match jetpilot::hw::bus::open_linux(cfg.oled.i2c_bus) {
            Ok(bus) => {
                let mut oled = jetpilot::hw::oled::Oled::new(bus, cfg.oled.address)
                    .with_bus_name(format!("/dev/i2c-{}", cfg.oled.i2c_bus));
                match oled.init() {
                    Ok(()) => return Box::new(oled),
                    Err(e) => tracing::warn!(error = %e, "OLED: going on without it"),
                }
            }
            Err(e) => tracing::warn!(error = %e, "OLED: going on without it"),
        }
    }
    Box::new(NoDisplay)
}

/// Starts the panel thread; it ends when `cancel` fires, blanking the display.
pub fn spawn(
    cfg: &Config,
    clock: Arc<dyn Clock>,
    mut status: watch::Receiver<DaemonStatus>,
    cancel: CancellationToken,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let mut display = open_display(cfg);
    let mut beeper: Box<dyn Buzzer> = match buzzer::open(&cfg.buzzer, clock) {
        Ok(b) => b,
        Err(e) => {
            tracing::warn!(error = %e, "buzzer: going on without it");
            Box::new(NoBuzzer)
        }
    };
    std::thread::Builder::new()
        .name("panel".into())
        .spawn(move || {
            let ip = primary_ip();
            let mut last: Option<DaemonStatus> = None;
            let mut ticks = 0u32;
            beeper.beep(BeepPattern::Long);
            while !cancel.is_cancelled() {
                // Poll the buzzer every 20 ms; refresh the display every 500 ms.
                std::thread::sleep(Duration::from_millis(20));
                beeper.poll();
                ticks += 1;
                if ticks % 25 != 0 {
                    continue;
                }
                let now = status.borrow_and_update().clone();
                if let Some(prev) = &last
                    && prev.mode != now.mode
                {
                    beeper.beep(if now.mode == "stopped" {
                        BeepPattern::Alarm
                    } else {
                        BeepPattern::Short
                    });
                }
                let fps = match &last {
                    Some(p) if now.elapsed_s > p.elapsed_s => {
                        (now.commands_written - p.commands_written) as f32
                            / (now.elapsed_s - p.elapsed_s)
                    }
                    _ => 0.0,
                };
                let shown = Status {
                    mode: now.mode.clone(),
                    fps,
                    speed: (now.last.left + now.last.right) / 2.0,
                    steering: (now.last.left - now.last.right) / 2.0,
                    interventions: now.interventions as u32,
                    autonomy_percent: jetpilot::sim::reward::autonomy(
                        now.interventions as u32,
                        now.elapsed_s.max(1.0),
                    ),
                    ip: ip.clone(),
                };
                if let Err(e) = display.show(&shown) {
                    tracing::debug!(error = %e, "OLED update failed");
                }
                last = Some(now);
            }
            beeper.silence();
            let _ = display.clear();
        })
}

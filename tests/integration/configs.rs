//! The shipped configs load, validate, and describe the boards they are named after.

use std::path::Path;

use jetpilot::config::{Config, MotorBackend};
use jetpilot::hw::HatLayout;

fn load(name: &str) -> Config {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(name);
    Config::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn jetbot_is_the_adafruit_hat_with_inverted_motors() {
    let hat = load("jetbot.toml").motors.hat_settings();
    assert_eq!(
        (hat.layout, hat.address, hat.pwm_hz),
        (HatLayout::Adafruit, 0x60, 1600.0)
    );
    assert!(hat.left.invert && hat.right.invert);
}

#[test]
fn waveshare_and_yahboom_layouts() {
    let ws = load("waveshare.toml").motors.hat_settings();
    assert_eq!((ws.layout, ws.address), (HatLayout::Waveshare, 0x60));
    let yb = load("yahboom.toml").motors.hat_settings();
    assert_eq!((yb.layout, yb.address), (HatLayout::Yahboom, 0x40));
}

#[test]
fn l298n_nano_drives_both_motors_through_gpio_lines_and_hardware_pwm() {
    let cfg = load("l298n-nano.toml");
    assert_eq!(cfg.motors.backend, MotorBackend::Gpio);
    let g = cfg.motors.gpio.as_ref().unwrap();
    assert_eq!(g.chip, jetpilot::hw::hbridge::BridgeChip::L298n);
    assert_eq!(
        g.summary(),
        "l298n H-bridge on /dev/gpiochip0 and /sys/class/pwm: left IN1 line 76, IN2 line 51, \
         PWM pwmchip0/pwm0; right IN1 line 12, IN2 line 77, PWM pwmchip0/pwm2; 1000 Hz, stop = coast"
    );
    // An H-bridge kit's motors are not inverted unless the config says so.
    let (l, r) = cfg.motors.trims();
    assert!(!l.invert && !r.invert);
}

#[test]
fn a_gpio_backend_without_its_pins_is_refused_naming_the_key() {
    let err = Config::parse("[motors]\nbackend = \"gpio\"\n", "kit.toml").unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("kit.toml") && msg.contains("motors.gpio"),
        "{msg}"
    );
    let err = Config::parse(
        "[motors]\nbackend = \"gpio\"\n[motors.gpio]\nchip = \"tb6612fng\"\n\
         [motors.gpio.left]\nin1 = 1\nin2 = 2\npwm = { chip = 0, channel = 0 }\n",
        "kit.toml",
    )
    .unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("motors.gpio.right.in1"), "{msg}");
}

#[test]
fn demo_runs_on_bundled_frames_with_virtual_motors() {
    let cfg = load("demo.toml");
    assert_eq!(cfg.motors.backend, MotorBackend::Log);
    let frames = jetpilot::camera::folder::list_images(&cfg.camera.path).unwrap();
    assert!(frames.len() >= 16, "{} frames", frames.len());
}

#[test]
fn robot_configs_read_the_csi_camera_and_keep_state_in_var_lib() {
    for name in ["jetbot.toml", "waveshare.toml", "yahboom.toml"] {
        let cfg = load(name);
        assert_eq!(
            cfg.camera.source,
            jetpilot::config::CameraSource::Pipe,
            "{name}"
        );
        assert!(cfg.camera.command.contains("nvarguscamerasrc"), "{name}");
        assert!(cfg.record.path.starts_with("/var/lib/jetpilot"), "{name}");
        assert!(cfg.model.path.starts_with("/var/lib/jetpilot"), "{name}");
        assert!(cfg.oled.enabled, "{name}");
    }
    assert!(load("yahboom.toml").buzzer.enabled);
}

/// Every shipped track loads, closes and stays on the mat, both ways round; the experiment's
/// tracks differ from the mat the demonstrations were recorded on.
#[test]
fn shipped_tracks_load_both_ways_round() {
    use jetpilot::sim::track::Track;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/tracks");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let track = Track::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let back = track.reversed();
        assert!((back.length() - track.length()).abs() < 1e-4);
        assert!(
            track.length() > 4.0,
            "{}: {}",
            path.display(),
            track.length()
        );
        names.push(track.name().to_string());
    }
    names.sort();
    assert_eq!(
        names,
        [
            "jetbot_mat",
            "narrow",
            "narrow_print",
            "s_bends",
            "sharp_corners"
        ]
    );
}

#[test]
fn the_sim_config_sees_through_jetbots_camera() {
    // The shipped simulator config spells out the default camera: JetBot's fisheye.
    let cam = load("sim.toml").sim.camera;
    assert_eq!(cam, jetpilot::sim::camera::CameraModel::jetbot(224, 224));
    assert_eq!(cam, jetpilot::sim::camera::CameraModel::default());
}

#[test]
fn the_donkeycar_config_spells_out_the_car_its_camera_and_the_chassis_mask() {
    // `poses --config config/donkeycar.toml` means what `poses` does for a car without one.
    let sim = load("donkeycar.toml").sim;
    assert_eq!(
        sim.camera,
        jetpilot::sim::camera::CameraModel::donkeycar(160, 120)
    );
    assert_eq!(
        sim.car,
        jetpilot::sim::odometry::ackermann::CarParams::default()
    );
    let chassis = sim.chassis;
    assert_eq!(chassis.find, Some(true));
    assert_eq!(
        jetpilot::sim::odometry::mask::ChassisConfig {
            find: None,
            ..chassis
        },
        jetpilot::sim::odometry::mask::ChassisConfig::default()
    );
}

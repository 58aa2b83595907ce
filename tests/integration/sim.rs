//! The simulator closed loop: the scripted expert's commands, sent through the daemon's
//! motor driver and the virtual PCA9685, keep the car on the track for 10 laps; leaving the
//! road is counted as interventions with the paper's accounting; a simulated run with a
//! real model is deterministic for a seed; `jetpilot eval` reports the protocol's numbers.

use crate::common;

use std::process::Command;

use jetpilot::config::Config;
use jetpilot::control::WheelCommand;
use jetpilot::drive::DriveParams;
use jetpilot::drive::stages::FrameProcessor;
use jetpilot::hw::MotorOutput;
use jetpilot::policy::Policy;
use jetpilot::sim::closed_loop::{self, Pilot};
use jetpilot::sim::reward::autonomy;
use jetpilot::sim::setup;

/// The "N commands written" count from `sim --realtime`'s summary (0 when absent).
fn commands_written(summary: &str) -> u32 {
    summary
        .split(" commands written")
        .next()
        .and_then(|s| s.rsplit(", ").next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(0)
}

/// A config with a small camera, so debug-build tests render quickly.
fn small_config(extra: &str) -> Config {
    Config::parse(
        &format!(
            "[control]\nspeed_gain = 0.25\nsteering_gain = 0.5\n{extra}\n\
             [sim.camera]\nwidth = 48\nheight = 48\n"
        ),
        "test.toml",
    )
    .unwrap()
}

#[test]
fn the_expert_drives_ten_laps_without_an_intervention() {
    let cfg = small_config("");
    let mut rig = setup::build(&cfg).unwrap();
    let mut pilot = Pilot::expert(cfg.sim.expert, 0);
    let lap_s = rig.world.track.length() as f64 / cfg.sim.expert.speed_mps as f64;
    let mut min_edge = f32::MAX;
    closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(lap_s * 11.5, &cfg),
        (48, 48),
        |s| min_edge = min_edge.min(s.score.edge_distance_m),
    )
    .unwrap();
    let stats = &rig.world.stats;
    assert!(rig.world.laps() >= 10.0, "{} laps", rig.world.laps());
    assert_eq!(stats.interventions, 0);
    assert!(
        min_edge > 0.0,
        "stayed inside its lane: closest {min_edge} m"
    );
    // The wheels only moved because the driver's register writes reached the virtual HAT.
    assert!(rig.hat.transactions() > 1000);
    assert_eq!(
        rig.hat.wheel_duties(cfg.motors.layout, true, true),
        (0.0, 0.0)
    );
}

/// Always the same wheel command: a car that cannot steer.
struct Straight;
impl Policy for Straight {
    fn contract(&self) -> &jetpilot::policy::ModelContract {
        static C: std::sync::OnceLock<jetpilot::policy::ModelContract> = std::sync::OnceLock::new();
        C.get_or_init(|| jetpilot::policy::ModelContract {
            input_size: 32,
            ..Default::default()
        })
    }
    fn infer(&mut self, _input: &[f32]) -> Result<[f32; 2], jetpilot::policy::PolicyError> {
        Ok([0.0, 0.5]) // target straight ahead: equal wheels
    }
    fn describe(&self) -> String {
        "straight".into()
    }
}

/// A DIY car without a motor HAT: config/l298n-nano.toml's L298N, driven through the
/// daemon's H-bridge driver on the simulator's virtual GPIO lines and PWM channels, drives
/// the same laps as the HAT car.
#[test]
fn an_l298n_car_drives_through_its_virtual_h_bridge() {
    let small = small_config("");
    let mut cfg = Config::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/l298n-nano.toml"),
    )
    .unwrap();
    cfg.sim = small.sim.clone();
    cfg.control = small.control.clone();
    let laps = |cfg: &Config| {
        let mut rig = setup::build(cfg).unwrap();
        let mut pilot = Pilot::expert(cfg.sim.expert, 0);
        let lap_s = rig.world.track.length() as f64 / cfg.sim.expert.speed_mps as f64;
        closed_loop::run(
            &mut rig.world,
            &mut rig.motors,
            &mut pilot,
            &cfg.sim.loop_settings(lap_s * 3.0, cfg),
            (48, 48),
            |_| {},
        )
        .unwrap();
        assert_eq!(rig.world.stats.interventions, 0);
        (
            rig.world.laps(),
            rig.hat.transactions(),
            rig.motors.describe(),
        )
    };
    let (bridge_laps, hat_writes, describe) = laps(&cfg);
    assert!(describe.contains("l298n H-bridge"), "{describe}");
    assert_eq!(hat_writes, 0, "the virtual HAT is not what moved it");
    let (hat_laps, _, _) = laps(&small);
    assert!(
        bridge_laps > 2.0 && (bridge_laps - hat_laps).abs() < 0.05 * hat_laps,
        "H-bridge {bridge_laps} laps, HAT {hat_laps}"
    );

    // The real daemon (threads, actuator, watchdog) driving the virtual L298N in real time.
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 4);
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/l298n-nano.toml"),
    )
    .unwrap()
    .replace("\"/var/lib/jetpilot/model.onnx\"", &format!("{model:?}"));
    let path = dir.path().join("l298n.toml");
    std::fs::write(&path, text + "\n[sim.camera]\nwidth = 48\nheight = 48\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "sim", "--realtime", "--seconds", "2", "--config"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(commands_written(&text) >= 30, "{text}");
}

#[test]
fn leaving_the_road_counts_interventions_and_recentres() {
    let cfg = small_config("");
    let mut rig = setup::build(&cfg).unwrap();
    let params = DriveParams::from_config(&cfg);
    let mut policy = Straight;
    let processor = FrameProcessor::new(policy.contract(), params.gains, 10.0);
    let mut pilot = Pilot::Model {
        policy: &mut policy,
        processor: Box::new(processor),
    };
    let mut seen = 0u32;
    closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(60.0, &cfg),
        (48, 48),
        |s| {
            if s.score.intervention {
                seen += 1;
                assert_eq!(s.score.reward, 0.0);
            }
        },
    )
    .unwrap();
    let n = rig.world.stats.interventions;
    assert!(n >= 3, "a car that cannot steer leaves the road: {n}");
    assert_eq!(n, seen);
    assert_eq!(rig.world.stats.causes.off_road, n);
    assert_eq!(rig.world.stats.intervention_poses.len(), n as usize);
    // After each, it is put back on the road, so it keeps driving (and leaving).
    assert!(
        rig.world
            .track
            .on_road(rig.world.pose().x, rig.world.pose().y)
    );
    let a = autonomy(n, 60.0);
    assert!((a - (1.0 - n as f32 * 6.0 / 60.0) * 100.0).abs() < 1e-4);
    // The paper's pure-RL figure, with this accounting:
    assert!((autonomy(95, 600.0) - 5.0).abs() < 1e-4);
}

#[test]
fn a_simulated_run_is_deterministic_for_a_seed() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 5);
    let run = |seed: u64| {
        let cfg = small_config(&format!(
            "[sim]\nframes = \"replay\"\nseed = {seed}\n[sim.robot]\nspeed_noise = 0.05\n"
        ));
        let mut rig = setup::build(&cfg).unwrap();
        let mut policy = jetpilot::drive::setup::load_policy(&cfg, Some(&model)).unwrap();
        let params = DriveParams::from_config(&cfg);
        let processor = FrameProcessor::new(&policy.contract().clone(), params.gains, 10.0);
        let mut pilot = Pilot::Model {
            policy: &mut policy,
            processor: Box::new(processor),
        };
        let mut log = String::new();
        closed_loop::run(
            &mut rig.world,
            &mut rig.motors,
            &mut pilot,
            &cfg.sim.loop_settings(10.0, &cfg),
            (48, 48),
            |s| {
                log.push_str(&format!(
                    "{} {:?} {:?} {:?} {:?}\n",
                    s.seq, s.pose, s.wheels, s.outputs, s.score
                ))
            },
        )
        .unwrap();
        log
    };
    let a = run(1);
    assert_eq!(a, run(1), "same seed, same log byte for byte");
    assert_ne!(a, run(2), "the seed matters (wheel-speed noise)");
}

#[test]
fn a_motor_fault_in_the_loop_stops_and_reports() {
    let cfg = small_config("");
    let mut rig = setup::build(&cfg).unwrap();
    let mut pilot = Pilot::expert(cfg.sim.expert, 0);
    rig.hat.fail_next(1000);
    let err = closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(5.0, &cfg),
        (48, 48),
        |_| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("motors failed"), "{err}");
    rig.hat.fail_next(0);
    rig.motors.drive(WheelCommand::new(0.5, 0.5)).unwrap();
    rig.motors.stop().unwrap();
    assert_eq!(
        rig.hat.wheel_duties(cfg.motors.layout, true, true),
        (0.0, 0.0)
    );
}

#[test]
fn eval_reports_the_protocol_numbers_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 2);
    let cfg = dir.path().join("sim.toml");
    std::fs::write(
        &cfg,
        format!("[model]\npath = {model:?}\n[sim.camera]\nwidth = 48\nheight = 48\n"),
    )
    .unwrap();
    let json = dir.path().join("eval.json");
    let png = dir.path().join("trace.png");
    let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "eval", "--seconds", "20", "--config"])
        .arg(&cfg)
        .arg("--json")
        .arg(&json)
        .arg("--png")
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("autonomy"), "{text}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["control_steps"], 600);
    let n = v["interventions"].as_u64().unwrap() as f64;
    let a = v["autonomy_percent"].as_f64().unwrap();
    assert!((a - (1.0 - n * 6.0 / 20.0) * 100.0).abs() < 1e-3, "{v}");
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
}

/// `sim` and `eval` without --config use the built-in config/sim.toml: the same numbers
/// and the same scattered frames as with `--config config/sim.toml`; a drive that needs a
/// model is refused, naming --model, since the built-in config names none.
#[test]
fn without_a_config_sim_and_eval_use_the_built_in_sim_toml() {
    let dir = tempfile::tempdir().unwrap();
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim.toml");
    let jetpilot = |args: &[&str], config: bool| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
        c.arg("-q").args(args).current_dir(dir.path());
        if config {
            c.arg("--config").arg(&file);
        }
        c.output().unwrap()
    };
    // The expert's eval: every number but the wall-clock ones.
    let eval = |name: &str, config: bool| {
        let json = format!("{name}.json");
        let o = jetpilot(
            &["eval", "--expert", "--seconds", "3", "--json", &json],
            config,
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join(json)).unwrap()).unwrap();
        for wall in ["wall_seconds", "realtime_factor", "wall_share"] {
            v.as_object_mut().unwrap().remove(wall);
        }
        v
    };
    let built_in = eval("built_in", false);
    assert_eq!(built_in["control_steps"], 90);
    assert_eq!(built_in, eval("file", true));

    // Scattered frames: the same names and bytes.
    let scatter = |name: &str, config: bool| {
        let o = jetpilot(&["sim", "--scatter", "3", "--record-xy", name], config);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir.path().join(name))
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().to_string(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        files.sort();
        files
    };
    let frames = scatter("built_in", false);
    assert_eq!(frames.len(), 3);
    assert_eq!(frames, scatter("file", true));

    let o = jetpilot(&["sim", "--seconds", "1"], false);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("give --model FILE (or --expert)") && err.contains("built-in config/sim.toml"),
        "{err}"
    );
    // The real daemon cannot take --expert, so the refusal does not offer it.
    let o = jetpilot(&["sim", "--realtime", "--seconds", "1"], false);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("give --model FILE,") && !err.contains("--expert"),
        "{err}"
    );
    // A flag that needs another is named before the missing model.
    let o = jetpilot(&["sim", "--record-xy", "xy"], false);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--record-xy needs --record DIR"), "{err}");
}

#[test]
fn jetbot_camera_replays_and_draws_sim_beside_real_frames() {
    let dir = tempfile::tempdir().unwrap();
    let real = dir.path().join("real");
    std::fs::create_dir(&real).unwrap();
    for (name, rgb) in [
        ("xy_010_100_a.png", [230u8, 150, 200]),
        ("xy_200_100_c.png", [90, 90, 90]),
    ] {
        image::RgbImage::from_pixel(224, 224, image::Rgb(rgb))
            .save(real.join(name))
            .unwrap();
    }
    std::fs::write(real.join("xy_100_100_b.jpg"), b"").unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[sim.camera]\nwidth = 48\nheight = 48\n").unwrap();
    let png = dir.path().join("png");
    let jp = || Command::new(env!("CARGO_BIN_EXE_jetpilot"));
    let out = jp()
        .args([
            "-q",
            "sim",
            "--expert",
            "--seconds",
            "2",
            "--camera",
            "jetbot",
            "--config",
        ])
        .arg(&cfg)
        .arg("--png")
        .arg(&png)
        .arg("--real")
        .arg(&real)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("xy_100_100_b.jpg") && stderr.contains("empty"),
        "{stderr}"
    );
    let sheet = image::open(png.join("sim_vs_real.png")).unwrap().to_rgb8();
    // Eight 224 px tiles with 4 px gaps; sim on top, the two readable real frames below.
    assert_eq!(sheet.dimensions(), (8 * 228 + 4, 2 * 228 + 4));
    assert_eq!(
        sheet.get_pixel(4 + 100, 228 + 4 + 100),
        &image::Rgb([230, 150, 200])
    );
    assert_eq!(
        sheet.get_pixel(228 + 4 + 100, 228 + 4 + 100),
        &image::Rgb([90, 90, 90])
    );

    // Replayed-frame synthesis through the fisheye: the expert keeps the road.
    let replay = dir.path().join("replay.toml");
    std::fs::write(
        &replay,
        "[sim]\nframes = \"replay\"\n[sim.camera]\nwidth = 48\nheight = 48\n",
    )
    .unwrap();
    let json = dir.path().join("eval.json");
    let out = jp()
        .args([
            "-q",
            "eval",
            "--expert",
            "--seconds",
            "10",
            "--camera",
            "jetbot",
            "--config",
        ])
        .arg(&replay)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["interventions"], 0, "{v}");
}

#[test]
fn randomised_recordings_change_the_frames_and_repeat_for_a_seed() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[sim.camera]\nwidth = 48\nheight = 48\n").unwrap();
    let record = |name: &str, randomise: bool| {
        let tub = dir.path().join(name);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
        cmd.args(["-q", "sim", "--expert", "--seconds", "1", "--config"])
            .arg(&cfg)
            .arg("--record")
            .arg(&tub);
        if randomise {
            cmd.arg("--randomise");
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut images: Vec<_> = std::fs::read_dir(tub.join("images"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        images.sort();
        assert_eq!(images.len(), 30);
        images
            .iter()
            .map(|p| std::fs::read(p).unwrap())
            .collect::<Vec<_>>()
    };
    let plain = record("plain", false);
    let a = record("a", true);
    let b = record("b", true);
    assert_eq!(a, b, "the same seed must give the same randomised frames");
    let differing = plain.iter().zip(&a).filter(|(p, r)| p != r).count();
    assert_eq!(
        differing, 30,
        "every randomised frame differs from the plain one"
    );
}

#[test]
fn scene_randomisation_repaints_the_road_at_each_episode_and_repeats_for_a_seed() {
    // Looks off (no tint, noise, light), scenes on: what changes is the paint and the room.
    let cfg = small_config(
        "[sim.appearance]\nenabled = true\npink_probability = 0.0\ntint = 0.0\n\
         exposure = [1.0, 1.0]\ngamma = [1.0, 1.0]\nvignette = [0.0, 0.0]\n\
         noise_std = [0.0, 0.0]\nblur_probability = 0.0\nlight_gradient = [0.0, 0.0]\n\
         glare_probability = 0.0\nredraw_every_frames = 0\nclutter = [3, 3]\n\
         floor_objects = [0, 0]\nshadow_probability = 0.0\ncables = [0, 0]",
    );
    let episodes = |cfg: &Config| {
        let mut rig = setup::build(cfg).unwrap();
        let mut frames = Vec::new();
        let mut styles = Vec::new();
        for k in 0..12 {
            rig.world.reset_at(0.3 * k as f32);
            let mut rgb = vec![0u8; 48 * 48 * 3];
            rig.world.observe(&mut rgb);
            frames.push(rgb);
            styles.push(
                rig.world
                    .appearance()
                    .and_then(|a| a.scene())
                    .map(|s| s.style),
            );
        }
        (frames, styles)
    };
    let (a, styles) = episodes(&cfg);
    let (b, _) = episodes(&cfg);
    assert_eq!(a, b, "the same seed gives the same scenes");
    let mut plain_cfg = cfg.clone();
    plain_cfg.sim.appearance.enabled = false;
    let (plain, _) = episodes(&plain_cfg);
    for (k, (r, p)) in a.iter().zip(&plain).enumerate() {
        assert_ne!(
            r, p,
            "episode {k}: a repainted scene differs from the plain render"
        );
    }
    use jetpilot::sim::scene::RoadStyle;
    for style in [
        RoadStyle::Sim,
        RoadStyle::Print,
        RoadStyle::Tape,
        RoadStyle::Painted,
    ] {
        assert!(
            styles.contains(&Some(style)),
            "12 episodes show every style: {styles:?}"
        );
    }
    // A printed-mat episode: the road straight ahead at the bottom centre is near black.
    let k = styles
        .iter()
        .position(|s| *s == Some(RoadStyle::Print))
        .unwrap();
    let (u, v) = (20, 46);
    let px = &a[k][(v * 48 + u) * 3..][..3];
    assert!(
        px.iter().all(|&c| c < 80),
        "printed road at ({u}, {v}): {px:?}"
    );
}

#[test]
fn height_and_lens_ranges_move_the_camera_with_each_look() {
    // JetBot kits mount the camera 8-15 cm up, behind lenses of 160-200 degrees.
    let cfg = small_config(
        "[sim.appearance]\nenabled = true\nredraw_every_frames = 0\n\
         camera_height_m = [0.08, 0.15]\nlens_fov_scale = [0.9, 1.1]",
    );
    let base = cfg.sim.camera;
    let mut rig = setup::build(&cfg).unwrap();
    let mut rgb = vec![0u8; 48 * 48 * 3];
    let mut heights = Vec::new();
    for k in 0..6 {
        rig.world.reset_at(0.3 * k as f32);
        rig.world.observe(&mut rgb);
        let cam = rig.world.camera();
        let look = *rig.world.appearance().unwrap().look();
        assert_eq!(Some(cam.height_m), look.height_m, "episode {k}");
        let k_fov = look.fov_scale.unwrap();
        assert!((0.9..1.1).contains(&k_fov), "episode {k}: {k_fov}");
        assert!((cam.hfov_deg - base.hfov_deg * k_fov).abs() < 1e-4);
        assert!((cam.fisheye_fov_deg - base.fisheye_fov_deg * k_fov).abs() < 1e-4);
        assert_eq!(
            cam.tilt_deg, base.tilt_deg,
            "no tilt range: the configured tilt"
        );
        heights.push(cam.height_m);
    }
    assert!(
        heights.iter().all(|h| (0.08..0.15).contains(h)),
        "{heights:?}"
    );
    // Randomisation off: back to the configured camera.
    rig.world.set_appearance(None);
    assert_eq!(*rig.world.camera(), base);
}

#[test]
fn a_tilt_range_moves_the_camera_with_each_look_and_the_labels_go_through_it() {
    // JetBot's camera mount is bent by hand: with `camera_tilt_deg` each look draws a tilt,
    // the renderer moves its camera, and every step reports the camera it saw through.
    let cfg = small_config(
        "[sim.appearance]\nenabled = true\nredraw_every_frames = 30\n\
         camera_tilt_deg = [15.0, 40.0]",
    );
    let mut rig = setup::build(&cfg).unwrap();
    let mut rgb = vec![0u8; 48 * 48 * 3];
    let mut tilts = Vec::new();
    for k in 0..8 {
        rig.world.reset_at(0.3 * k as f32);
        rig.world.observe(&mut rgb);
        let tilt = rig.world.camera().tilt_deg;
        let drawn = rig.world.appearance().and_then(|a| a.look().tilt_deg);
        assert_eq!(
            Some(tilt),
            drawn,
            "episode {k}: the renderer's camera is the look's"
        );
        assert!((15.0..40.0).contains(&tilt), "episode {k}: {tilt}");
        tilts.push(tilt);
    }
    let spread = tilts.iter().cloned().fold(f32::MIN, f32::max)
        - tilts.iter().cloned().fold(f32::MAX, f32::min);
    assert!(spread > 8.0, "8 looks: {tilts:?}");
    // In the closed loop, looks change every 30 steps, and so does the camera each step
    // reports; the expert's target projects through it (what --record-xy writes).
    let mut pilot = Pilot::expert(cfg.sim.expert, 0);
    let mut seen: Vec<(f32, Option<(f32, f32)>)> = Vec::new();
    closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(4.0, &cfg),
        (48, 48),
        |s| {
            let label = s
                .expert
                .and_then(|a| jetpilot::sim::expert::target_label(&s.camera, &s.pose, a.target));
            seen.push((s.camera.tilt_deg, label));
        },
    )
    .unwrap();
    assert_eq!(seen.len(), 120);
    let mut changes = 0;
    for w in seen.windows(2) {
        changes += usize::from(w[0].0 != w[1].0);
    }
    assert!(
        (2..=4).contains(&changes),
        "4 looks in 120 steps: {changes} changes"
    );
    // Tilted down more, the target ahead sits higher in the frame: over the looks the
    // label's row falls as the tilt rises.
    let (lo, hi) = seen.iter().filter_map(|&(t, l)| l.map(|l| (t, l.1))).fold(
        ((f32::MAX, 0.0), (f32::MIN, 0.0)),
        |(lo, hi), (t, y)| {
            (
                if t < lo.0 { (t, y) } else { lo },
                if t > hi.0 { (t, y) } else { hi },
            )
        },
    );
    assert!(hi.0 - lo.0 > 3.0 && hi.1 < lo.1, "tilt {lo:?} vs {hi:?}");
    // Randomisation off: the configured tilt again.
    rig.world.set_appearance(None);
    rig.world.observe(&mut rgb);
    assert_eq!(rig.world.camera().tilt_deg, cfg.sim.camera.tilt_deg);
}

#[test]
fn replay_from_a_recorded_tub_and_realtime_under_the_real_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 4);
    let demos = dir.path().join("demos");
    let base = format!("[model]\npath = {model:?}\n[sim.camera]\nwidth = 48\nheight = 48\n");
    let cfg = dir.path().join("rec.toml");
    std::fs::write(&cfg, &base).unwrap();
    let jp = || Command::new(env!("CARGO_BIN_EXE_jetpilot"));
    // The expert's demonstrations, with poses, as a tub.
    let out = jp()
        .args(["-q", "sim", "--expert", "--seconds", "8", "--config"])
        .arg(&cfg)
        .arg("--record")
        .arg(&demos)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let tub = jetpilot::dataset::tub::TubReader::open(&demos).unwrap();
    assert_eq!(tub.len(), 240);
    // Replayed-frame simulation from that tub.
    let replay = dir.path().join("replay.toml");
    std::fs::write(
        &replay,
        format!("{base}[sim]\nframes = \"replay\"\nrecording = {demos:?}\n"),
    )
    .unwrap();
    let out = jp()
        .args(["-q", "eval", "--expert", "--seconds", "5", "--config"])
        .arg(&replay)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The same recording as the road (`road = "path"`): an 8 s drive does not come back to
    // its start, so the road is open, and the expert is carried back to its start at the end.
    let path = dir.path().join("path.toml");
    let path_road =
        format!("{base}[sim]\nframes = \"replay\"\nrecording = {demos:?}\nroad = \"path\"\n");
    let eval_expert = |toml: &str, args: &[&str]| {
        std::fs::write(&path, toml).unwrap();
        jp().args(["-q", "eval", "--expert"])
            .args(args)
            .arg("--config")
            .arg(&path)
            .output()
            .unwrap()
    };
    let json = dir.path().join("path.json");
    let out = eval_expert(
        &path_road,
        &["--seconds", "12", "--json", json.to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["interventions"], 0, "{v}");
    // Turning on the spot on the path road: the replayed view turns past 18 degrees from
    // its recorded frame long before the stall rule's window ends, and that is what each
    // intervention is counted as.
    let mut rig = setup::build(&Config::parse(&path_road, "path.toml").unwrap()).unwrap();
    let mut frame = vec![0u8; 48 * 48 * 3];
    for _ in 0..(6 * 30) {
        rig.motors.drive(WheelCommand::new(0.3, -0.3)).unwrap();
        for _ in 0..8 {
            rig.world.advance(1.0 / 240.0);
        }
        rig.world.observe(&mut frame);
        rig.world.score();
    }
    let s = &rig.world.stats;
    assert!(s.interventions >= 3, "{s:?}");
    assert_eq!(s.causes.replay_heading, s.interventions, "{:?}", s.causes);
    // A path road needs replayed frames: refused, naming the key.
    let out = eval_expert(
        &format!("{base}[sim]\nrecording = {demos:?}\nroad = \"path\"\n"),
        &["--seconds", "1"],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("sim.frames = \"replay\""),
        "{err}"
    );
    // Nor driven the other way: the recorded frames look the way it was driven.
    let out = eval_expert(&path_road, &["--seconds", "1", "--reverse"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("reverse = false"),
        "{err}"
    );
    // The real daemon (threads, actuator, watchdog) on the simulated car, in real time.
    let out = jp()
        .args(["-q", "sim", "--realtime", "--seconds", "2", "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(commands_written(&text) >= 30, "{text}");
}

#[test]
fn a_car_spinning_on_the_road_is_an_intervention_too() {
    let cfg = small_config("[sim.stall]\nseconds = 5.0\nmin_progress_m = 0.3\n");
    let mut rig = setup::build(&cfg).unwrap();
    // Spin in place on the lane centre, through the motor driver and the virtual HAT.
    for _ in 0..(31 * 30) {
        rig.motors.drive(WheelCommand::new(0.4, -0.4)).unwrap();
        for _ in 0..8 {
            rig.world.advance(1.0 / 240.0);
        }
        rig.world.score();
    }
    let w = &rig.world;
    assert_eq!(
        w.stats.interventions, 6,
        "one per 5 s window: {:?}",
        w.stats.interventions
    );
    assert!(
        w.stats
            .intervention_poses
            .iter()
            .all(|p| w.track.on_road(p.x, p.y)),
        "all on the road: the stall rule, not the road edge"
    );
    assert_eq!(w.stats.causes.stalled, 6, "{:?}", w.stats.causes);
}

#[test]
fn recovery_demonstrations_leave_out_the_swerves_and_stop_at_the_frame_count() {
    // The expert swerves every second on average; recording every 2nd control step (30 Hz:
    // 67 ms apart), 60 frames at most. Swerve steps are not recorded, so some gaps are
    // longer; every label is the expert's own pure-pursuit correction.
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("rec.toml");
    std::fs::write(&cfg, "[sim.camera]\nwidth = 32\nheight = 32\n").unwrap();
    // `sim --expert --record-every 2 --record DIR` with `args`, into `dir/name`.
    let record = |name: &str, args: &[&str]| {
        let tub = dir.path().join(name);
        let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
            .args(["-q", "sim", "--expert", "--record-every", "2"])
            .args(args)
            .arg("--config")
            .arg(&cfg)
            .arg("--record")
            .arg(&tub)
            .output()
            .unwrap();
        (tub, out)
    };
    let (tub, out) = record(
        "demos",
        &[
            "--seconds",
            "8",
            "--swerve-every",
            "1",
            "--record-frames",
            "60",
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("recorded 60 steps"));
    let reader = jetpilot::dataset::tub::TubReader::open(&tub).unwrap();
    let ms: Vec<u64> = reader.records().map(|r| r.timestamp_ms).collect();
    assert_eq!(ms.len(), 60);
    let gaps: Vec<u64> = ms.windows(2).map(|w| w[1] - w[0]).collect();
    // Whole numbers of 2-step intervals (2/30 s), to the millisecond.
    let whole = |g: u64| {
        let k = (g as f64 * 15.0 / 1000.0).round();
        k >= 1.0 && (g as f64 - k * 1000.0 / 15.0).abs() <= 1.0
    };
    assert!(gaps.iter().all(|g| whole(*g)), "{gaps:?}");
    let long = gaps.iter().filter(|g| **g > 100).count();
    assert!(long >= 2, "no swerve left out: {gaps:?}");
    // Without swerves the same drive records every 2nd step with no longer gap.
    let (plain, out) = record("plain", &["--seconds", "3"]);
    assert!(out.status.success());
    let reader = jetpilot::dataset::tub::TubReader::open(&plain).unwrap();
    let ms: Vec<u64> = reader.records().map(|r| r.timestamp_ms).collect();
    assert_eq!(ms.len(), 45);
    assert!(ms.windows(2).all(|w| w[1] - w[0] <= 67), "{ms:?}");
    // With --record-swerves the recorder runs through the swerves (a continuous
    // recording, to replay its path): every 2nd step again, though the expert swerved.
    let (all, out) = record(
        "all",
        &["--seconds", "3", "--swerve-every", "1", "--record-swerves"],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reader = jetpilot::dataset::tub::TubReader::open(&all).unwrap();
    let ms: Vec<u64> = reader.records().map(|r| r.timestamp_ms).collect();
    assert_eq!(ms.len(), 45);
    assert!(ms.windows(2).all(|w| w[1] - w[0] <= 67), "{ms:?}");
    // ... and its path is not the plain drive's: the swerves are in it.
    let plain_end = jetpilot::dataset::tub::TubReader::open(&plain)
        .unwrap()
        .records()
        .last()
        .and_then(|r| r.pose)
        .unwrap();
    let swerved_end = reader.records().last().and_then(|r| r.pose).unwrap();
    let apart = (plain_end.0 - swerved_end.0).hypot(plain_end.1 - swerved_end.1);
    assert!(apart > 0.002, "the swerves left no trace: {apart} m");
}

#[test]
fn scattered_samples_are_labelled_jetbot_files_that_repeat_for_a_seed() {
    // `sim --scatter N --record-xy DIR`: N frames from random poses on and beside the road,
    // named the way JetBot's notebook names them, the same for the same seed.
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.toml");
    std::fs::write(&cfg, "[sim.camera]\nwidth = 48\nheight = 48\n").unwrap();
    let scatter = |name: &str| {
        let xy = dir.path().join(name);
        let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
            .args(["-q", "sim", "--scatter", "16", "--camera", "jetbot"])
            .args(["--randomise", "--config"])
            .arg(&cfg)
            .arg("--record-xy")
            .arg(&xy)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("wrote 16 scattered samples"),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
        let folder = jetpilot::dataset::jetbot_xy::XyFolder::open(&xy).unwrap();
        assert!(folder.warnings().is_empty(), "{:?}", folder.warnings());
        let mut files: Vec<(String, Vec<u8>)> = folder
            .samples()
            .iter()
            .map(|s| {
                let name = s.path.file_name().unwrap().to_string_lossy().into_owned();
                (name, std::fs::read(&s.path).unwrap())
            })
            .collect();
        files.sort();
        files
    };
    let a = scatter("a");
    assert_eq!(a.len(), 16);
    // Every frame is a different place, and the targets spread across the frame.
    let labels: Vec<(u32, u32)> = a
        .iter()
        .map(|(n, _)| jetpilot::dataset::jetbot_xy::parse_file_name(n).unwrap())
        .collect();
    assert!(labels.iter().all(|&(x, y)| x < 48 && y < 48), "{labels:?}");
    let xs: Vec<u32> = labels.iter().map(|l| l.0).collect();
    let spread = xs.iter().max().unwrap() - xs.iter().min().unwrap();
    assert!(spread >= 10, "targets all in one column: {labels:?}");
    let frames: std::collections::BTreeSet<&Vec<u8>> = a.iter().map(|(_, f)| f).collect();
    assert_eq!(frames.len(), 16);
    assert_eq!(a, scatter("b"), "the same seed must give the same samples");

    // --record-xy alone has nowhere to take frames from.
    let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "sim", "--expert", "--seconds", "1", "--config"])
        .arg(&cfg)
        .arg("--record-xy")
        .arg(dir.path().join("c"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--record") && stderr.contains("--scatter"),
        "{stderr}"
    );
}

#[test]
fn scattered_samples_on_random_layouts_draw_a_new_road_every_few_samples() {
    // With layouts on, `write_scattered` puts the robot down on a new road every
    // `per_layout` samples; on a centre-line layout every label is a centre-line point.
    use jetpilot::sim::scatter::{ScatterParams, target, write_scattered};
    use jetpilot::sim::track::DriveLane;
    let cfg = small_config(
        "[sim.layouts]\nenabled = true\nevery_s = 0.0\nlane_width_m = [0.06, 0.07]\n\
         drive_lane = \"centre\"\n",
    );
    let dir = tempfile::tempdir().unwrap();
    let run = |per_layout: u64, n: u64| {
        let mut rig = setup::build(&cfg).unwrap();
        let first = rig.world.track.clone();
        assert_eq!(first.drive_lane(), DriveLane::Centre);
        let p = ScatterParams {
            lookahead_m: 0.135,
            per_layout,
            ..ScatterParams::default()
        };
        let out = dir.path().join(format!("xy-{per_layout}-{n}"));
        let mut labels = 0;
        let summary = write_scattered(&mut rig.world, &rig.camera, &p, n, 5, &out, |_, _| {
            labels += 1
        })
        .unwrap();
        assert_eq!((summary.written, labels), (n, n));
        // The label of a pose on the centre line is the centre-line point ahead.
        let track = rig.world.track.clone();
        let pose = track.pose_at(0.4, 0.0);
        let goal = track.pose_at(0.4 + 0.135, 0.0);
        let t = target(&track, &pose, 0.135);
        assert!((t.0 - goal.x).abs() < 1e-4 && (t.1 - goal.y).abs() < 1e-4);
        (first, track)
    };
    // 10 samples fit on the first road; the 11th is on a new one.
    let (first, last) = run(10, 10);
    assert_eq!(first, last);
    let (first, last) = run(10, 11);
    assert_ne!(first, last, "no new road after 10 samples");
    // 0: one road for all.
    let (first, last) = run(0, 25);
    assert_eq!(first, last);
}

#[test]
fn random_layouts_change_the_road_keep_the_expert_on_it_and_repeat_for_a_seed() {
    // A new layout every 8 s: about five in 40 s, each with the expert on its lane.
    let run = |seed: u64| {
        let cfg = small_config(&format!(
            "[sim]\nseed = {seed}\n[sim.layouts]\nenabled = true\nevery_s = 8.0\n"
        ));
        let mut rig = setup::build(&cfg).unwrap();
        let mut pilot = Pilot::expert(cfg.sim.expert, 0);
        let mut tracks = vec![rig.world.track.clone()];
        let mut min_edge = f32::MAX;
        closed_loop::run(
            &mut rig.world,
            &mut rig.motors,
            &mut pilot,
            &cfg.sim.loop_settings(40.0, &cfg),
            (48, 48),
            |s| min_edge = min_edge.min(s.score.edge_distance_m),
        )
        .unwrap();
        tracks.push(rig.world.track.clone());
        let mut frame = vec![0u8; 48 * 48 * 3];
        rig.world.observe(&mut frame);
        (rig.world.stats.clone(), tracks, frame, min_edge)
    };
    let (stats, tracks, frame, min_edge) = run(3);
    assert_eq!(stats.interventions, 0, "{stats:?}");
    assert!(min_edge > 0.0, "stayed in its lane: closest {min_edge} m");
    // The road is not the mat's, and it changed during the run.
    let mat = jetpilot::sim::track::Track::jetbot_mat();
    assert_ne!(tracks[0], mat);
    assert_ne!(tracks[0], tracks[1]);
    let again = run(3);
    assert_eq!(again.1, tracks);
    assert_eq!(again.2, frame, "same seed, same frame");
    assert_ne!(run(4).1, tracks, "the seed matters");

    // Replayed frames were recorded on one road: layouts need rendered frames.
    let cfg = small_config("[sim]\nframes = \"replay\"\n[sim.layouts]\nenabled = true\n");
    let e = setup::build(&cfg)
        .err()
        .expect("replay with layouts is refused");
    assert!(e.to_string().contains("[sim.layouts]"), "{e}");
}

#[test]
fn each_training_episode_gets_a_new_layout() {
    let cfg = small_config("[sim.layouts]\nenabled = true\nevery_s = 0.0\n");
    let mut env = jetpilot::sim::env::Env::new(&cfg, 100).unwrap();
    env.reset(None).unwrap();
    let first = env.world().track.clone();
    let obs = env.observation().to_vec();
    env.reset(None).unwrap();
    assert_ne!(env.world().track, first);
    assert_ne!(env.observation(), &obs[..]);
}

/// One HTTP GET on loopback; the whole response as text ("" while nothing listens).
fn http_get(port: u16, path: &str) -> String {
    use std::io::{Read, Write};
    let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return String::new();
    };
    let req = format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
    let _ = s.set_read_timeout(Some(std::time::Duration::from_secs(2)));
    let mut got = Vec::new();
    if s.write_all(req.as_bytes()).is_err() || s.read_to_end(&mut got).is_err() {
        return String::new();
    }
    String::from_utf8_lossy(&got).into_owned()
}

#[test]
fn the_demo_drive_the_daemon_with_its_web_page_engaged_from_the_start_and_a_trace() {
    // scripts/demo.sh's last step: `sim --realtime --web --png DIR`.
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 4);
    let cfg = dir.path().join("sim.toml");
    std::fs::write(
        &cfg,
        format!("[model]\npath = {model:?}\n[sim.camera]\nwidth = 48\nheight = 48\n"),
    )
    .unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .unwrap()
        .port();
    let png = dir.path().join("out");
    let child = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "sim", "--realtime", "--seconds", "6", "--web"])
        .arg(format!("127.0.0.1:{port}"))
        .arg("--png")
        .arg(&png)
        .arg("--config")
        .arg(&cfg)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The page answers while the car drives, and says the autopilot has it: no one pressed
    // Auto.
    let started = std::time::Instant::now();
    let mut status = String::new();
    while started.elapsed() < std::time::Duration::from_secs(5) {
        status = http_get(port, "/api/status");
        if status.contains("\"commands_written\"") && !status.contains("\"commands_written\":0,") {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    assert!(status.contains("\"mode\":\"auto\""), "{status}");
    assert!(http_get(port, "/").contains("200 OK"));
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains(&format!("web page: http://127.0.0.1:{port}/")),
        "{text}"
    );
    assert!(commands_written(&text) >= 90, "{text}");
    assert!(text.contains("interventions (autonomy"), "{text}");
    let trace = image::open(png.join("trace.png")).unwrap();
    assert!(trace.width() > 100 && trace.height() > 100);
}

#[test]
fn the_simulated_car_gets_donkeycars_throttle_and_angle_through_the_virtual_hat() {
    // A DonkeyCar at throttle 0.25 and full lock left: `[sim.car]` says 1 m/s and a 0.5 m
    // turning radius. The law's car mixing goes through the daemon's motor driver and the
    // virtual PCA9685's registers; the car drives the circle, where JetBot's mixing would
    // have clipped the same command to (0, 1), half lock at twice the speed.
    let cfg = small_config(
        "mixing = \"car\"\n[sim]\nvehicle = \"car\"\n[sim.car]\ntime_constant_s = 0.0\n",
    );
    let mut rig = setup::build(&cfg).unwrap();
    let law = cfg.control.gains();
    rig.motors.drive(law.mixing.mix(0.25, -1.0)).unwrap();
    let start = rig.world.robot.pose;
    let (mut far, steps) = (0.0f32, 754); // pi seconds at 240 Hz
    for _ in 0..steps {
        rig.world.advance(std::f32::consts::PI / steps as f32);
        let p = rig.world.robot.pose;
        far = far.max((p.x - start.x).hypot(p.y - start.y));
    }
    let p = rig.world.robot.pose;
    // JetBot's 8-bit motor speed (0-255, truncated) carries the channels: within 1 % of
    // the radius.
    assert!((far - 1.0).abs() < 0.01, "diameter {far}");
    assert!(
        (p.x - start.x).hypot(p.y - start.y) < 0.03,
        "{p:?} from {start:?}"
    );
    assert!((rig.world.robot.speed() - 1.0).abs() < 0.01);
    // A car's mixing needs the car: the config says which key is wrong.
    let err = Config::parse("[control]\nmixing = \"car\"\n", "bad.toml").unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("control.mixing") && msg.contains("sim.vehicle"),
        "{msg}"
    );
    let err = Config::parse("[sim]\nvehicle = \"car\"\n", "bad.toml").unwrap_err();
    assert!(err.to_string().contains("control.mixing"), "{err}");
    // A wheel's trim would mix the car's throttle into its angle.
    let err = Config::parse(
        "[control]\nmixing = \"car\"\n[sim]\nvehicle = \"car\"\n[motors.right]\nalpha = 0.9\n",
        "bad.toml",
    )
    .unwrap_err();
    assert!(err.to_string().contains("motors.right.alpha"), "{err}");
}

#[test]
fn the_expert_drives_the_simulated_car_round_the_mat() {
    // Pure pursuit as DonkeyCar's throttle and angle: a car that turns as tight as 0.17 m
    // keeps to the mat's lane for two laps (1.96 in 2.2 laps' time: the speed lags).
    let cfg = small_config(
        "mixing = \"car\"\n[sim]\nvehicle = \"car\"\n[sim.car]\ncurvature_per_unit = -6.0\n",
    );
    let mut rig = setup::build(&cfg).unwrap();
    assert!(rig.world.robot.car_params().is_some());
    let mut pilot = Pilot::expert(cfg.sim.expert, 0);
    let lap_s = rig.world.track.length() as f64 / cfg.sim.expert.speed_mps as f64;
    closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(lap_s * 2.2, &cfg),
        (48, 48),
        |_| {},
    )
    .unwrap();
    assert_eq!(rig.world.stats.interventions, 0);
    assert!(rig.world.laps() >= 1.9, "{} laps", rig.world.laps());
}

#[test]
fn a_recorded_car_drive_is_a_donkeycar_tub() {
    // `sim --record` with the car: the tub has DonkeyCar's throttle and angle and no
    // `wheels/*`, so `poses` and the trainer take it for a car's without `--vehicle car`.
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("car.toml");
    std::fs::write(
        &cfg,
        "[control]\nmixing = \"car\"\nspeed_gain = 0.25\n[sim]\nvehicle = \"car\"\n\
         [sim.camera]\nwidth = 48\nheight = 48\n",
    )
    .unwrap();
    let tub = dir.path().join("tub");
    let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["-q", "sim", "--expert", "--seconds", "6", "--record"])
        .arg(&tub)
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let reader = jetpilot::dataset::tub::TubReader::open(&tub).unwrap();
    assert!(
        !reader.inputs().iter().any(|k| k.starts_with("wheels/")),
        "{:?}",
        reader.inputs()
    );
    let recs: Vec<_> = reader.records().collect();
    assert!(recs.len() > 30, "{} records", recs.len());
    assert!(recs.iter().all(|r| r.wheels.is_none() && r.pose.is_some()));
    // The car's own channels: the expert's throttle is the speed gain times its speed,
    // under 0.25, and it turns into the mat's first bend about 4.5 s in.
    assert!(
        recs.iter()
            .all(|r| (0.0..=0.2501).contains(&r.user_throttle)),
        "throttles {:?}",
        recs.iter().map(|r| r.user_throttle).collect::<Vec<_>>()
    );
    let turn = recs.iter().map(|r| r.user_angle.abs()).fold(0.0, f32::max);
    assert!(turn > 0.05, "the largest angle {turn}");
    let vehicle =
        jetpilot::sim::odometry::Vehicle::for_tub(&reader, Default::default(), Default::default());
    assert!(matches!(vehicle, jetpilot::sim::odometry::Vehicle::Car(_)));
}

#[test]
fn the_simulated_car_refuses_manual_driving_by_name() {
    // The gamepad, the web page's sticks and the recorder mix and store a JetBot's wheel
    // commands: with the car's mixing the daemon says so instead of driving it at half.
    let dir = tempfile::tempdir().unwrap();
    let model = common::write_model(dir.path(), 48, 4);
    let cfg = dir.path().join("car.toml");
    std::fs::write(
        &cfg,
        format!(
            "[model]\npath = {model:?}\n[control]\nmixing = \"car\"\n[sim]\nvehicle = \"car\"\n\
             [sim.camera]\nwidth = 48\nheight = 48\n"
        ),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args([
            "-q",
            "sim",
            "--realtime",
            "--seconds",
            "2",
            "--web",
            "127.0.0.1:0",
        ])
        .arg("--config")
        .arg(&cfg)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("control.mixing") && err.contains("[gamepad]"),
        "{err}"
    );
}

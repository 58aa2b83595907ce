//! A generated DonkeyCar drive through the whole estimate: a car-like vehicle driven by
//! known `(angle, throttle)` commands over a textured floor, its frames rendered through
//! DonkeyCar's wide-angle camera with a still chassis at the bottom, written as a DonkeyCar
//! tub (no wheel keys), and its poses recovered by [`super::estimate`] with a prior whose
//! speed and curvature are off, as a real car's defaults are.

use std::collections::HashMap;

use super::ackermann::{CarOdometry, CarParams};
use super::mask::ChassisConfig;
use super::*;
use crate::dataset::tub::{DriveMode, TubInputs, TubWriter};

/// A floor of blobs on a 4 cm lattice, each of a grey drawn from its lattice cell (a
/// hash), smoothly blended: texture at 1-5 cm in every direction.
pub(super) fn floor(x: f32, y: f32) -> f32 {
    let hash = |i: i32, j: i32| {
        let mut h = (i as u32).wrapping_mul(0x9E37_79B1) ^ (j as u32).wrapping_mul(0x85EB_CA77);
        h ^= h >> 15;
        h = h.wrapping_mul(0x2C1B_3C6D);
        h ^= h >> 12;
        (h & 0xff) as f32
    };
    let (gx, gy) = (x / 0.04, y / 0.04);
    let (i, j) = (gx.floor() as i32, gy.floor() as i32);
    let (fx, fy) = (gx - i as f32, gy - j as f32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let top = hash(i, j) * (1.0 - sx) + hash(i + 1, j) * sx;
    let bottom = hash(i, j + 1) * (1.0 - sx) + hash(i + 1, j + 1) * sx;
    top * (1.0 - sy) + bottom * sy
}

/// The frame the camera sees from `pose`: the floor, sky (grey 200) above the horizon, and
/// the chassis (grey 30) in the bottom 10 rows.
pub(super) fn render(camera: &CameraModel, pose: &Pose2) -> Vec<u8> {
    let (w, h) = (camera.width, camera.height);
    let mut rgb = Vec::with_capacity((w * h * 3) as usize);
    for v in 0..h {
        for u in 0..w {
            let g = if v >= h - 10 {
                30.0
            } else {
                camera
                    .pixel_to_ground(pose, u as f32 + 0.5, v as f32 + 0.5)
                    .map_or(200.0, |(x, y)| floor(x, y))
            };
            let g = g.round().clamp(0.0, 255.0) as u8;
            rgb.extend_from_slice(&[g, g, g]);
        }
    }
    rgb
}

/// A car at 0.7 m/s at throttle 0.25 with a 0.8 m radius at full lock and no trim, its
/// speed lagging by `time_constant_s` (the view and loop tests' car).
pub(super) fn test_car(time_constant_s: f32) -> CarOdometry {
    CarOdometry::new(CarParams {
        speed_per_throttle_mps: 2.8,
        curvature_per_unit: -1.25,
        curvature_offset: 0.0,
        time_constant_s,
    })
}

fn jpeg(rgb: Vec<u8>, w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_raw(w, h, rgb).expect("the frame's size");
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg)
        .expect("JPEG encoding");
    out.into_inner()
}

/// Writes 4 s of a DonkeyCar drive at 20 Hz through `camera` to a new tub at `tub_dir`:
/// straight, left at full lock, straight, half right, at throttle 0.25, the car `car`.
/// Returns each record's index and true pose.
fn write_drive(
    tub_dir: &std::path::Path,
    camera: &CameraModel,
    car: CarParams,
) -> Vec<(u64, Pose2)> {
    let mut writer =
        TubWriter::create(tub_dir, &TubInputs::DONKEY, 1_700_000_000.0).expect("a new tub");
    let angle_at = |k: usize| match k {
        0..20 => 0.0,
        20..45 => -1.0,
        45..60 => 0.0,
        _ => 0.5,
    };
    let mut car = CarOdometry::new(car);
    let mut pose = Pose2::default();
    let mut truth = Vec::new();
    for k in 0..80usize {
        if k > 0 {
            let m = car.advance(angle_at(k - 1), 0.25, 0.05);
            pose = compose(&pose, &m);
        }
        let rec = TubRecord::new(
            1_700_000_000_000 + 50 * k as u64,
            angle_at(k),
            0.25,
            DriveMode::User,
        );
        let index = writer
            .append(&rec, &jpeg(render(camera, &pose), 160, 120))
            .expect("a record");
        truth.push((index, pose));
    }
    writer.flush_and_sync().expect("the tub on disk");
    truth
}

#[test]
fn a_generated_ackermann_drive_is_recovered_within_its_drift() {
    // The true car: 0.7 m/s at throttle 0.25, a 0.8 m radius at full lock, a trim that
    // turns it 0.1 /m to the left at angle 0. The prior's defaults: 1 m/s, 0.5 m, none.
    let truth_car = CarParams {
        speed_per_throttle_mps: 2.8,
        curvature_per_unit: -1.25,
        curvature_offset: 0.1,
        time_constant_s: 0.3,
    };
    let camera = CameraModel::donkeycar(160, 120);
    let dir = tempfile::tempdir().expect("a temporary folder");
    let tub_dir = dir.path().join("drive");
    let truth = write_drive(&tub_dir, &camera, truth_car);
    let tub = TubReader::open(&tub_dir).expect("the tub");
    let vehicle = Vehicle::for_tub(&tub, RobotParams::default(), CarParams::default());
    assert!(matches!(vehicle, Vehicle::Car(_)), "no wheel keys: the car");
    let params = OdometryParams {
        grid: ViewGrid::donkeycar(),
        levels: 2,
        chassis: ChassisConfig::default(),
        ..OdometryParams::default()
    };
    let est = estimate(
        &tub,
        &camera,
        vehicle,
        params,
        Pose2::default(),
        ReadOptions::default(),
    )
    .expect("an estimate");
    // The chassis: 10 rows of 160, grown by a row (9.2 % of the frame).
    assert_eq!(est.masked_pixels(), Some(11 * 160));
    // Over 5 % allowed: taken for a drive the variance cannot tell, dropped with a warning.
    let records: Vec<&TubRecord> = tub.records().collect();
    let strict = ChassisConfig {
        max_fraction: 0.05,
        ..ChassisConfig::default()
    };
    let mut warnings = Vec::new();
    let none = chassis_mask(&tub, &records, &camera, &vehicle, &strict, &mut warnings);
    assert!(none.is_none() && warnings.len() == 1, "{warnings:?}");
    assert!(warnings[0].contains("9 % of the frame"), "{warnings:?}");
    // A differential drive finds none unless asked.
    let wheels = Vehicle::Wheels(RobotParams::default());
    let cfg = ChassisConfig::default();
    assert!(chassis_mask(&tub, &records, &camera, &wheels, &cfg, &mut warnings).is_none());
    let truth: HashMap<u64, Pose2> = truth.into_iter().collect();
    let d = check::drift(&est.poses, &truth);
    let mut prior_only = params;
    prior_only.fusion.min_texture = f32::INFINITY;
    prior_only.calibrate = false;
    let base = estimate(
        &tub,
        &camera,
        vehicle,
        prior_only,
        Pose2::default(),
        ReadOptions::default(),
    )
    .expect("the prior alone");
    let b = check::drift(&base.poses, &truth);
    eprintln!(
        "estimate: {d}\nprior alone: {b}\n{:?}\n{:?}",
        est.scales, est.car
    );
    assert_eq!(est.poses.len(), 80);
    // Vision turns with the commands (the prior turns 1.6 times too much: about 0.6)...
    let (slope, n) = est.turn_agreement.expect("turning frames");
    assert!((0.4..0.9).contains(&slope), "{slope} over {n}");
    // ...and against them when the prior's steering sign is reversed.
    let reversed = estimate(
        &tub,
        &camera,
        vehicle,
        OdometryParams {
            reverse_turn: true,
            ..params
        },
        Pose2::default(),
        ReadOptions::default(),
    )
    .expect("an estimate");
    let (slope, _) = reversed.turn_agreement.expect("turning frames");
    assert!(slope < -0.2, "{slope}");
    assert!(d.final_error_pct < 5.0 && d.heading_error_deg < 5.0, "{d}");
    assert!(
        d.final_error_m < b.final_error_m / 3.0,
        "{d} against the prior's {b}"
    );
}

#[test]
fn a_car_tubs_replay_drives_its_calibrated_car() {
    // The drive above, its poses estimated, written with the replay config `poses` writes:
    // the replay's vehicle is the calibrated car in the tub's own angle convention
    // (negative curvature per unit: angle -1 steers left), and the scripted expert drives
    // its road as that car without an intervention.
    let camera = CameraModel::donkeycar(160, 120);
    let dir = tempfile::tempdir().expect("a temporary folder");
    let tub_dir = dir.path().join("drive");
    let truth_car = CarParams {
        speed_per_throttle_mps: 2.8,
        curvature_per_unit: -1.25,
        curvature_offset: 0.0,
        time_constant_s: 0.3,
    };
    write_drive(&tub_dir, &camera, truth_car);
    let tub = TubReader::open(&tub_dir).expect("the tub");
    let params = OdometryParams {
        grid: ViewGrid::donkeycar(),
        levels: 2,
        ..OdometryParams::default()
    };
    let vehicle = Vehicle::Car(CarParams::default());
    let est = estimate(
        &tub,
        &camera,
        vehicle,
        params,
        Pose2::default(),
        ReadOptions::default(),
    )
    .expect("an estimate");
    let car = est.car.expect("a car's calibration");
    assert!(car.curvature_per_unit < 0.0, "{car:?}");
    let mut base = crate::config::Config::default();
    base.sim.camera = camera;
    let text = output::replay_config(&base, "a test", est.car).expect("the replay config");
    let out = dir.path().join("drive-poses");
    output::write_tub(
        &tub,
        &est,
        &out,
        1.7e9,
        output::Labels::Keep,
        &[(output::REPLAY_CONFIG, text)],
    )
    .expect("the tub with poses");
    let cfg = crate::config::Config::load(&out.join(output::REPLAY_CONFIG)).expect("replay.toml");
    assert_eq!(cfg.sim.vehicle, crate::sim::setup::SimVehicle::Car);
    let mut rig = crate::sim::setup::build(&cfg).expect("the replay");
    assert_eq!(rig.world.robot.car_params(), Some(&car));
    let mut pilot = crate::sim::closed_loop::Pilot::expert(cfg.sim.expert, 0);
    crate::sim::closed_loop::run(
        &mut rig.world,
        &mut rig.motors,
        &mut pilot,
        &cfg.sim.loop_settings(8.0, &cfg),
        (camera.width, camera.height),
        |_| {},
    )
    .expect("the drive");
    assert_eq!(rig.world.stats.interventions, 0);
    assert!(
        rig.world.stats.distance_m > 1.2,
        "{} m",
        rig.world.stats.distance_m
    );
}

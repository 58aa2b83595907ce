//! Poses for a recording that has none (a real robot's `jetpilot record` tub, a
//! DonkeyCar's): visual odometry on the ground plane, fused with a prior from the recorded
//! commands: a differential drive's wheel duties ([`wheels`]) or a car's steering angle and
//! throttle ([`ackermann`]), chosen by the tub's fields ([`Vehicle::for_tub`]) or by config.
//!
//! ```text
//! frame k+1 --birdseye--> view --pyramid--+
//!                                         +--register (start: wheel prior)--> motion + information
//! frame k   --birdseye--> view --pyramid--+                                        |
//! wheels/left,right of record k, dt --wheels--> prior motion ----------------fuse--+--> pose k+1
//! ```
//!
//! [`Odometer`] is the per-frame core; [`estimate`] runs it over a tub; [`output`] writes a
//! new tub with `pose/x`, `pose/y`, `pose/heading` beside the old one (never touching it),
//! a per-frame CSV with the confidence and where each motion came from, and a top-down
//! trace; [`check`] measures the drift against a tub whose poses are known (the
//! simulator's).

pub mod ackermann;
pub mod birdseye;
pub mod calibrate;
#[cfg(test)]
mod car_drive_test;
pub mod check;
pub mod fuse;
pub mod loops;
pub mod mask;
pub mod output;
pub mod register;
pub mod views;
pub mod wheels;

use std::sync::Arc;

use super::camera::CameraModel;
use super::flat_field::FlatField;
use super::robot::RobotParams;
use super::synth::{FlatFieldFit, RecordedFrame, Recording, Synthesizer};
use super::{Pose2, SimError, wrap_angle};
use crate::dataset::tub::{TubReader, TubRecord};
use ackermann::{CarOdometry, CarParams};
use birdseye::{View, ViewGrid, Warp};
use fuse::{FusionParams, Source};
use mask::{ChassisConfig, PixelMask};
use register::{Motion, register};
use wheels::WheelOdometry;

/// Settings of the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryParams {
    pub grid: ViewGrid,
    /// Pyramid levels (the finest and this many minus one coarser). One by default: the
    /// wheel prior starts the search within a few millimetres at 10-30 Hz, and on the
    /// simulator's mat the coarse levels, where the dashes blur away, slid along the
    /// curves' unobservable direction (a lap: 35 % drift with three levels, 4-5 % with one).
    pub levels: usize,
    pub fusion: FusionParams,
    /// Calibrate the wheel model's speed and turn scales from the frames first
    /// ([`calibrate`]), then estimate with the corrected model.
    pub calibrate: bool,
    /// With calibration: where vision's own motions scatter about the wheels' by more
    /// than this ([`calibrate::scatter`]), vision is taken to be `scatter / this` times
    /// overconfident: the calibration counts fewer frames as well measured, and the
    /// wheels hold the fused pass harder (the prior's weight is multiplied by it). 0: off. 4 by default: above the
    /// 1.1-3.8 of the laps where vision helps (30, 15 and 10 Hz, noise, blur; the
    /// odometry study, docs/results/odometry.md), below the 4.6-14 of looks where it
    /// pulled the estimate off.
    pub scatter_ref: f64,
    /// Take out what the camera adds at fixed pixels (vignetting, a light gradient, glare
    /// that travels with the robot), which registration would read as no motion: fit a
    /// [`FlatField`] on the first estimate's poses and, where it explains the frames,
    /// estimate again on the flattened frames.
    pub flat_field: bool,
    /// The chassis mask: pixels that show the vehicle itself are left out of
    /// registration ([`mask`]).
    pub chassis: ChassisConfig,
    /// The commands turn the other way from the motion model: the wheels' duties are
    /// swapped, a car's angle negated (a reversed steering sign, or a mirrored camera,
    /// which [`calibrate::turn_agreement`] finds).
    pub reverse_turn: bool,
}

impl Default for OdometryParams {
    fn default() -> Self {
        Self {
            grid: ViewGrid::default(),
            levels: 1,
            fusion: FusionParams::default(),
            calibrate: true,
            scatter_ref: 4.0,
            flat_field: false,
            chassis: ChassisConfig::default(),
            reverse_turn: false,
        }
    }
}

/// The vehicle whose commands give the prior.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Vehicle {
    /// Differential drive (JetBot): the wheels' duties set the wheels' speeds.
    Wheels(RobotParams),
    /// Car-like (DonkeyCar, Ackermann steering): the angle sets a curvature, the throttle
    /// a speed.
    Car(CarParams),
}

impl Vehicle {
    /// The model a tub's fields call for: `wheels/left`, `wheels/right` in any record:
    /// the differential drive; only `user/angle` and `user/throttle`: the car.
    pub fn for_tub(tub: &TubReader, robot: RobotParams, car: CarParams) -> Vehicle {
        if tub.records().any(|r| r.wheels.is_some()) {
            Vehicle::Wheels(robot)
        } else {
            Vehicle::Car(car)
        }
    }

    /// The same vehicle turning `scale` (> 0) times as much for the same commands (the
    /// wheel base divided by it; the car's curvatures multiplied). The turn's sign is
    /// [`OdometryParams::reverse_turn`].
    pub fn with_turn(self, scale: f32) -> Vehicle {
        match self {
            Vehicle::Wheels(mut r) => {
                r.wheel_base_m /= scale;
                Vehicle::Wheels(r)
            }
            Vehicle::Car(mut c) => {
                c.curvature_per_unit *= scale;
                c.curvature_offset *= scale;
                Vehicle::Car(c)
            }
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            Vehicle::Wheels(_) => "differential drive (wheels/left, wheels/right)",
            Vehicle::Car(_) => "car-like (user/angle -> curvature, user/throttle -> speed)",
        }
    }
}

/// A record's command, as recorded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Wheel duties `(left, right)`, -1..1.
    Wheels(f32, f32),
    /// DonkeyCar's steering angle and throttle, -1..1.
    Steer { angle: f32, throttle: f32 },
}

/// The prior's motion model, running.
#[derive(Debug, Clone)]
enum Prior {
    Wheels(WheelOdometry),
    Car(CarOdometry),
}

impl Prior {
    fn new(vehicle: Vehicle) -> Self {
        match vehicle {
            Vehicle::Wheels(robot) => Prior::Wheels(WheelOdometry::new(robot)),
            Vehicle::Car(car) => Prior::Car(CarOdometry::new(car)),
        }
    }

    /// `cmd` held for `dt` seconds; a command of the other kind is converted
    /// ([`wheels::wheels_from_angle_throttle`] and its inverse).
    fn advance(&mut self, cmd: Command, dt: f32) -> Motion {
        match (self, cmd) {
            (Prior::Wheels(w), Command::Wheels(l, r)) => w.advance(l, r, dt),
            (Prior::Wheels(w), Command::Steer { angle, throttle }) => {
                let (l, r) = wheels::wheels_from_angle_throttle(angle, throttle);
                w.advance(l, r, dt)
            }
            (Prior::Car(c), Command::Steer { angle, throttle }) => c.advance(angle, throttle, dt),
            (Prior::Car(c), Command::Wheels(l, r)) => {
                let (angle, throttle) = ackermann::angle_throttle_from_wheels(l, r);
                c.advance(angle, throttle, dt)
            }
        }
    }

    fn with_scales(self, sc: &calibrate::Scales) -> Self {
        match self {
            Prior::Wheels(w) => Prior::Wheels(w.with_scales(sc.speed, sc.turn)),
            Prior::Car(c) => Prior::Car(c.with_scales(sc.speed, sc.turn, sc.offset)),
        }
    }
}

/// One frame's estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePose {
    /// The record's index in its tub.
    pub index: u64,
    /// Seconds since the first frame.
    pub time_s: f64,
    pub pose: Pose2,
    /// 0..1 (see [`fuse::Fused::confidence`]); 0 for a flagged frame.
    pub confidence: f32,
    pub source: Source,
}

/// The pose after `motion` from `pose` (the motion in `pose`'s frame).
pub fn compose(pose: &Pose2, m: &Motion) -> Pose2 {
    let (s, c) = pose.heading.sin_cos();
    Pose2::new(
        pose.x + c * m.forward - s * m.left,
        pose.y + s * m.forward + c * m.left,
        wrap_angle(pose.heading + m.yaw),
    )
}

/// Frame-by-frame visual-wheel odometry: [`Odometer::drive`] integrates the wheel
/// commands between frames into the prior, [`Odometer::see`] registers the next frame
/// against the previous one and fuses.
pub struct Odometer {
    warp: Warp,
    params: OdometryParams,
    prior: Prior,
    pose: Pose2,
    /// The prior's motion since the last frame.
    pending: Motion,
    previous: Option<Vec<View>>,
    /// Calibration pass: registrations without the prior's pull, with their priors.
    samples: Option<Vec<calibrate::Sample>>,
}

/// `a` then `b` (`b` in the frame at the end of `a`).
pub fn then(a: &Motion, b: &Motion) -> Motion {
    let (s, c) = a.yaw.sin_cos();
    Motion::new(
        a.forward + c * b.forward - s * b.left,
        a.left + s * b.forward + c * b.left,
        a.yaw + b.yaw,
    )
}

impl Odometer {
    pub fn new(
        camera: &CameraModel,
        vehicle: Vehicle,
        params: OdometryParams,
        start: Pose2,
    ) -> Self {
        Self {
            warp: Warp::new(camera, params.grid),
            params,
            prior: Prior::new(vehicle),
            pose: start,
            pending: Motion::default(),
            previous: None,
            samples: None,
        }
    }

    /// Applies calibrated motion-model corrections (from the start).
    pub fn with_scales(mut self, scales: &calibrate::Scales) -> Self {
        self.prior = self.prior.with_scales(scales);
        self
    }

    /// Leaves the masked pixels (the chassis) out of every view.
    pub fn with_mask(mut self, mask: &PixelMask) -> Self {
        self.warp = self.warp.masked(mask);
        self
    }

    /// The car model's parameters with the corrections folded in (`None` for wheels).
    pub fn car_params(&self) -> Option<CarParams> {
        match &self.prior {
            Prior::Car(c) => Some(c.calibrated()),
            Prior::Wheels(_) => None,
        }
    }

    /// A calibration pass: frames are registered without the prior's pull and kept for
    /// [`calibrate::fit`] ([`Odometer::samples`]).
    pub fn calibrating(mut self) -> Self {
        self.samples = Some(Vec::new());
        self
    }

    /// The calibration pass's samples.
    pub fn samples(&self) -> &[calibrate::Sample] {
        self.samples.as_deref().unwrap_or(&[])
    }

    pub fn pose(&self) -> Pose2 {
        self.pose
    }

    /// The command `cmd` was held for `dt` seconds.
    pub fn drive(&mut self, cmd: Command, dt: f32) {
        let cmd = match cmd {
            _ if !self.params.reverse_turn => cmd,
            Command::Wheels(l, r) => Command::Wheels(r, l),
            Command::Steer { angle, throttle } => Command::Steer {
                angle: -angle,
                throttle,
            },
        };
        let m = self.prior.advance(cmd, dt);
        self.pending = then(&self.pending, &m);
    }

    /// The next frame (`None`: its image is missing or unreadable): the new pose, its
    /// confidence and where its motion came from.
    pub fn see(&mut self, rgb: Option<(&[u8], u32, u32)>) -> (Pose2, f32, Source) {
        let prior = std::mem::take(&mut self.pending);
        let view = rgb.map(|(px, w, h)| self.warp.view(px, w, h));
        let texture = view.as_ref().map_or(0.0, |v| v.stats().1);
        let pyr = view.map(|v| register::pyramid(&v, self.params.levels));
        let reg = match (&self.previous, &pyr) {
            (Some(a), Some(b)) => {
                let pull = self.samples.is_none().then(|| {
                    fuse::prior_information(&prior, &self.params.fusion)
                        * f64::from(self.params.fusion.prior_weight)
                });
                Some(register(a, b, prior, pull))
            }
            _ => None,
        };
        if let (Some(samples), Some(r)) = (self.samples.as_mut(), reg) {
            samples.push(calibrate::Sample { prior, vision: r });
        }
        let fused = fuse::fuse(prior, reg.as_ref(), texture, &self.params.fusion);
        self.pose = compose(&self.pose, &fused.motion);
        self.previous = pyr;
        (self.pose, fused.confidence, fused.source)
    }
}

/// A record's command: `wheels/left`, `wheels/right` when recorded, else DonkeyCar's
/// angle and throttle.
pub fn record_command(rec: &TubRecord) -> Command {
    match rec.wheels {
        Some((l, r)) => Command::Wheels(l, r),
        None => Command::Steer {
            angle: rec.user_angle,
            throttle: rec.user_throttle,
        },
    }
}

/// How [`estimate`] reads frames.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ReadOptions {
    /// Use every n-th record only (1 or 0: all): a lower frame rate.
    pub every: usize,
    /// Gaussian noise added to each frame, grey levels (0: none).
    pub noise: f32,
    /// Box blur radius in pixels applied to each frame (0: none).
    pub blur: usize,
}

/// What [`estimate`] returns.
#[derive(Debug, Clone)]
pub struct Estimate {
    pub poses: Vec<FramePose>,
    /// The motion model's corrections (when calibrated).
    pub scales: Option<calibrate::Scales>,
    /// The car model's parameters with the corrections folded in (a car only).
    pub car: Option<CarParams>,
    /// The pixels left out of registration as the chassis (`None`: no mask was made).
    pub mask: Option<PixelMask>,
    /// Vision's scatter about the wheels ([`calibrate::scatter`]).
    pub scatter: Option<f64>,
    /// How vision's turn follows the prior's in the calibration pass
    /// ([`calibrate::turn_agreement`]): slope and frames.
    pub turn_agreement: Option<(f64, usize)>,
    /// The prior's weight the fused pass used (`params.fusion.prior_weight`, raised by
    /// `scatter_ref`).
    pub prior_weight: f32,
    /// With [`OdometryParams::flat_field`]: what was fitted on the first estimate (the
    /// poses are the second estimate's when the field was used).
    pub flat_field: Option<FlatFieldFit>,
    /// Records whose image could not be read (each named), and the tub's own warnings.
    pub warnings: Vec<String>,
}

impl Estimate {
    /// How many pixels the chassis mask leaves out (`None`: no mask was made).
    pub fn masked_pixels(&self) -> Option<usize> {
        self.mask.as_ref().map(PixelMask::count)
    }

    /// Frames that fell back to the wheel prior.
    pub fn flagged(&self) -> usize {
        self.poses
            .iter()
            .filter(|p| p.source != Source::Fused)
            .count()
    }
}

/// The wheel prior's weight for the fused pass: `weight`, raised by `scatter / reference`
/// where vision scatters about the wheels by more than `reference` (0: never).
pub fn held_harder(weight: f32, scatter: Option<f64>, reference: f64) -> f32 {
    weight * calibrate::overconfidence(scatter, reference) as f32
}

/// Runs the odometer over `tub`'s live records from `start` (the first frame's pose). The
/// first frame has nothing to match: it sits at `start`, flagged `prior:no_match`. A record
/// the tub reader drops (its image missing) is named in `warnings`.
pub fn estimate(
    tub: &TubReader,
    camera: &CameraModel,
    vehicle: Vehicle,
    params: OdometryParams,
    start: Pose2,
    opts: ReadOptions,
) -> Result<Estimate, SimError> {
    match &vehicle {
        Vehicle::Wheels(robot) => robot.validate()?,
        Vehicle::Car(car) => car.validate()?,
    }
    camera.validate()?;
    let mut warnings: Vec<String> = tub.warnings().to_vec();
    let records: Vec<&TubRecord> = tub
        .records()
        .filter(|r| !tub.deleted_indexes().contains(&r.index))
        .collect();
    if records.is_empty() {
        return Err(SimError::File {
            path: tub.dir().display().to_string(),
            reason: "the tub has no records".into(),
        });
    };
    let mask = chassis_mask(
        tub,
        &records,
        camera,
        &vehicle,
        &params.chassis,
        &mut warnings,
    );
    let setup = Setup {
        camera,
        vehicle,
        mask: mask.as_ref(),
    };
    let mut est = estimate_once(tub, &records, &setup, params, start, &opts, None)?;
    est.warnings.splice(0..0, warnings);
    if !params.flat_field {
        return Ok(est);
    }
    let (field, fit) = fit_flat_field(tub, &records, camera, &est.poses)?;
    est.flat_field = fit;
    let Some(field) = field else {
        return Ok(est);
    };
    let mut again = estimate_once(tub, &records, &setup, params, start, &opts, Some(&field))?;
    again.warnings = est.warnings;
    again.flat_field = fit;
    Ok(again)
}

/// What the odometer is built from: the camera, the vehicle, and the chassis mask.
struct Setup<'a> {
    camera: &'a CameraModel,
    vehicle: Vehicle,
    mask: Option<&'a PixelMask>,
}

impl Setup<'_> {
    fn odometer(&self, params: OdometryParams, start: Pose2) -> Odometer {
        let odo = Odometer::new(self.camera, self.vehicle, params, start);
        match self.mask {
            Some(m) => odo.with_mask(m),
            None => odo,
        }
    }
}

/// The chassis mask of `config` for these records: found from the frames' per-pixel
/// variance ([`mask::from_variance`]; by default for a car only) and/or set by row;
/// `None` when neither is asked for or no frame could be read. A found mask over
/// `config.max_fraction` of the frame is dropped, and a warning says so.
pub fn chassis_mask(
    tub: &TubReader,
    records: &[&TubRecord],
    camera: &CameraModel,
    vehicle: &Vehicle,
    config: &ChassisConfig,
    warnings: &mut Vec<String>,
) -> Option<PixelMask> {
    let (w, h) = (camera.width, camera.height);
    let by_row = config.below_row.map(|r| PixelMask::below_row(w, h, r));
    if !config.find.unwrap_or(matches!(vehicle, Vehicle::Car(_))) {
        return by_row;
    }
    let mut var = mask::Variance::new(w, h);
    for rec in records {
        if let Ok((fw, fh, rgb)) = tub.load_rgb(rec) {
            var.add(&rgb, fw, fh);
        }
    }
    if var.frames() < 2 {
        return by_row;
    }
    let found = mask::from_variance(&var.std(), w, h, config.max_std);
    if found.fraction() > config.max_fraction {
        warnings.push(format!(
            "chassis mask: {:.0} % of the frame hardly changes over the drive, more than a chassis ([sim.chassis] max_fraction {:.0} %); not used",
            found.fraction() * 100.0,
            config.max_fraction * 100.0
        ));
        return by_row;
    }
    Some(match by_row {
        Some(r) => found.or(&r),
        None => found,
    })
}

/// Calibration (if asked for) and the fused pass, on frames flattened by `flat` if given.
fn estimate_once(
    tub: &TubReader,
    records: &[&TubRecord],
    setup: &Setup,
    params: OdometryParams,
    start: Pose2,
    opts: &ReadOptions,
    flat: Option<&FlatField>,
) -> Result<Estimate, SimError> {
    let mut warnings = Vec::new();
    let (scales, scatter, turn_agreement) = if params.calibrate {
        let mut odo = setup.odometer(params, start).calibrating();
        pass(
            tub,
            records,
            setup.camera,
            opts,
            flat,
            &mut odo,
            &mut Vec::new(),
        )?;
        let scatter = calibrate::scatter(odo.samples());
        let overconfidence = calibrate::overconfidence(scatter, params.scatter_ref);
        let scales = match setup.vehicle {
            Vehicle::Wheels(_) => calibrate::fit(odo.samples(), overconfidence),
            Vehicle::Car(_) => calibrate::fit_car(odo.samples(), overconfidence),
        };
        (
            Some(scales),
            scatter,
            calibrate::turn_agreement(odo.samples()),
        )
    } else {
        (None, None, None)
    };
    let mut params = params;
    params.fusion.prior_weight =
        held_harder(params.fusion.prior_weight, scatter, params.scatter_ref);
    let mut odo = setup.odometer(params, start);
    if let Some(sc) = &scales {
        odo = odo.with_scales(sc);
    }
    let poses = pass(
        tub,
        records,
        setup.camera,
        opts,
        flat,
        &mut odo,
        &mut warnings,
    )?;
    Ok(Estimate {
        poses,
        scales,
        car: odo.car_params(),
        mask: setup.mask.cloned(),
        scatter,
        turn_agreement,
        prior_weight: params.fusion.prior_weight,
        warnings,
        flat_field: None,
    })
}

/// The camera's image-fixed effects, fitted on `poses` (the first estimate) from the
/// frames they were estimated from; the field is `None` where it does not explain them.
fn fit_flat_field(
    tub: &TubReader,
    records: &[&TubRecord],
    camera: &CameraModel,
    poses: &[FramePose],
) -> Result<(Option<FlatField>, Option<FlatFieldFit>), SimError> {
    let by_index: std::collections::HashMap<u64, &TubRecord> =
        records.iter().map(|r| (r.index, *r)).collect();
    let mut frames = Vec::with_capacity(poses.len());
    for p in poses {
        let Some(rec) = by_index.get(&p.index) else {
            continue;
        };
        if let Ok((w, h, rgb)) = tub.load_rgb(rec)
            && (w, h) == (camera.width, camera.height)
        {
            frames.push(RecordedFrame {
                pose: p.pose,
                width: w,
                height: h,
                rgb: Arc::new(rgb),
            });
        }
    }
    if frames.is_empty() {
        return Ok((None, None));
    }
    let recording = Recording {
        camera: *camera,
        frames,
    };
    // The field alone: fitted, not applied to the frames held here.
    Ok(match Synthesizer::new(recording, 0.1)?.fit_flat_field() {
        Some((field, fit)) => (fit.explains_the_pairs().then_some(field), Some(fit)),
        None => (None, None),
    })
}

/// One pass of `odo` over `records`.
fn pass(
    tub: &TubReader,
    records: &[&TubRecord],
    camera: &CameraModel,
    opts: &ReadOptions,
    flat: Option<&FlatField>,
    odo: &mut Odometer,
    warnings: &mut Vec<String>,
) -> Result<Vec<FramePose>, SimError> {
    let every = opts.every.max(1);
    let t0 = records.first().map_or(0, |r| r.timestamp_ms);
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
    let mut poses = Vec::with_capacity(records.len() / every + 1);
    for (i, rec) in records.iter().enumerate() {
        if i > 0 {
            // The previous record's command was held until this record's time; with
            // every n-th frame the skipped records' commands still drive the prior.
            let prev = records[i - 1];
            let dt = rec.timestamp_ms.saturating_sub(prev.timestamp_ms) as f32 / 1000.0;
            odo.drive(record_command(prev), dt);
        }
        if i % every != 0 {
            continue;
        }
        let frame = match tub.load_rgb(rec) {
            Ok((w, h, mut rgb)) => {
                if (w, h) != (camera.width, camera.height) {
                    return Err(SimError::File {
                        path: tub.image_path(rec).display().to_string(),
                        reason: format!(
                            "record {}: frame is {w}x{h}, the camera model ([sim.camera]) is {}x{}",
                            rec.index, camera.width, camera.height
                        ),
                    });
                }
                degrade(&mut rgb, w, h, opts, &mut rng);
                match flat {
                    Some(field) => Some((field.flatten(&rgb), w, h)),
                    None => Some((rgb, w, h)),
                }
            }
            Err(e) => {
                warnings.push(format!(
                    "record {}: {e} (its motion comes from the wheels)",
                    rec.index
                ));
                None
            }
        };
        let (pose, confidence, source) =
            odo.see(frame.as_ref().map(|(px, w, h)| (px.as_slice(), *w, *h)));
        poses.push(FramePose {
            index: rec.index,
            time_s: rec.timestamp_ms.saturating_sub(t0) as f64 / 1000.0,
            pose,
            confidence,
            source,
        });
    }
    Ok(poses)
}

/// Adds noise and blur to a frame (the robustness study).
fn degrade(rgb: &mut [u8], w: u32, h: u32, opts: &ReadOptions, rng: &mut impl rand::Rng) {
    if opts.blur > 0 {
        let r = opts.blur as i64;
        let src = rgb.to_vec();
        let (w, h) = (i64::from(w), i64::from(h));
        for y in 0..h {
            for x in 0..w {
                for ch in 0..3 {
                    let (mut s, mut n) = (0u32, 0u32);
                    for dy in -r..=r {
                        for dx in -r..=r {
                            let (xx, yy) = (x + dx, y + dy);
                            if (0..w).contains(&xx) && (0..h).contains(&yy) {
                                s += u32::from(src[((yy * w + xx) * 3 + ch) as usize]);
                                n += 1;
                            }
                        }
                    }
                    rgb[((y * w + x) * 3 + ch) as usize] = (s / n.max(1)) as u8;
                }
            }
        }
    }
    if opts.noise > 0.0 {
        let normal = rand_distr::Normal::new(0.0f32, opts.noise).ok();
        if let Some(d) = normal {
            for v in rgb.iter_mut() {
                let n: f32 = rand_distr::Distribution::sample(&d, rng);
                *v = (f32::from(*v) + n).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composing_motions() {
        let p = Pose2::new(1.0, 2.0, std::f32::consts::FRAC_PI_2);
        // Facing +y: forward is +y, left is -x.
        let q = compose(&p, &Motion::new(0.1, 0.02, 0.3));
        assert!(
            (q.x - 0.98).abs() < 1e-6 && (q.y - 2.1).abs() < 1e-6,
            "{q:?}"
        );
        assert!((q.heading - (std::f32::consts::FRAC_PI_2 + 0.3)).abs() < 1e-6);
    }

    #[test]
    fn the_wheels_hold_harder_where_vision_scatters() {
        // The glare look's drive: scatter 13.92 against 4: 16 x 3.48 = 55.68.
        assert!((held_harder(16.0, Some(13.92), 4.0) - 55.68).abs() < 1e-3);
        assert_eq!(held_harder(16.0, Some(3.81), 4.0), 16.0);
        assert_eq!(held_harder(16.0, None, 4.0), 16.0);
        assert_eq!(held_harder(16.0, Some(13.92), 0.0), 16.0, "0: off");
    }

    #[test]
    fn flat_frames_fall_back_to_the_wheels() {
        let cam = CameraModel::jetbot(224, 224);
        let mut robot = RobotParams::default();
        robot.motor.time_constant_s = 0.0;
        robot.motor.dead_band = 0.0;
        let mut odo = Odometer::new(
            &cam,
            Vehicle::Wheels(robot),
            OdometryParams::default(),
            Pose2::default(),
        );
        let grey = vec![100u8; 224 * 224 * 3];
        let (_, c, s) = odo.see(Some((&grey, 224, 224)));
        assert_eq!((c, s), (0.0, Source::Prior(fuse::Fallback::Textureless)));
        // 0.4 duty on both wheels for 0.1 s: 0.5 * 0.4 * 0.1 = 0.02 m straight ahead.
        odo.drive(Command::Wheels(0.4, 0.4), 0.1);
        let (p, c, s) = odo.see(Some((&grey, 224, 224)));
        assert_eq!((c, s), (0.0, Source::Prior(fuse::Fallback::Textureless)));
        assert!((p.x - 0.02).abs() < 1e-5 && p.y.abs() < 1e-6, "{p:?}");
        // A missing image too.
        odo.drive(Command::Wheels(0.4, 0.4), 0.1);
        let (p, _, s) = odo.see(None);
        assert_eq!(s, Source::Prior(fuse::Fallback::Textureless));
        assert!((p.x - 0.04).abs() < 1e-5);
    }
}

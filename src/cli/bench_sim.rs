//! `jetpilot bench --sim`: the simulator's frame costs on one thread (it runs beside the
//! model, which gets the other core): rendering the mat and replayed-frame synthesis at
//! 224x224 and 96x96, through the 120-degree pinhole (`CameraModel::pinhole`) and through
//! JetBot's fisheye (`CameraModel::jetbot`, the default), and repainting the mat for a
//! randomised scene.

use std::process::ExitCode;
use std::time::Instant;

use jetpilot::config::Config;
use jetpilot::drive::stats::summarise;
use jetpilot::sim::Pose2;
use jetpilot::sim::appearance::{AppearanceConfig, Glare, Look};
use jetpilot::sim::camera::CameraModel;
use jetpilot::sim::render::{MatTexture, Renderer};
use jetpilot::sim::scene::{SIM_FLOOR_RGB, SIM_MAT_RGB, Scene};
use jetpilot::sim::setup::{FrameMode, expert_lap_recording};
use jetpilot::sim::synth::Synthesizer;
use jetpilot::sim::track::Track;

fn time_ms(iterations: u32, mut f: impl FnMut(u32)) -> (f32, f32) {
    for i in 0..iterations.min(20) {
        f(i);
    }
    let mut samples: Vec<f32> = (0..iterations)
        .map(|i| {
            let t = Instant::now();
            f(i);
            t.elapsed().as_secs_f32() * 1000.0
        })
        .collect();
    let s = summarise(&mut samples);
    (s.p50, s.p90)
}

/// Vignetting, a light gradient and a glare patch: what a camera adds at fixed pixels.
const CAMERA_EFFECTS: Look = Look {
    vignette: 0.4,
    gradient: [0.2, -0.2],
    glare: Some(Glare {
        centre: [0.65, 0.6],
        radius: 0.1,
        peak: 0.4,
    }),
    ..Look::PLAIN
};

/// One line of the table: the label, then the median and p90 in milliseconds.
fn row(label: &str, (median, p90): (f32, f32)) {
    println!("  {label:<52} {median:>8.3} {p90:>8.3}");
}

pub fn main(iterations: u32) -> anyhow::Result<ExitCode> {
    let track = Track::jetbot_mat();
    println!("jetpilot bench --sim: one thread, {iterations} iterations, milliseconds");
    println!("  {:<52} {:>8} {:>8}", "", "median", "p90");
    let cases = [
        ("pinhole", 224u32),
        ("pinhole", 96),
        ("fisheye", 224),
        ("fisheye", 96),
    ];
    for (lens, size) in cases {
        let mut cfg = Config::default();
        cfg.sim.camera = match lens {
            "fisheye" => CameraModel::jetbot(size, size),
            _ => CameraModel::pinhole(size, size),
        };
        cfg.sim.frames = FrameMode::Replay;
        let texture = MatTexture::new(
            &track.paint(),
            track.mat_size(),
            cfg.sim.mat_px_per_m,
            SIM_MAT_RGB,
            SIM_FLOOR_RGB,
        )?;
        let renderer = Renderer::new(texture, cfg.sim.camera)?;
        let recording = expert_lap_recording(&cfg, &track)?;
        let n_rec = recording.frames.len();
        let synth = Synthesizer::new(recording, track.road_half_width())?;
        // Poses along the lane, a little off the recorded line, as a learner drives.
        let poses: Vec<Pose2> = (0..64)
            .map(|i| {
                let s = track.length() * i as f32 / 64.0;
                let mut p =
                    track.pose_at(s, track.lane_offset() + 0.03 * ((i % 5) as f32 - 2.0) / 2.0);
                p.heading += 0.05 * ((i % 3) as f32 - 1.0);
                p
            })
            .collect();
        let mut out = vec![0u8; (size * size * 3) as usize];
        let (r50, r90) = time_ms(iterations, |i| {
            renderer.render(&poses[i as usize % 64], &mut out)
        });
        row(&format!("render {lens} {size}x{size}"), (r50, r90));
        let (s50, s90) = time_ms(iterations, |i| {
            synth.synthesize(&poses[i as usize % 64], &mut out);
        });
        row(
            &format!("replayed-frame synthesis {lens} {size}x{size} ({n_rec} rec.)"),
            (s50, s90),
        );
        if lens == "fisheye" {
            // The reference the interpolated map is timed against (where it is used).
            let exact = synth.clone().with_interpolated_map(false);
            let (e50, e90) = time_ms(iterations, |i| {
                exact.synthesize(&poses[i as usize % 64], &mut out);
            });
            row("  every ground pixel projected", (e50, e90));
        }
        // Turned 20 degrees as well (DDPG's exploration near the heading bound): a fifth
        // of a fisheye's floor comes from earlier frames, or is the edge pixel smeared.
        let turned: Vec<Pose2> = poses
            .iter()
            .enumerate()
            .map(|(i, p)| Pose2 {
                heading: p.heading + 20f32.to_radians() * if i % 2 == 0 { 1.0 } else { -1.0 },
                ..*p
            })
            .collect();
        let edge = synth.clone().with_fill_from_earlier(false);
        for (name, s) in [("earlier frames", &synth), ("edge", &edge)] {
            let (t50, t90) = time_ms(iterations, |i| {
                s.synthesize(&turned[i as usize % 64], &mut out);
            });
            row(
                &format!("  turned 20 deg, unseen floor from {name}"),
                (t50, t90),
            );
        }
        // The same lap through a camera with vignetting, a light gradient and glare: the
        // flat field is fitted once (printed) and every view is restored through it.
        let mut lit = synth.recording().clone();
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
        for f in &mut lit.frames {
            let mut rgb = f.rgb.to_vec();
            CAMERA_EFFECTS.apply(size, size, &mut rng, &mut rgb);
            f.rgb = std::sync::Arc::new(rgb);
        }
        let started = Instant::now();
        let (flat, fit) = Synthesizer::new(lit, track.road_half_width())?.with_flat_field(true);
        let fit_ms = started.elapsed().as_secs_f32() * 1e3;
        if flat.has_flat_field() {
            let (t50, t90) = time_ms(iterations, |i| {
                flat.synthesize(&turned[i as usize % 64], &mut out);
            });
            row(
                "  turned 20 deg, camera effects kept (flat field)",
                (t50, t90),
            );
        }
        if let Some(field) = flat.flat_field() {
            let (r50, r90) = time_ms(iterations, |_| field.restore(&mut out));
            row("    of which restoring the camera's effects", (r50, r90));
        }
        println!(
            "  {:<52} fitted in {fit_ms:.0} ms from {} pixel pairs{}",
            "  flat field",
            fit.map_or(0, |f| f.pairs),
            if flat.has_flat_field() {
                ""
            } else {
                ", not used"
            }
        );
    }
    // A new scene (appearance randomisation): the mat texture painted again, with its
    // mips, and the backdrop; once per episode and every 150 frames.
    let mut cfg = Config::default();
    cfg.sim.camera = CameraModel::jetbot(224, 224);
    let texture = MatTexture::new(
        &track.paint(),
        track.mat_size(),
        cfg.sim.mat_px_per_m,
        SIM_MAT_RGB,
        SIM_FLOOR_RGB,
    )?;
    let mut renderer = Renderer::new(texture, cfg.sim.camera)?;
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
    let scenes: Vec<Scene> = (0..16)
        .map(|_| Scene::draw(&AppearanceConfig::default(), &mut rng))
        .collect();
    let mut failed = None;
    let n = (iterations / 10).max(3);
    let (p50, p90) = time_ms(n, |i| {
        let scene = &scenes[i as usize % scenes.len()];
        let painted = scene.show(&mut renderer, &track);
        if let Err(e) = painted {
            failed = Some(e);
        }
    });
    if let Some(e) = failed {
        return Err(e.into());
    }
    row(
        &format!(
            "new scene: mat repainted at {} texels/m ({n} it.)",
            cfg.sim.mat_px_per_m
        ),
        (p50, p90),
    );
    Ok(ExitCode::SUCCESS)
}

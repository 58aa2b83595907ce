//! The trainer end to end on small data: `jetpilot train il` on a simulated expert's tub
//! (files, curve, resume, reproducibility, an export ONNX Runtime runs like burn), and
//! `jetpilot train ddpg` from that policy with the demonstrations (its in-training
//! evaluation drives exactly like `jetpilot eval` on the exported best.onnx).
#![cfg(feature = "train")]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use jetpilot::policy::{OutputKind, Policy, Preprocessor};
use jetpilot::train::load_onnx;

const SIZE: u32 = 32;

fn jetpilot(args: &[&str], extra: &[&Path]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
    cmd.arg("-q").args(args);
    for p in extra {
        cmd.arg(p);
    }
    cmd.output().expect("run jetpilot")
}

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "stdout: {}\nstderr: {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A sim config with a 32x32 camera and the gains config/sim.toml uses.
fn sim_config(dir: &Path) -> PathBuf {
    let path = dir.join("sim.toml");
    std::fs::write(
        &path,
        "[control]\nspeed_gain = 0.5\nsteering_gain = 0.5\nsteering_kd = 0.1\n\
         [model]\ninput_size = 32\noutput = \"speed_steering\"\n\
         [sim.camera]\nwidth = 32\nheight = 32\n",
    )
    .unwrap();
    path
}

/// The scripted expert's demonstrations: `seconds` of driving, 30 steps per second.
fn demos(dir: &Path, cfg: &Path, seconds: &str) -> PathBuf {
    let tub = dir.join("demos");
    ok(&jetpilot(
        &["sim", "--expert", "--seconds", seconds, "--config"],
        &[cfg, Path::new("--record"), &tub],
    ));
    tub
}

fn il(cfg: &Path, tub: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["train", "il", "--batch", "8", "--seed", "3"];
    args.extend_from_slice(extra);
    jetpilot(
        &args,
        &[
            Path::new("--config"),
            cfg,
            Path::new("--data"),
            tub,
            Path::new("--out"),
            out,
        ],
    )
}

/// A short `train ddpg --sim` run: `episodes` of `steps`, an in-training eval of
/// `eval_seconds` every 2nd episode, small batches, seed 1, one thread.
fn ddpg(
    cfg: &Path,
    init: &Path,
    demos: &Path,
    out: &Path,
    episodes: &str,
    steps: &str,
    eval_seconds: &str,
) -> Output {
    ddpg_with(cfg, init, demos, out, [episodes, steps, eval_seconds], &[])
}

/// [`ddpg`] with more path arguments (`--select-sim FILE`, say) after its own.
fn ddpg_with(
    cfg: &Path,
    init: &Path,
    demos: &Path,
    out: &Path,
    [episodes, steps, eval_seconds]: [&str; 3],
    extra: &[&Path],
) -> Output {
    let mut paths: Vec<&Path> = vec![
        Path::new("--sim"),
        cfg,
        Path::new("--init"),
        init,
        Path::new("--demos"),
        demos,
        Path::new("--out"),
        out,
    ];
    paths.extend_from_slice(extra);
    jetpilot(
        &[
            "train",
            "ddpg",
            "--episodes",
            episodes,
            "--episode-steps",
            steps,
            "--eval-every",
            "2",
            "--eval-seconds",
            eval_seconds,
            "--warmup-updates",
            "5",
            "--batch",
            "16",
            "--seed",
            "1",
            "--threads",
            "1",
        ],
        &paths,
    )
}

fn csv_rows(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(str::to_owned)
        .collect()
}

/// Loss columns only (wall-clock columns differ between runs).
fn losses(rows: &[String]) -> Vec<String> {
    rows.iter()
        .map(|r| r.split(',').take(3).collect::<Vec<_>>().join(","))
        .collect()
}

#[test]
fn imitation_learning_trains_resumes_reproduces_and_exports() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let tub = demos(dir.path(), &cfg, "2");

    // Two epochs straight.
    let a = dir.path().join("a");
    let text = ok(&il(&cfg, &tub, &a, &["--epochs", "2"]));
    assert!(text.contains("best test loss"), "{text}");
    for f in [
        "best.onnx",
        "last.onnx",
        "il_log.csv",
        "il_curve.png",
        "il_state.json",
    ] {
        assert!(a.join(f).is_file(), "{f} missing");
    }
    let rows_a = csv_rows(&a.join("il_log.csv"));
    assert_eq!(rows_a.len(), 2, "{rows_a:?}");
    let png = image::open(a.join("il_curve.png")).unwrap();
    assert_eq!((png.width(), png.height()), (800, 500));

    // One epoch then --resume: the same two epochs as the straight run, to the last digit
    // (weights from last.onnx, Adam's moments from il_optim.bpk, seeded batches).
    let c = dir.path().join("c");
    ok(&il(&cfg, &tub, &c, &["--epochs", "1"]));
    assert!(c.join("il_optim.bpk").is_file());
    ok(&il(&cfg, &tub, &c, &["--epochs", "2", "--resume"]));
    let rows_c = csv_rows(&c.join("il_log.csv"));
    assert_eq!(losses(&rows_a), losses(&rows_c), "the resumed run differs");
    let state: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(c.join("il_state.json")).unwrap()).unwrap();
    assert_eq!(state["epochs_done"], 2);

    // The export: our contract, and ONNX Runtime agrees with burn on a demonstration frame.
    let best = a.join("best.onnx");
    let mut ort = common::load_ort(&best);
    assert_eq!(ort.contract().output, OutputKind::SpeedSteering);
    assert_eq!(ort.contract().input_size, SIZE);
    let reader = jetpilot::dataset::tub::TubReader::open(&tub).unwrap();
    let rec = reader.records().nth(5).unwrap();
    let (w, h, rgb) = reader.load_rgb(rec).unwrap();
    let mut pre = Preprocessor::new(ort.contract());
    let input = pre.run(w, h, &rgb).unwrap().to_vec();
    let want = ort.infer(&input).unwrap();
    let device = Device::flex();
    let (model, contract) = load_onnx(&best, &device).unwrap();
    assert_eq!(contract.output, OutputKind::SpeedSteering);
    let s = SIZE as usize;
    let x = Tensor::<4>::from_data(TensorData::new(input, [1, 3, s, s]), &device);
    let got = model
        .valid()
        .forward(x)
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .unwrap();
    for i in 0..2 {
        assert!(
            (got[i] - want[i]).abs() <= 1e-4,
            "burn {got:?} vs ort {want:?}"
        );
    }
}

#[test]
fn imitation_learning_refuses_bad_data_with_the_folder_named() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = il(
        &cfg,
        &empty,
        &dir.path().join("o"),
        &["--epochs", "1", "--head", "xy"],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&*empty.display().to_string()), "{err}");
    // An xy folder cannot train a speed_steering head.
    let out = il(&cfg, &empty, &dir.path().join("o"), &["--epochs", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--head xy"), "{err}");
}

#[test]
fn ddpg_fine_tunes_from_the_imitation_policy_and_its_eval_matches_jetpilot_eval() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let tub = demos(dir.path(), &cfg, "2");
    let il_out = dir.path().join("il");
    ok(&il(&cfg, &tub, &il_out, &["--epochs", "1"]));
    let init = il_out.join("best.onnx");

    let run = |out: &Path| ddpg(&cfg, &init, &tub, out, "3", "40", "4");
    let a = dir.path().join("a");
    let text = ok(&run(&a));
    assert!(text.contains("demonstration transitions"), "{text}");
    for f in [
        "best.onnx",
        "last.onnx",
        "ddpg_episodes.csv",
        "ddpg_eval.csv",
        "ddpg_curve.png",
    ] {
        assert!(a.join(f).is_file(), "{f} missing");
    }
    assert_eq!(csv_rows(&a.join("ddpg_episodes.csv")).len(), 3);
    // The frozen backbone (the default) leaves the convolutions as imitation learning made them.
    let weights = |p: &Path| {
        load_onnx(p, &Device::flex())
            .unwrap()
            .0
            .to_weights()
            .unwrap()
    };
    let (before, after) = (weights(&init), weights(&a.join("last.onnx")));
    assert_eq!(
        after.tensors["conv1.weight"],
        before.tensors["conv1.weight"]
    );
    assert_ne!(after.tensors["fc.weight"], before.tensors["fc.weight"]);
    // Evaluations at episode 0, 2 and after the last (3).
    let evals = csv_rows(&a.join("ddpg_eval.csv"));
    assert_eq!(evals.len(), 3, "{evals:?}");

    // Reproducible: the same seed, the same episodes (wall-clock columns aside).
    let b = dir.path().join("b");
    ok(&run(&b));
    let cols = |rows: Vec<String>| -> Vec<String> {
        rows.iter()
            .map(|r| {
                let v: Vec<&str> = r.split(',').collect();
                [v[0], v[1], v[2], v[3], v[4], v[7], v[8]].join(",")
            })
            .collect()
    };
    assert_eq!(
        cols(csv_rows(&a.join("ddpg_episodes.csv"))),
        cols(csv_rows(&b.join("ddpg_episodes.csv")))
    );

    // The exported best policy, run by `jetpilot eval` on ONNX Runtime, drives as the
    // in-training evaluation that chose it.
    let best_eval: Vec<f64> = {
        // The trainer's rule (train::ddpg::eval::improves_on): autonomy, then rewards, among
        // the evaluations with at least half the start's rewards.
        let rows: Vec<Vec<f64>> = evals
            .iter()
            .map(|r| r.split(',').map(|x| x.parse().unwrap()).collect())
            .collect();
        let mut best: Option<&Vec<f64>> = None;
        for v in &rows {
            let drives = 2.0 * v[5] >= rows[0][5];
            if drives && best.is_none_or(|b| (v[4], v[5]) > (b[4], b[5])) {
                best = Some(v);
            }
        }
        best.unwrap().clone()
    };
    let json = dir.path().join("eval.json");
    ok(&jetpilot(
        &["eval", "--seconds", "4", "--config"],
        &[
            &cfg,
            Path::new("--model"),
            &a.join("best.onnx"),
            Path::new("--json"),
            &json,
        ],
    ));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // The head runs in Rust on ONNX Runtime's features during training, inside the graph
    // (MLAS's Gemm, whose summation order follows the CPU's SIMD level) in the export: the
    // two steerings differ by float rounding, which can move a motor duty by one step and,
    // in a closed loop, tip a reward over the count threshold or, rarely, an intervention
    // (a 600 s test measured 9100 vs 9072 rewards, the same 17 interventions).
    let interventions = v["interventions"].as_f64().unwrap();
    assert!(
        (interventions - best_eval[3]).abs() <= 1.0,
        "{v} vs {best_eval:?}"
    );
    let rewards = v["rewards"].as_f64().unwrap();
    assert!(
        (rewards - best_eval[5]).abs() <= 0.02 * best_eval[5] + 2.0,
        "{v} vs {best_eval:?}"
    );
}

#[test]
fn ddpg_evaluates_and_picks_best_onnx_in_the_selection_world() {
    // `--select-sim` moves the evaluations (and so the choice of best.onnx) to another
    // world: here the S-bends track, whose length differs from the mat's, so the same
    // drive covers another share of a lap. The first evaluation is the unchanged --init
    // policy (the warm-up updates only the critic): it must be `jetpilot eval` in the
    // selection world, not in the training one.
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let tub = demos(dir.path(), &cfg, "2");
    let il_out = dir.path().join("il");
    ok(&il(&cfg, &tub, &il_out, &["--epochs", "1"]));
    let init = il_out.join("best.onnx");
    let select = dir.path().join("select.toml");
    let track = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/tracks/s_bends.toml");
    std::fs::write(
        &select,
        format!(
            "[control]\nspeed_gain = 0.5\nsteering_gain = 0.5\nsteering_kd = 0.1\n\
             [model]\ninput_size = 32\noutput = \"speed_steering\"\n\
             [sim]\ntrack = {:?}\n[sim.camera]\nwidth = 32\nheight = 32\n",
            track.display().to_string()
        ),
    )
    .unwrap();

    let out = dir.path().join("ddpg");
    ok(&ddpg_with(
        &cfg,
        &init,
        &tub,
        &out,
        ["1", "20", "4"],
        &[Path::new("--select-sim"), &select],
    ));
    let first: Vec<f64> = csv_rows(&out.join("ddpg_eval.csv"))[0]
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect();
    assert_eq!(
        first[0], 0.0,
        "the first evaluation is at episode 0: {first:?}"
    );
    let laps = |world: &Path, name: &str| -> f64 {
        let json = dir.path().join(name);
        ok(&jetpilot(
            &["eval", "--seconds", "4", "--config"],
            &[
                world,
                Path::new("--model"),
                &init,
                Path::new("--json"),
                &json,
            ],
        ));
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        v["laps"]
            .as_f64()
            .unwrap_or_else(|| panic!("no laps in {v}"))
    };
    let (in_select, in_training) = (laps(&select, "select.json"), laps(&cfg, "train.json"));
    // The two worlds give different laps (0.016 on the mat and -0.006 on the S-bends when
    // written; 0.0088 and 0.0093 on another CPU, where the one-epoch policy's float
    // rounding differs); the trainer's head and the exported graph differ by float
    // rounding only (see the test above), far less than the worlds, so the evaluation lies
    // next to the selection world's.
    assert!(
        (in_select - in_training).abs() > 1e-4,
        "the two worlds must tell apart: {in_select} vs {in_training} laps"
    );
    assert!(
        (first[7] - in_select).abs() < 0.25 * (in_select - in_training).abs(),
        "evaluated in the selection world: {} laps, eval there {in_select}, in training {in_training}",
        first[7]
    );
}

#[test]
fn ddpg_with_trainable_backbones_trains_the_exported_trunk() {
    // From scratch (the random ResNet-18 of --seed) with the demonstrations: a few updates
    // with --train-backbone must change the exported convolutions but not the batch-norm
    // statistics, and `jetpilot eval` drives the result.
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let tub = demos(dir.path(), &cfg, "1");
    let out = dir.path().join("ddpg");
    let text = ok(&jetpilot(
        &[
            "train",
            "ddpg",
            "--train-backbone",
            "--input-size",
            "32",
            "--episodes",
            "2",
            "--episode-steps",
            "16",
            "--eval-every",
            "0",
            "--eval-seconds",
            "1",
            "--warmup-updates",
            "2",
            "--batch",
            "8",
            "--updates-per-step",
            "0.25",
            "--seed",
            "1",
            "--threads",
            "1",
        ],
        &[
            Path::new("--sim"),
            &cfg,
            Path::new("--demos"),
            &tub,
            Path::new("--out"),
            &out,
        ],
    ));
    assert!(text.contains("demonstration transitions"), "{text}");
    let initial = jetpilot::policy::onnx::Resnet18Weights::random(2, 1);
    let (last, contract) = load_onnx(&out.join("last.onnx"), &Device::flex()).unwrap();
    assert_eq!(contract.input_size, SIZE);
    let last = last.to_weights().unwrap();
    for name in ["conv1.weight", "layer2.0.conv1.weight", "fc.weight"] {
        assert_ne!(
            last.tensors[name].1, initial.tensors[name].1,
            "{name} did not train"
        );
    }
    for name in ["bn1.running_mean", "layer4.1.bn2.running_var"] {
        assert_eq!(
            last.tensors[name].1, initial.tensors[name].1,
            "{name} changed"
        );
    }
    ok(&jetpilot(
        &["eval", "--seconds", "2", "--config"],
        &[&cfg, Path::new("--model"), &out.join("last.onnx")],
    ));
}

/// The paper's claim in miniature: DDPG fixes a deliberately biased policy. On a circle the
/// actor must hold a small left steering; the initial actor steers straight (fc weights 0,
/// bias speed 0.6, steering 0), so it leaves the road every few seconds. DDPG, seeded,
/// with a short budget, must bring the 20 s test to 0 interventions.
///
/// The budget is the worst seed's, not seed 3's: another CPU rounds the updates
/// differently, and the run then goes as another seed would. Measured on an AMD EPYC
/// (2026-12-01), seeds 1-11 reached 0 at episodes 5-45, but for seed 4 at 75 (1
/// intervention left at 60, the old budget); seed 3 at episode 5. The run stops at the
/// first eval without an intervention, so the budget costs only a slow seed time.
#[test]
fn ddpg_removes_the_interventions_of_a_biased_policy() {
    use jetpilot::config::Config;
    use jetpilot::policy::onnx::Resnet18Weights;
    use jetpilot::train::ddpg::{self, DdpgOptions};
    use jetpilot::train::export::write_weights;

    let dir = tempfile::tempdir().unwrap();
    let track = dir.path().join("circle.toml");
    std::fs::write(
        &track,
        "name = \"circle\"\nstart = [1.265, 1.37, 90.0]\n\
         [[segment]]\nkind = \"arc\"\nradius = 0.35\nangle = 360.0\n",
    )
    .unwrap();
    let mut cfg = Config::load(&sim_config(dir.path())).unwrap();
    cfg.sim.track = Some(track);

    let mut contract = cfg.model.fallback_contract();
    contract.input_size = SIZE;
    contract.output = OutputKind::SpeedSteering;
    let mut biased = Resnet18Weights::random(2, 5);
    biased
        .tensors
        .insert("fc.weight".into(), (vec![2, 512], vec![0.0; 1024]));
    biased
        .tensors
        .insert("fc.bias".into(), (vec![2], vec![0.6, 0.0]));
    let init = dir.path().join("biased.onnx");
    write_weights(&biased, &contract, &init).unwrap();

    let mut opts = DdpgOptions::new(dir.path().join("ddpg"), cfg);
    opts.init = Some(init);
    opts.seed = 3;
    opts.max_episodes = 120;
    opts.episode_steps = 150;
    opts.eval_every = 5;
    opts.eval_seconds = 20.0;
    opts.stop_at_full_autonomy = true;
    opts.warmup_updates = 0;
    opts.ort_threads = 1;
    opts.agent.batch = 64;
    opts.agent.actor_lr = 1e-3;
    // The levers of the paper's experiment (docs/results/paper-experiment.md): search, a
    // decaying anchor (the critic starts untrained: there are no demonstrations), failure
    // resets, OU noise on steering.
    opts.agent.search_step = 0.1;
    opts.agent.anchor_weight = 5.0;
    opts.agent.anchor_decay_updates = 600;
    opts.failure_resets = 0.5;
    opts.noise = jetpilot::train::ddpg::noise::NoiseKind::Ou;
    opts.sigma = [0.05, 0.3];
    let report = ddpg::train(&opts, |_| {}, |_, _| {}).unwrap();
    let first = report.evals.first().unwrap().outcome;
    let best = report.best.unwrap();
    eprintln!(
        "start: {} interventions; best: {} at episode {} ({} env steps, {:.0} s)",
        first.interventions,
        best.outcome.interventions,
        best.episode,
        best.env_steps,
        report.wall_s
    );
    assert!(first.interventions >= 3, "{first:?}");
    assert_eq!(best.outcome.interventions, 0, "{:?}", report.evals);
}

/// `n` grey 224x224 JetBot xy frames, labelled (50 + 3 i, 60) px, in `dir`.
fn xy_frames(dir: &Path, n: usize, grey: u8) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let mut jpeg = Vec::new();
    jetpilot::dataset::encode_jpeg(&vec![grey; 224 * 224 * 3], 224, 224, &mut jpeg).unwrap();
    for i in 0..n {
        let id = format!("{grey}-{i}");
        jetpilot::dataset::jetbot_xy::write_sample(dir, 50 + 3 * i as u32, 60, &jpeg, &id).unwrap();
    }
    dir.to_path_buf()
}

#[test]
fn imitation_learning_mixes_extra_frames_into_every_epoch_but_not_into_the_test_split() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let own = xy_frames(&dir.path().join("real"), 12, 90);
    let mix = xy_frames(&dir.path().join("sim"), 30, 160);
    let out = dir.path().join("il");
    let run = |share: &str| {
        let args = [
            "train",
            "il",
            "--batch",
            "8",
            "--seed",
            "3",
            "--epochs",
            "2",
            "--head",
            "xy",
            "--mix-share",
            share,
        ];
        let paths: [&Path; 8] = [
            Path::new("--config"),
            &cfg,
            Path::new("--data"),
            &own,
            Path::new("--mix"),
            &mix,
            Path::new("--out"),
            &out,
        ];
        jetpilot(&args, &paths)
    };
    let first = run("0.25");
    let stdout = ok(&first);
    // 12 own frames: 11 train, 1 test; the 30 mixed-in ones are never held out.
    // A share of 0.25: round(0.25 / 0.75 * 11) = 4 an epoch, 4 of 15 images.
    assert!(stdout.contains("on 11 train / 1 test frames"), "{stdout}");
    assert!(
        stdout.contains("mixed in: 4 frames an epoch from 30 (--mix, 27 % of each epoch's images)"),
        "{stdout}"
    );
    assert_eq!(csv_rows(&out.join("il_log.csv")).len(), 2);
    let err = String::from_utf8_lossy(&first.stderr);
    assert!(
        err.contains("lowest loss on only 1 held-out frame(s), a noisy pick"),
        "{err}"
    );
    // A share of 1 would leave no room for the own frames; 0.95 is the most (19 to 1).
    let bad = run("1");
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("--mix-share must be in 0..0.95"), "{err}");
}

#[test]
fn train_plot_draws_one_line_per_series_and_names_a_missing_column() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("points.csv");
    std::fs::write(
        &csv,
        "frames,start,mean_px\n25,sim,30.5\n25,random,44\n50,random,40\n50,sim,26\n",
    )
    .unwrap();
    let png = dir.path().join("plot.png");
    let run = |x: &str| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
        cmd.args([
            "train", "plot", "--x", x, "--y", "mean_px", "--series", "start",
        ])
        .arg("--csv")
        .arg(&csv)
        .arg("--out")
        .arg(&png);
        cmd.output().expect("run jetpilot")
    };
    let stdout = ok(&run("frames"));
    assert!(stdout.contains("2 line(s), 4 point(s)"), "{stdout}");
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (900, 560));
    let out = run("frame");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no column `frame`") && err.contains("frames, start, mean_px"),
        "{err}"
    );
}

#[test]
fn train_plot_draws_the_seeds_mean_where_rows_repeat_an_x() {
    // real-finetune.sh with SEEDS="1 2 3": one row per seed; the line is their mean.
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("finetune.csv");
    std::fs::write(
        &csv,
        // Two runs' CSVs, `cat` together: the second header row is skipped.
        "frames,start,seed,mean_px\n25,sim,1,30\n25,sim,2,34\n\
         frames,start,seed,mean_px\n25,sim,3,32\n25,random,1,38\n50,sim,1,28\n",
    )
    .unwrap();
    let png = dir.path().join("plot.png");
    let run = |log_y: bool| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_jetpilot"));
        cmd.args(["train", "plot", "--x", "frames", "--y", "mean_px"])
            .args(["--series", "start"])
            .arg("--csv")
            .arg(&csv)
            .arg("--out")
            .arg(&png);
        if log_y {
            cmd.arg("--log-y");
        }
        cmd.output().expect("run jetpilot")
    };
    let stdout = ok(&run(false));
    assert!(
        stdout.contains("line \"sim\", x 25: mean 32.0 ± 2.0 (3 rows: 30, 34, 32)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("2 line(s), 3 point(s) (the means of 5 rows)"),
        "{stdout}"
    );
    assert!(!stdout.contains("x 50"), "one row there: {stdout}");
    let img = image::open(&png).unwrap();
    assert_eq!((img.width(), img.height()), (900, 560));
    let out = run(true);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("drop --log-y"), "{err}");
}

#[test]
fn ddpg_and_eval_run_on_the_road_made_from_a_recordings_path() {
    // Issue 12, item 3: a recording with poses and no track file is the road
    // (`sim.road = "path"`); `eval` and `train ddpg --sim` run on it unchanged. Here 40 s of
    // the expert on the mat (about 1.2 laps) close into a loop.
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    // A frame every 3rd step: 2 cm apart at the expert's 0.2 m/s, 400 frames.
    let tub = dir.path().join("demos");
    ok(&jetpilot(
        &[
            "sim",
            "--expert",
            "--seconds",
            "40",
            "--record-every",
            "3",
            "--config",
        ],
        &[&cfg, Path::new("--record"), &tub],
    ));
    let path_cfg = dir.path().join("path.toml");
    std::fs::write(
        &path_cfg,
        format!(
            "{}[sim]\nframes = \"replay\"\nrecording = {tub:?}\nroad = \"path\"\n",
            std::fs::read_to_string(&cfg).unwrap()
        ),
    )
    .unwrap();
    let json = dir.path().join("eval.json");
    ok(&jetpilot(
        &["eval", "--expert", "--seconds", "15", "--config"],
        &[&path_cfg, Path::new("--json"), &json],
    ));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["interventions"], 0, "{v}");
    // 15 s at the expert's 0.2 m/s is about 3 m of the 6.62 m loop (0.38 laps of the
    // 7.88 m path if it had stayed open).
    let laps = v["laps"].as_f64().unwrap();
    assert!((0.42..0.48).contains(&laps), "{v}");
    assert!(v["rewards"].as_u64().unwrap() > 300, "{v}");

    let il_out = dir.path().join("il");
    ok(&il(&cfg, &tub, &il_out, &["--epochs", "1"]));
    let out = dir.path().join("ddpg");
    ok(&ddpg(
        &path_cfg,
        &il_out.join("best.onnx"),
        &tub,
        &out,
        "2",
        "30",
        "3",
    ));
    assert_eq!(csv_rows(&out.join("ddpg_episodes.csv")).len(), 2);
    assert!(out.join("best.onnx").is_file());

    // `eval --compare-render`: the same poses in the replay and in the world it was
    // recorded in (the path road's poses are moved; the comparison moves them back). At a
    // recorded pose the replayed view is the recorded frame (a JPEG of 32x32 pixels) and
    // the rendered one is drawn at that pose: their pixels differ by the JPEG's error only
    // (measured: 3.2 levels; 3.7-4.8 at the moved and turned poses, which are re-projected).
    // With the path's shift (about 0.3 m) left out of the comparison they differ by 32.7,
    // and the test fails.
    //
    // The model is judged against its own reach, not against the moved poses' differences:
    // a 1-epoch model's outputs depend on the float rounding of the CPU that trained it
    // (an AMD EPYC failed the bound "half the moved poses' mean difference", 0.020 against
    // 0.027, that held where it was set). Over seeds 1-5 of `train il` there, the at-pose
    // steering difference was 0.009-0.032, 5-17 % of how far the rendered outputs move
    // across the offsets (their reach, 0.09-0.46); with the shift left out, 75 % and 143 %
    // (seeds 3 and 4).
    let cmp = dir.path().join("compare.json");
    let stdout = ok(&jetpilot(
        &["eval", "--config"],
        &[
            &path_cfg,
            Path::new("--model"),
            &il_out.join("best.onnx"),
            Path::new("--compare-render"),
            &cfg,
            Path::new("--json"),
            &cmp,
            Path::new("--png"),
            &dir.path().join("compare.png"),
        ],
    ));
    assert!(stdout.contains("corrections kept"), "{stdout}");
    // Two poses, three offsets each: rendered above replayed, 160-pixel tiles.
    let sheet = image::open(dir.path().join("compare.png")).unwrap();
    let gap = (sheet.width() - 6 * 160) / 7;
    assert_eq!(
        (sheet.width(), sheet.height()),
        (6 * 160 + 7 * gap, 2 * 160 + 3 * gap)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cmp).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 11, "{v}");
    assert!(v["poses"].as_u64().unwrap() >= 40, "{v}");
    let at_pose = &rows[0];
    assert!(at_pose["coverage"].as_f64().unwrap() > 0.99, "{v}");
    let field = |row: &serde_json::Value, key: &str| row[key].as_f64().unwrap();
    assert!(
        field(at_pose, "pixel_diff") < 8.0,
        "the views at the recorded pose, levels: {v}"
    );
    let rendered: Vec<f64> = rows.iter().map(|r| field(r, "rendered")).collect();
    let reach = rendered.iter().cloned().fold(f64::MIN, f64::max)
        - rendered.iter().cloned().fold(f64::MAX, f64::min);
    assert!(
        field(at_pose, "steering_diff") < 0.4 * reach,
        "the model's outputs at the recorded pose, against their reach {reach}: {v}"
    );
    // A replay config is needed, and a rendered world to compare with.
    let out = jetpilot(
        &["eval", "--config"],
        &[&cfg, Path::new("--compare-render"), &cfg],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("is not a replay"), "{err}");
}

/// EfficientNet-Lite0 through DDPG: a Lite0 actor (`model init --arch efficientnet-lite0`)
/// trains its 1280-wide head on frozen features, the critic reads 1280 features, and the
/// export is still a Lite0 whose backbone is the start's and which `jetpilot eval` drives.
/// A backbone that trains is ResNet-18 only, and says so naming the file.
#[test]
fn ddpg_trains_an_efficientnet_lite0_head_on_its_frozen_features() {
    use jetpilot::policy::onnx::{Arch, read_net_weights};
    let dir = tempfile::tempdir().unwrap();
    let cfg = sim_config(dir.path());
    let tub = demos(dir.path(), &cfg, "1");
    let init = dir.path().join("lite0.onnx");
    ok(&jetpilot(
        &[
            "model",
            "init",
            "--arch",
            "efficientnet-lite0",
            "--input-size",
            "32",
            "--head",
            "speed-steering",
            "--seed",
            "2",
            "-o",
        ],
        &[&init],
    ));
    let out = dir.path().join("ddpg");
    let text = ok(&ddpg(&cfg, &init, &tub, &out, "2", "24", "2"));
    assert!(text.contains("demonstration transitions"), "{text}");
    let (before, _) = read_net_weights(&init).unwrap();
    let (after, contract) = read_net_weights(&out.join("last.onnx")).unwrap();
    assert_eq!(after.arch(), Arch::EfficientNetLite0);
    assert_eq!(contract.input_size, SIZE);
    assert_eq!(after.tensors()["_fc.weight"].0, vec![2, 1280]);
    assert_ne!(
        after.tensors()["_fc.weight"].1,
        before.tensors()["_fc.weight"].1,
        "the head did not train"
    );
    for frozen in [
        "_conv_stem.weight",
        "_blocks.15._project_conv.weight",
        "_bn1.running_var",
    ] {
        assert_eq!(
            after.tensors()[frozen],
            before.tensors()[frozen],
            "{frozen} changed"
        );
    }
    ok(&jetpilot(
        &["eval", "--seconds", "2", "--config"],
        &[&cfg, Path::new("--model"), &out.join("best.onnx")],
    ));

    let refused = jetpilot(
        &["train", "ddpg", "--train-backbone", "--episodes", "1"],
        &[
            Path::new("--sim"),
            &cfg,
            Path::new("--init"),
            &init,
            Path::new("--out"),
            &dir.path().join("refused"),
        ],
    );
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success());
    assert!(
        stderr.contains("lite0.onnx") && stderr.contains("ResNet-18 only"),
        "{stderr}"
    );
}

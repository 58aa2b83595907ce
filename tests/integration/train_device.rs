//! The trainer on burn's GPU backends (`train --device`), against the Flex CPU backend.
//!
//! wgpu runs here on Mesa's lavapipe, a CPU Vulkan driver (`wgpu:cpu`; scripts/test.sh
//! installs `mesa-vulkan-drivers`), so the GPU code path (shaders compiled by cubecl,
//! buffers, read-backs) is exercised on any machine: the same ResNet-18 forward pass, the
//! same imitation-learning epochs and the same DDPG updates must agree with Flex. A device
//! that is not built in or not there is a clear error before any work.
#![cfg(feature = "train")]

use std::process::Command;

fn jetpilot(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn an_unknown_or_unbuilt_device_is_a_clear_error_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let out = dir.path().display().to_string();
    let run = jetpilot(&[
        "train", "il", "--data", &out, "--out", &out, "--device", "gpu",
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        err.contains("unknown device `gpu`") && err.contains("wgpu:cpu"),
        "{err}"
    );

    // CUDA is not built in: the run stops with the device named and the alternative, before
    // it creates its output folder.
    let out = out_dir.display().to_string();
    let run = jetpilot(&[
        "train",
        "ddpg",
        "--sim",
        "config/sim.toml",
        "--out",
        &out,
        "--device",
        "cuda:99",
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        err.contains("device `cuda:99`") && err.contains("--device wgpu"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out_dir.exists());
}

/// A wgpu adapter of a kind this machine has none of is an error, not a panic.
#[cfg(feature = "train-wgpu")]
#[test]
fn a_missing_wgpu_adapter_is_an_error() {
    let err = "wgpu:discrete:99"
        .parse::<jetpilot::train::TrainDevice>()
        .unwrap()
        .open()
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("wgpu:discrete:99") && err.contains("cannot be opened"),
        "{err}"
    );
}

#[cfg(feature = "train-wgpu")]
mod wgpu {
    use burn::tensor::{Device, Tensor, TensorData};
    use jetpilot::policy::onnx::Resnet18Weights;
    use jetpilot::policy::{ModelContract, OutputKind};
    use jetpilot::train::augment::Augment;
    use jetpilot::train::data::{Dataset, LabelMap};
    use jetpilot::train::ddpg::agent::{Agent, AgentConfig};
    use jetpilot::train::ddpg::features::Head;
    /// ResNet-18's feature width.
    const FEATURES: usize = 512;
    use jetpilot::train::ddpg::replay::{Replay, Transition};
    use jetpilot::train::device::WgpuAdapter;
    use jetpilot::train::il::{self, IlOptions};
    use jetpilot::train::{Resnet18, TrainDevice};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn lavapipe() -> Device {
        TrainDevice::Wgpu(WgpuAdapter::Cpu)
            .open()
            .expect("wgpu:cpu (Mesa's lavapipe; scripts/test.sh installs mesa-vulkan-drivers)")
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn resnet18_forward_on_wgpu_matches_flex() {
        const S: usize = 64;
        let w = Resnet18Weights::random(2, 3);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let x: Vec<f32> = (0..2 * 3 * S * S)
            .map(|_| rng.random_range(-2.0..2.0))
            .collect();
        let forward = |device: &Device| {
            let net = Resnet18::from_weights(&w, device).unwrap();
            let x = Tensor::<4>::from_data(TensorData::new(x.clone(), [2, 3, S, S]), device);
            net.forward(x).into_data().try_into_vec::<f32>().unwrap()
        };
        let flex = forward(&Device::flex());
        let gpu = forward(&lavapipe());
        let diff = max_abs_diff(&flex, &gpu);
        println!("ResNet-18 64x64: flex {flex:?}, wgpu:cpu {gpu:?}, max |diff| {diff:e}");
        assert!(flex.iter().any(|v| v.abs() > 1e-3), "{flex:?}");
        assert!(diff <= 1e-4, "max |flex - wgpu| = {diff}");
    }

    // One training step's gradients on wgpu and on Flex: tests/integration/train_gradients.rs checks
    // each against a float64 reference (backend against backend is ill-posed there).

    /// Imitation learning on `wgpu:cpu` runs its whole loop: epochs, checkpoints, the
    /// export, the learning curve, and `--resume`, whose saved Adam state burn rebuilds on
    /// its default device (Flex) and moves to the training device.
    #[test]
    fn imitation_learning_runs_and_resumes_on_wgpu() {
        const S: u32 = 32;
        let data = Dataset::random(S, 12, 2);
        let contract = ModelContract {
            input_size: S,
            output: OutputKind::SpeedSteering,
            ..ModelContract::default()
        };
        let labels = LabelMap::new(OutputKind::SpeedSteering, &Default::default());
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("wgpu");
        let run = |epochs: usize, resume: bool| {
            let mut opts = IlOptions::paper(out.clone(), contract.clone(), labels);
            opts.epochs = epochs;
            opts.batch = 4;
            opts.test_fraction = 0.25;
            opts.augment = Augment::NONE;
            opts.progress = false;
            opts.resume = resume;
            opts.device = TrainDevice::Wgpu(WgpuAdapter::Cpu);
            let mut epochs = Vec::new();
            il::train(&data, &opts, |e| {
                epochs.push((e.epoch, e.train_loss, e.test_loss))
            })
            .unwrap();
            epochs
        };
        let first = run(1, false);
        let resumed = run(2, true);
        println!("wgpu:cpu epochs (epoch, train, test): {first:?} then {resumed:?}");
        assert_eq!(first.len(), 1);
        assert_eq!(resumed.len(), 1);
        assert_eq!(resumed[0].0, 2);
        for (_, train, test) in first.iter().chain(&resumed) {
            assert!(train.is_finite() && test.is_finite() && *train > 0.0);
        }
        for file in [
            "best.onnx",
            "last.onnx",
            "il_log.csv",
            "il_curve.png",
            "il_optim.bpk",
        ] {
            assert!(out.join(file).is_file(), "{file}");
        }
        let (model, c) =
            jetpilot::train::load_onnx(&out.join("last.onnx"), &Device::flex()).unwrap();
        assert_eq!(c.output, OutputKind::SpeedSteering);
        let trained = model.to_weights().unwrap();
        let init = Resnet18Weights::random(2, 0);
        assert_ne!(trained.tensors["fc.weight"], init.tensors["fc.weight"]);
        assert_ne!(
            trained.tensors["conv1.weight"],
            init.tensors["conv1.weight"]
        );
    }

    #[test]
    fn ddpg_updates_on_wgpu_follow_the_flex_ones() {
        let weights = Resnet18Weights::random(2, 4);
        let head =
            Head::from_weights(&jetpilot::policy::onnx::NetWeights::Resnet18(weights)).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut replay = Replay::new(64);
        for i in 0..64 {
            replay.push(Transition {
                features: (0..FEATURES).map(|_| rng.random_range(0.0..2.0)).collect(),
                action: [rng.random_range(0.0..1.0), rng.random_range(-1.0..1.0)],
                reward: rng.random(),
                next_features: (0..FEATURES).map(|_| rng.random_range(0.0..2.0)).collect(),
                discount: 0.98,
                demo: i % 4 == 0,
            });
        }
        let probe: Vec<f32> = (0..FEATURES).map(|_| rng.random_range(0.0..2.0)).collect();
        let run = |device: &Device| {
            let cfg = AgentConfig {
                batch: 16,
                ..AgentConfig::default()
            };
            let mut agent = Agent::new(cfg, &head, 0, device);
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            let mut critic = Vec::new();
            for step in 0..6 {
                let stats = agent.update(&replay, step % 2 == 1, &mut rng).unwrap();
                critic.push(stats.critic_loss as f32);
            }
            (critic, agent.head().unwrap().apply(&probe))
        };
        let (flex_loss, flex_action) = run(&Device::flex());
        let (gpu_loss, gpu_action) = run(&lavapipe());
        println!(
            "critic losses flex {flex_loss:?} wgpu {gpu_loss:?}; actions {flex_action:?} {gpu_action:?}"
        );
        let rel = flex_loss
            .iter()
            .zip(&gpu_loss)
            .map(|(f, g)| (f - g).abs() / f.abs().max(1e-6))
            .fold(0.0f32, f32::max);
        assert!(
            rel <= 1e-2,
            "critic losses flex {flex_loss:?} vs wgpu {gpu_loss:?}"
        );
        assert!(max_abs_diff(&flex_action, &gpu_action) <= 1e-3);
        assert_ne!(flex_action, head.apply(&probe), "the actor was updated");
    }
}

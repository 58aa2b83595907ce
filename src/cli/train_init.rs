//! `train il --init` and `--arch`: which file a run starts from and which network it is,
//! and the input normalisation that goes with pretrained weights.

use std::path::{Path, PathBuf};

use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::Arch;
use jetpilot::policy::pytorch;

/// Where a run starts: the file, its architecture, and an ONNX file's contract.
pub struct Start {
    pub init: Option<PathBuf>,
    pub arch: Arch,
    pub contract: Option<ModelContract>,
}

/// `--init imagenet` becomes the cached ImageNet file of the architecture (Lite0 unless
/// `--arch` says otherwise); a `.pth` file keeps `--arch` (default ResNet-18); an ONNX
/// file's architecture is its own, and an `--arch` that disagrees is refused.
pub fn resolve(init: Option<&Path>, arch: Option<Arch>) -> anyhow::Result<Start> {
    let state_dict = |init: PathBuf, arch: Arch| Start {
        init: Some(init),
        arch,
        contract: None,
    };
    match init {
        None => Ok(Start {
            init: None,
            arch: arch.unwrap_or(Arch::Resnet18),
            contract: None,
        }),
        Some(p) if p == Path::new("imagenet") => {
            let arch = arch.unwrap_or(Arch::EfficientNetLite0);
            Ok(state_dict(pytorch::imagenet_weights(arch)?, arch))
        }
        Some(p) if is_pth(p) => Ok(state_dict(p.to_path_buf(), arch.unwrap_or(Arch::Resnet18))),
        Some(p) => {
            let (weights, contract) = jetpilot::policy::onnx::read_net_weights(p)?;
            let own = weights.arch();
            if let Some(a) = arch.filter(|a| *a != own) {
                anyhow::bail!(
                    "{}: a {} model, but --arch {} was given; leave --arch out for an ONNX --init",
                    p.display(),
                    own.title(),
                    a.name()
                );
            }
            Ok(Start {
                init: Some(p.to_path_buf()),
                arch: own,
                contract: Some(contract),
            })
        }
    }
}

/// Pretrained weights expect the normalisation they were trained with: a state dict gets
/// the architecture's ImageNet normalisation, an ONNX file its own channel order, mean and
/// std. Said in the log when it changes the config's.
pub fn adopt_normalisation(start: &Start, contract: &mut ModelContract) {
    let Some(path) = &start.init else { return };
    let before = contract.clone();
    match &start.contract {
        Some(c) => {
            contract.channel_order = c.channel_order;
            contract.mean = c.mean;
            contract.std = c.std;
        }
        None => (contract.mean, contract.std) = start.arch.imagenet_normalisation(),
    }
    if *contract != before {
        // Only what changed here: the input size and the head are settled later.
        tracing::info!(
            init = %path.display(),
            "input normalisation from the start's weights: {}, mean {:?}, std {:?}",
            contract.channel_order.as_str(),
            contract.mean,
            contract.std
        );
    }
}

fn is_pth(p: &Path) -> bool {
    matches!(p.extension().and_then(|e| e.to_str()), Some("pth" | "pt"))
}

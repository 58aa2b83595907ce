//! `train il --init` and `--arch`: which file a run starts from and which network it is,
//! and the input normalisation that goes with pretrained weights.

use std::path::{Path, PathBuf};

use jetpilot::policy::ModelContract;
use jetpilot::policy::onnx::Arch;
use jetpilot::policy::pytorch;

/// `--init imagenet` becomes the cached ImageNet file of the architecture (Lite0 unless
/// `--arch` says otherwise); a `.pth` file keeps `--arch` (default ResNet-18); an ONNX
/// file's architecture is its own, and an `--arch` that disagrees is refused.
pub fn resolve(init: Option<&Path>, arch: Option<Arch>) -> anyhow::Result<(Option<PathBuf>, Arch)> {
    match init {
        None => Ok((None, arch.unwrap_or(Arch::Resnet18))),
        Some(p) if p == Path::new("imagenet") => {
            let arch = arch.unwrap_or(Arch::EfficientNetLite0);
            Ok((Some(pytorch::imagenet_weights(arch)?), arch))
        }
        Some(p) if is_pth(p) => Ok((Some(p.to_path_buf()), arch.unwrap_or(Arch::Resnet18))),
        Some(p) => {
            let (weights, _) = jetpilot::train::read_onnx(p)?;
            let own = weights.arch();
            if let Some(a) = arch.filter(|a| *a != own) {
                anyhow::bail!(
                    "{}: a {} model, but --arch {} was given; leave --arch out for an ONNX --init",
                    p.display(),
                    own.title(),
                    a.name()
                );
            }
            Ok((Some(p.to_path_buf()), own))
        }
    }
}

/// Pretrained weights expect the normalisation they were trained with: a state dict gets
/// the architecture's ImageNet normalisation, an ONNX file with a contract its own
/// channel order, mean and std. Said in the log when it changes the config's.
pub fn adopt_normalisation(
    init: Option<&Path>,
    arch: Arch,
    contract: &mut ModelContract,
) -> anyhow::Result<()> {
    let Some(path) = init else { return Ok(()) };
    let before = contract.clone();
    if is_pth(path) {
        (contract.mean, contract.std) = arch.imagenet_normalisation();
    } else if let Some(c) = read_contract(path)? {
        contract.channel_order = c.channel_order;
        contract.mean = c.mean;
        contract.std = c.std;
    }
    if *contract != before {
        tracing::info!(
            init = %path.display(),
            "input normalisation from the start's weights: {contract}"
        );
    }
    Ok(())
}

fn read_contract(path: &Path) -> anyhow::Result<Option<ModelContract>> {
    let s = jetpilot::policy::onnx::inspect_file(path)?;
    Ok(s.contract()?)
}

fn is_pth(p: &Path) -> bool {
    matches!(p.extension().and_then(|e| e.to_str()), Some("pth" | "pt"))
}

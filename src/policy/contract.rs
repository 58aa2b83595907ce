//! The model contract: what a policy network expects as input and what its two outputs mean.
//!
//! The contract travels inside the ONNX file as `metadata_props` (keys below), so a model
//! trained by jetpilot carries everything the daemon needs. A model without that metadata
//! (for example one exported from JetBot's PyTorch notebook) is given its contract by the
//! `[model]` section of the config.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

/// Metadata key prefix used in ONNX `metadata_props`.
pub const META_PREFIX: &str = "jetpilot.";
pub const META_CONTRACT_VERSION: &str = "jetpilot.contract_version";
pub const META_INPUT_SIZE: &str = "jetpilot.input_size";
pub const META_CHANNEL_ORDER: &str = "jetpilot.channel_order";
pub const META_MEAN: &str = "jetpilot.mean";
pub const META_STD: &str = "jetpilot.std";
pub const META_OUTPUT: &str = "jetpilot.output";
/// Version of the metadata layout written by this build.
pub const CONTRACT_VERSION: u32 = 1;

/// ImageNet normalisation, as used by torchvision and JetBot's notebooks.
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// The order of colour planes in the network input tensor.
///
/// JetBot's road-following trainer feeds BGR (OpenCV frames) while torchvision's ImageNet
/// weights expect RGB, so the order must be stated, never assumed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChannelOrder {
    Rgb,
    Bgr,
}

impl ChannelOrder {
    pub fn as_str(self) -> &'static str {
        match self {
            ChannelOrder::Rgb => "rgb",
            ChannelOrder::Bgr => "bgr",
        }
    }
}

/// What the model's two outputs mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputKind {
    /// JetBot road following: `[x, y]`, the target point in the image, each in about -1..1
    /// (`x = (px - 112) / 112`, `y = (py - 112) / 112` for a 224x224 frame).
    Xy,
    /// `[speed, steering]`: speed in 0..1 scales `speed_gain`; steering in -1..1, positive
    /// turns right.
    SpeedSteering,
}

impl OutputKind {
    pub fn as_str(self) -> &'static str {
        match self {
            OutputKind::Xy => "xy",
            OutputKind::SpeedSteering => "speed_steering",
        }
    }
}

/// Input size, channel order, normalisation and output meaning of a policy network.
/// The input tensor is `[1, 3, input_size, input_size]` f32, NCHW.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelContract {
    pub input_size: u32,
    pub channel_order: ChannelOrder,
    pub mean: [f32; 3],
    pub std: [f32; 3],
    pub output: OutputKind,
}

impl Default for ModelContract {
    /// JetBot's road-following model: 224x224, ImageNet normalisation, target point.
    /// Channel order RGB (jetpilot's own models); set `bgr` for JetBot notebook exports.
    fn default() -> Self {
        Self {
            input_size: 224,
            channel_order: ChannelOrder::Rgb,
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            output: OutputKind::Xy,
        }
    }
}

/// A contract key in a model's metadata that is missing or cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("model metadata key `{key}` = {value:?} is invalid: expected {expected}")]
pub struct ContractError {
    pub key: String,
    pub value: String,
    pub expected: &'static str,
}

impl ModelContract {
    /// The `metadata_props` entries that record this contract.
    pub fn to_metadata(&self) -> Vec<(String, String)> {
        vec![
            (
                META_CONTRACT_VERSION.to_string(),
                CONTRACT_VERSION.to_string(),
            ),
            (META_INPUT_SIZE.to_string(), self.input_size.to_string()),
            (
                META_CHANNEL_ORDER.to_string(),
                self.channel_order.as_str().to_string(),
            ),
            (META_MEAN.to_string(), join_floats(&self.mean)),
            (META_STD.to_string(), join_floats(&self.std)),
            (META_OUTPUT.to_string(), self.output.as_str().to_string()),
        ]
    }

    /// The contract for a model without jetpilot metadata whose graph input has the dims
    /// `dims` (ONNX order `[n, c, h, w]`, a negative value for a size fixed only at run
    /// time). A fixed square image input `[n, 3, S, S]` with S from 32 to 1024 is the model's
    /// own statement of its size, so `input_size` becomes S; every other key, and the size
    /// of a model whose input is dynamic, comes from `self` (the config's `[model]` keys).
    pub fn for_unlabelled_input(&self, dims: &[i64]) -> Self {
        let mut c = self.clone();
        if let [_, 3, h, w] = dims
            && h == w
            && (32..=1024).contains(h)
        {
            c.input_size = *h as u32;
        }
        c
    }

    /// Reads the contract from model metadata. `Ok(None)` when the model carries no
    /// jetpilot contract at all (no `jetpilot.contract_version` key); an error when it
    /// carries one that is incomplete or malformed.
    pub fn from_metadata(meta: &BTreeMap<String, String>) -> Result<Option<Self>, ContractError> {
        let Some(version) = meta.get(META_CONTRACT_VERSION) else {
            return Ok(None);
        };
        if version.trim() != CONTRACT_VERSION.to_string() {
            return Err(ContractError {
                key: META_CONTRACT_VERSION.into(),
                value: version.clone(),
                expected: "1 (the only contract version this build reads)",
            });
        }
        let get = |key: &str, expected: &'static str| {
            meta.get(key).ok_or_else(|| ContractError {
                key: key.into(),
                value: String::new(),
                expected,
            })
        };
        let size_raw = get(META_INPUT_SIZE, "an integer from 32 to 1024")?;
        let input_size = size_raw
            .trim()
            .parse::<u32>()
            .ok()
            .filter(|s| (32..=1024).contains(s))
            .ok_or_else(|| ContractError {
                key: META_INPUT_SIZE.into(),
                value: size_raw.clone(),
                expected: "an integer from 32 to 1024",
            })?;
        let order_raw = get(META_CHANNEL_ORDER, "`rgb` or `bgr`")?;
        let channel_order = match order_raw.trim() {
            "rgb" => ChannelOrder::Rgb,
            "bgr" => ChannelOrder::Bgr,
            _ => {
                return Err(ContractError {
                    key: META_CHANNEL_ORDER.into(),
                    value: order_raw.clone(),
                    expected: "`rgb` or `bgr`",
                });
            }
        };
        let mean = parse_triplet(meta, META_MEAN, false)?;
        let std = parse_triplet(meta, META_STD, true)?;
        let output_raw = get(META_OUTPUT, "`xy` or `speed_steering`")?;
        let output = match output_raw.trim() {
            "xy" => OutputKind::Xy,
            "speed_steering" => OutputKind::SpeedSteering,
            _ => {
                return Err(ContractError {
                    key: META_OUTPUT.into(),
                    value: output_raw.clone(),
                    expected: "`xy` or `speed_steering`",
                });
            }
        };
        Ok(Some(Self {
            input_size,
            channel_order,
            mean,
            std,
            output,
        }))
    }
}

impl fmt::Display for ModelContract {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "input [1,3,{s},{s}] {order}, mean [{mean}], std [{std}], output {out}",
            s = self.input_size,
            order = self.channel_order.as_str(),
            mean = join_floats(&self.mean),
            std = join_floats(&self.std),
            out = self.output.as_str()
        )
    }
}

fn join_floats(v: &[f32; 3]) -> String {
    v.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

fn parse_triplet(
    meta: &BTreeMap<String, String>,
    key: &str,
    positive: bool,
) -> Result<[f32; 3], ContractError> {
    let expected = if positive {
        "three positive numbers separated by commas"
    } else {
        "three numbers separated by commas"
    };
    let raw = meta.get(key).ok_or_else(|| ContractError {
        key: key.into(),
        value: String::new(),
        expected,
    })?;
    let bad = || ContractError {
        key: key.into(),
        value: raw.clone(),
        expected,
    };
    let values: Vec<f32> = raw
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    let arr: [f32; 3] = values.try_into().map_err(|_| bad())?;
    if arr
        .iter()
        .any(|v| !v.is_finite() || (positive && *v <= 0.0))
    {
        return Err(bad());
    }
    Ok(arr)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metadata_round_trip() {
        let c = ModelContract {
            input_size: 112,
            channel_order: ChannelOrder::Bgr,
            mean: [0.5, 0.25, 0.125],
            std: [0.2, 0.3, 0.4],
            output: OutputKind::SpeedSteering,
        };
        let meta: BTreeMap<_, _> = c.to_metadata().into_iter().collect();
        assert_eq!(ModelContract::from_metadata(&meta).unwrap(), Some(c));
    }

    #[test]
    fn unlabelled_model_takes_its_fixed_square_input() {
        let config = ModelContract {
            input_size: 96,
            channel_order: ChannelOrder::Bgr,
            ..ModelContract::default()
        };
        // JetBot's notebook export: a fixed [1,3,224,224] input.
        let c = config.for_unlabelled_input(&[1, 3, 224, 224]);
        assert_eq!(c.input_size, 224);
        assert_eq!(
            c.channel_order,
            ChannelOrder::Bgr,
            "other keys stay the config's"
        );
        // A dynamic batch does not matter; a dynamic or non-square or odd image does.
        assert_eq!(
            config.for_unlabelled_input(&[-1, 3, 112, 112]).input_size,
            112
        );
        assert_eq!(config.for_unlabelled_input(&[1, 3, -1, -1]).input_size, 96);
        assert_eq!(
            config.for_unlabelled_input(&[1, 3, 120, 160]).input_size,
            96
        );
        assert_eq!(
            config.for_unlabelled_input(&[1, 1, 112, 112]).input_size,
            96
        );
        assert_eq!(config.for_unlabelled_input(&[1, 3, 16, 16]).input_size, 96);
        assert_eq!(config.for_unlabelled_input(&[1, 3, 224]).input_size, 96);
    }

    #[test]
    fn no_metadata_means_no_contract() {
        let mut meta = BTreeMap::new();
        meta.insert("producer".to_string(), "pytorch".to_string());
        assert_eq!(ModelContract::from_metadata(&meta).unwrap(), None);
    }

    #[test]
    fn bad_metadata_names_the_key() {
        let mut meta: BTreeMap<_, _> = ModelContract::default().to_metadata().into_iter().collect();
        meta.insert(META_STD.into(), "0.2,0,0.2".into());
        let err = ModelContract::from_metadata(&meta).unwrap_err();
        assert_eq!(err.key, META_STD);
        assert!(err.to_string().contains("positive"), "{err}");
        meta.remove(META_STD);
        meta.insert(META_OUTPUT.into(), "angle".into());
        let mut m2 = meta.clone();
        m2.insert(META_STD.into(), "0.2,0.2,0.2".into());
        let err = ModelContract::from_metadata(&m2).unwrap_err();
        assert_eq!(err.key, META_OUTPUT);
    }
}

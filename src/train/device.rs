//! Which burn device the trainer computes on (`train ... --device`).
//!
//! burn 0.22 picks its backend at run time through its `Device`, so the model code is the
//! same everywhere; this module owns the user's choice and turns it into a device:
//!
//! - `flex` (the default): burn's pure-Rust CPU backend, always built with `train`;
//! - `wgpu`, `wgpu:discrete`, `wgpu:integrated`, `wgpu:cpu`: burn's wgpu backend (Vulkan,
//!   Metal or DX12; `wgpu:cpu` is a software driver such as Mesa's lavapipe), built with the
//!   cargo feature `train-wgpu`;
//! - `cuda`, `cuda:N` are understood only to say what to use instead: burn 0.22's CUDA
//!   backend downloads an LLVM bundle from GitHub while it builds, so jetpilot does not
//!   build it; `wgpu` reaches NVIDIA GPUs through their Vulkan driver.
//!
//! A backend whose feature is not built, or whose device cannot be opened, is a clear
//! [`TrainError::Device`] before any training starts, never a panic halfway through.

use std::fmt;
use std::str::FromStr;
use std::sync::{Arc, Mutex};

use burn::tensor::{Device, Tensor, TensorData};

use super::TrainError;

/// The device a training run asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TrainDevice {
    /// burn's Flex CPU backend.
    #[default]
    Flex,
    /// burn's wgpu backend on an adapter of this kind.
    Wgpu(WgpuAdapter),
    /// burn's CUDA backend on this GPU index: not built (see the module doc), an error
    /// that points to `wgpu`.
    Cuda(usize),
}

/// Which wgpu adapter: wgpu's own pick (a high-power GPU first), or one of a kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WgpuAdapter {
    Default,
    Discrete(usize),
    Integrated(usize),
    /// A software rasteriser (Mesa's lavapipe, llvmpipe, WARP).
    Cpu,
}

/// The values `--device` accepts, for help texts and errors.
pub const DEVICE_CHOICES: &str =
    "flex, wgpu, wgpu:discrete[:N], wgpu:integrated[:N], wgpu:cpu, cuda, cuda:N";

impl FromStr for TrainDevice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase();
        let parts: Vec<&str> = lower.split(':').collect();
        let index = |i: usize| -> Result<usize, String> {
            match parts.get(i) {
                None => Ok(0),
                Some(n) => n
                    .parse()
                    .map_err(|_| format!("`{s}`: `{n}` is not a device index")),
            }
        };
        let device = match parts.as_slice() {
            ["flex"] | ["cpu"] => Self::Flex,
            ["wgpu"] => Self::Wgpu(WgpuAdapter::Default),
            ["wgpu", "cpu"] => Self::Wgpu(WgpuAdapter::Cpu),
            ["wgpu", "discrete", ..] if parts.len() <= 3 => {
                Self::Wgpu(WgpuAdapter::Discrete(index(2)?))
            }
            ["wgpu", "integrated", ..] if parts.len() <= 3 => {
                Self::Wgpu(WgpuAdapter::Integrated(index(2)?))
            }
            ["cuda", ..] if parts.len() <= 2 => Self::Cuda(index(1)?),
            _ => {
                return Err(format!(
                    "unknown device `{s}`; expected one of: {DEVICE_CHOICES}"
                ));
            }
        };
        Ok(device)
    }
}

impl fmt::Display for TrainDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Flex => write!(f, "flex"),
            Self::Wgpu(WgpuAdapter::Default) => write!(f, "wgpu"),
            Self::Wgpu(WgpuAdapter::Discrete(i)) => write!(f, "wgpu:discrete:{i}"),
            Self::Wgpu(WgpuAdapter::Integrated(i)) => write!(f, "wgpu:integrated:{i}"),
            Self::Wgpu(WgpuAdapter::Cpu) => write!(f, "wgpu:cpu"),
            Self::Cuda(i) => write!(f, "cuda:{i}"),
        }
    }
}

impl TrainDevice {
    /// The burn device, not yet opened.
    fn burn(self) -> Result<Device, TrainError> {
        match self {
            Self::Flex => Ok(Device::flex()),
            Self::Wgpu(adapter) => wgpu_device(self, adapter),
            Self::Cuda(index) => cuda_device(self, index),
        }
    }

    /// The burn device, opened and checked with a tiny round trip, so a missing driver or
    /// adapter is an error here rather than a panic in the first training step.
    pub fn open(self) -> Result<Device, TrainError> {
        let device = self.burn()?;
        if self == Self::Flex {
            return Ok(device);
        }
        let probe = device.clone();
        catch_backend_panic(move || round_trip(&probe)).map_err(|reason| TrainError::Device {
            device: self.to_string(),
            reason: format!("cannot be opened: {reason}"),
        })?;
        Ok(device)
    }
}

/// Checks burn's default device, on which burn rebuilds a restored optimiser state before
/// moving it to the parameters' device. It is `BURN_DEVICE`, else the first GPU backend
/// built in (CUDA before wgpu before Flex), which need not be the device training runs on;
/// the `jetpilot` binary sets `BURN_DEVICE=flex` when it is unset, and so does
/// `.cargo/config.toml` for `cargo test` and `cargo run`.
pub fn check_default_device() -> Result<(), TrainError> {
    catch_backend_panic(|| round_trip(&Device::default())).map_err(|reason| TrainError::Device {
        device: format!(
            "burn's default (BURN_DEVICE={})",
            std::env::var("BURN_DEVICE").unwrap_or_else(|_| "unset".into())
        ),
        reason: format!("cannot be opened: {reason}; set BURN_DEVICE=flex"),
    })
}

/// Doubles a two-element tensor on `device` and reads it back.
fn round_trip(device: &Device) -> Result<(), String> {
    let t = Tensor::<1>::from_data(TensorData::new(vec![1.0f32, 2.0], [2]), device);
    match (t * 2.0).into_data().try_into_vec::<f32>() {
        Ok(v) if v == [2.0, 4.0] => Ok(()),
        Ok(v) => Err(format!("a test computation returned {v:?}")),
        Err(e) => Err(format!("{e:?}")),
    }
}

/// Runs `f`, turning a backend's panic (a missing driver, no adapter) into its message;
/// the panic hook only records meanwhile, so the user sees one error, not a crash report.
/// A backend may panic on its own device thread and answer this one with a bare channel
/// error: the first recorded message, which says what was missing, is the one reported.
fn catch_backend_panic(f: impl FnOnce() -> Result<(), String>) -> Result<(), String> {
    let first = Arc::new(Mutex::new(None::<String>));
    let hook = std::panic::take_hook();
    let record = Arc::clone(&first);
    std::panic::set_hook(Box::new(move |info| {
        if let Ok(mut slot) = record.lock() {
            slot.get_or_insert_with(|| panic_message(info.payload()));
        }
    }));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    let recorded = first.lock().ok().and_then(|mut slot| slot.take());
    match (result, recorded) {
        (Ok(Ok(())), _) => Ok(()),
        (_, Some(message)) => Err(message),
        (Ok(Err(e)), None) => Err(e),
        (Err(panic), None) => Err(panic_message(panic.as_ref())),
    }
}

fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = panic.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = panic.downcast_ref::<String>() {
        s.clone()
    } else {
        "the backend panicked".to_string()
    }
}

#[cfg(feature = "train-wgpu")]
fn wgpu_device(_: TrainDevice, adapter: WgpuAdapter) -> Result<Device, TrainError> {
    use burn::tensor::DeviceKind;
    let kind = match adapter {
        WgpuAdapter::Default => DeviceKind::DefaultDevice,
        WgpuAdapter::Discrete(i) => DeviceKind::DiscreteGpu(i),
        WgpuAdapter::Integrated(i) => DeviceKind::IntegratedGpu(i),
        WgpuAdapter::Cpu => DeviceKind::Cpu,
    };
    Ok(Device::wgpu(kind))
}

#[cfg(not(feature = "train-wgpu"))]
fn wgpu_device(device: TrainDevice, _: WgpuAdapter) -> Result<Device, TrainError> {
    Err(TrainError::Device {
        device: device.to_string(),
        reason: "this build has no such backend; rebuild with \
                 `cargo build --release --features train-wgpu`"
            .into(),
    })
}

fn cuda_device(device: TrainDevice, _: usize) -> Result<Device, TrainError> {
    Err(TrainError::Device {
        device: device.to_string(),
        reason: "jetpilot is built without burn's CUDA backend (it downloads LLVM while it \
                 builds); use --device wgpu, which runs on NVIDIA GPUs through Vulkan \
                 (build feature `train-wgpu`)"
            .into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_names_parse_and_print_back() {
        let cases = [
            ("flex", TrainDevice::Flex, "flex"),
            ("CPU", TrainDevice::Flex, "flex"),
            ("wgpu", TrainDevice::Wgpu(WgpuAdapter::Default), "wgpu"),
            ("wgpu:cpu", TrainDevice::Wgpu(WgpuAdapter::Cpu), "wgpu:cpu"),
            (
                "wgpu:discrete",
                TrainDevice::Wgpu(WgpuAdapter::Discrete(0)),
                "wgpu:discrete:0",
            ),
            (
                "wgpu:integrated:1",
                TrainDevice::Wgpu(WgpuAdapter::Integrated(1)),
                "wgpu:integrated:1",
            ),
            ("cuda", TrainDevice::Cuda(0), "cuda:0"),
            ("cuda:3", TrainDevice::Cuda(3), "cuda:3"),
        ];
        for (text, device, shown) in cases {
            let parsed: TrainDevice = text.parse().unwrap();
            assert_eq!(parsed, device, "{text}");
            assert_eq!(parsed.to_string(), shown);
            assert_eq!(shown.parse::<TrainDevice>().unwrap(), device);
        }
    }

    #[test]
    fn bad_device_names_say_what_is_accepted() {
        for bad in [
            "gpu",
            "cuda:x",
            "wgpu:discrete:1:2",
            "cuda:0:1",
            "wgpu:fast",
            "",
        ] {
            let err = bad.parse::<TrainDevice>().unwrap_err();
            assert!(
                err.contains("flex, wgpu") || err.contains("index"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn flex_opens_everywhere() {
        assert_eq!(TrainDevice::default(), TrainDevice::Flex);
        assert!(TrainDevice::Flex.open().is_ok());
    }

    #[test]
    fn cuda_points_to_wgpu() {
        let err = TrainDevice::Cuda(1).open().unwrap_err().to_string();
        assert!(
            err.contains("device `cuda:1`") && err.contains("--device wgpu"),
            "{err}"
        );
    }

    #[cfg(not(feature = "train-wgpu"))]
    #[test]
    fn an_unbuilt_backend_names_its_feature() {
        let err = TrainDevice::Wgpu(WgpuAdapter::Default)
            .open()
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("`wgpu`") && err.contains("--features train-wgpu"),
            "{err}"
        );
    }
}

//! The two blocking stages of the pipeline, each on its own thread:
//!
//! - capture: pulls frames from the [`FrameSource`] into the [`LatestFrame`] slot;
//! - infer: takes the newest frame, preprocesses it, runs the policy, checks the outputs
//!   and applies the steering law, then hands a [`Command`] to the actuator.
//!
//! Any failure becomes a [`StageMsg::Fault`]; the actuator stops the motors on it.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use super::DriveError;
use crate::camera::latest::{CloseGuard, SourceEnd, Wait};
use crate::camera::{Frame, FrameSource, LatestFrame};
use crate::clock::Clock;
use crate::control::{SteeringGains, SteeringLaw, WheelCommand};
use crate::policy::{ModelContract, Policy, Preprocessor};

/// A wheel command with where it came from and what it cost.
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    pub seq: u64,
    pub captured_at: Duration,
    /// The frame it was computed from (shared, not copied), for recording.
    pub frame: Arc<Vec<u8>>,
    pub width: u32,
    pub height: u32,
    pub outputs: [f32; 2],
    pub wheels: WheelCommand,
    pub preprocess: Duration,
    pub inference: Duration,
    pub control: Duration,
}

/// What the inference stage sends to the actuator.
#[derive(Debug)]
pub enum StageMsg {
    Command(Command),
    /// The frame source ended normally (a replay without `loop`).
    SourceFinished,
    /// The frame source failed and is recovering: stop the motors, keep running.
    SourceError(String),
    Fault(DriveError),
}

/// Runs the frame source until it ends, fails, or `cancel` fires.
pub fn capture(
    mut source: Box<dyn FrameSource>,
    slot: Arc<LatestFrame>,
    cancel: CancellationToken,
) {
    let guard = CloseGuard::new(&slot);
    while !cancel.is_cancelled() {
        match source.next_frame() {
            Ok(Some(frame)) => slot.put(frame),
            Ok(None) => {
                slot.close(SourceEnd::Finished);
                break;
            }
            Err(e) if source.recoverable() => {
                tracing::warn!(error = %e, "frame source failed; it is recovering");
                slot.put_error(e.to_string());
            }
            Err(e) => {
                slot.close(SourceEnd::Failed(e.to_string()));
                break;
            }
        }
    }
    guard.disarm();
}

/// What the inference stage needs besides its channels.
pub struct InferParams {
    pub gains: SteeringGains,
    /// Gain changes from the gamepad buttons, applied before the next frame.
    pub gains_updates: Option<tokio::sync::watch::Receiver<SteeringGains>>,
    pub max_abs_output: f32,
    pub clock: Arc<dyn Clock>,
}

/// The daemon's per-frame work, shared by the threaded daemon and the simulator's
/// lockstep loop: preprocess -> policy -> output check -> steering law.
pub struct FrameProcessor {
    pre: Preprocessor,
    law: SteeringLaw,
    last_capture: Option<Duration>,
    max_abs_output: f32,
}

impl FrameProcessor {
    pub fn new(contract: &ModelContract, gains: SteeringGains, max_abs_output: f32) -> Self {
        Self {
            pre: Preprocessor::new(contract),
            law: SteeringLaw::new(gains, contract.output),
            last_capture: None,
            max_abs_output,
        }
    }

    pub fn law_mut(&mut self) -> &mut SteeringLaw {
        &mut self.law
    }

    /// Turns one frame into a command, timing each step on `clock`.
    pub fn process(
        &mut self,
        policy: &mut dyn Policy,
        frame: &Frame,
        clock: &dyn Clock,
    ) -> Result<Command, DriveError> {
        let t0 = clock.now();
        let input = self
            .pre
            .run(frame.width, frame.height, &frame.rgb)
            .map_err(|source| DriveError::Preprocess {
                seq: frame.seq,
                source,
            })?;
        let t1 = clock.now();
        let outputs = policy.infer(input)?;
        let t2 = clock.now();
        if outputs
            .iter()
            .any(|v| !v.is_finite() || v.abs() > self.max_abs_output)
        {
            return Err(DriveError::BadOutput {
                seq: frame.seq,
                outputs,
                limit: self.max_abs_output,
            });
        }
        let dt = self
            .last_capture
            .map(|t| frame.captured_at.saturating_sub(t).as_secs_f32())
            .unwrap_or(0.0);
        self.last_capture = Some(frame.captured_at);
        let wheels = self.law.step(outputs, dt).wheels;
        let t3 = clock.now();
        Ok(Command {
            seq: frame.seq,
            captured_at: frame.captured_at,
            frame: frame.rgb.clone(),
            width: frame.width,
            height: frame.height,
            outputs,
            wheels,
            preprocess: t1.saturating_sub(t0),
            inference: t2.saturating_sub(t1),
            control: t3.saturating_sub(t2),
        })
    }
}

/// Takes frames from the slot until it closes, `cancel` fires or the actuator is gone.
pub fn infer(
    mut policy: Box<dyn Policy>,
    slot: Arc<LatestFrame>,
    tx: mpsc::Sender<StageMsg>,
    cancel: CancellationToken,
    params: InferParams,
) {
    let contract = policy.contract().clone();
    let mut processor = FrameProcessor::new(&contract, params.gains, params.max_abs_output);
    let clock = params.clock;
    let mut gains_updates = params.gains_updates;
    let send = |msg| tx.blocking_send(msg).is_ok();
    while !cancel.is_cancelled() {
        if let Some(rx) = gains_updates.as_mut()
            && rx.has_changed().unwrap_or(false)
        {
            processor.law_mut().set_gains(*rx.borrow_and_update());
        }
        let frame = match slot.wait(Duration::from_millis(50)) {
            Wait::Timeout => continue,
            Wait::Closed(SourceEnd::Finished) => {
                send(StageMsg::SourceFinished);
                return;
            }
            Wait::Closed(SourceEnd::Failed(msg)) => {
                send(StageMsg::Fault(DriveError::Camera(msg)));
                return;
            }
            Wait::Error(msg) => {
                if !send(StageMsg::SourceError(msg)) {
                    return;
                }
                continue;
            }
            Wait::Frame(f) => f,
        };
        let msg = match processor.process(policy.as_mut(), &frame, clock.as_ref()) {
            Ok(cmd) => StageMsg::Command(cmd),
            Err(e) => {
                send(StageMsg::Fault(e));
                return;
            }
        };
        if !send(msg) {
            return; // the actuator has finished
        }
    }
}

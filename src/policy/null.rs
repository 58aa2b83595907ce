//! [`NullPolicy`]: no model. It lets the frame path run (for recording demonstrations with
//! `jetpilot record` before any model exists) while the autopilot stays unavailable.

use super::{ModelContract, Policy, Result};

pub struct NullPolicy {
    contract: ModelContract,
}

impl NullPolicy {
    pub fn new(contract: ModelContract) -> Self {
        Self { contract }
    }
}

impl Policy for NullPolicy {
    fn contract(&self) -> &ModelContract {
        &self.contract
    }

    /// Straight ahead (`[0, 0.5]` as a JetBot target point, `[0, 0]` as speed/steering);
    /// never reaches the motors, since the autopilot cannot be switched on without a model.
    fn infer(&mut self, _input: &[f32]) -> Result<[f32; 2]> {
        Ok(match self.contract.output {
            super::OutputKind::Xy => [0.0, 0.5],
            super::OutputKind::SpeedSteering => [0.0, 0.0],
        })
    }

    fn describe(&self) -> String {
        "no model (recording only; autopilot unavailable)".into()
    }
}

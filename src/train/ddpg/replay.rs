//! The replay buffer: owns transitions in feature space, n-step returns, and DDPGfD's rule
//! that demonstrations stay for good while the agent's own transitions cycle through a ring.
//!
//! An n-step transition from step t holds
//!
//! ```text
//! f_t, a_t,  R = r_t + g r_{t+1} + ... + g^(m-1) r_{t+m-1},  f_{t+m},  discount = g^m
//! ```
//!
//! with m = n, or fewer at the end of an episode; `discount = 0` when the episode ended by
//! leaving the road (no bootstrap), `g^m` when it was cut by the step limit.

use std::collections::VecDeque;

use rand::Rng;

/// One stored transition.
#[derive(Debug, Clone, PartialEq)]
pub struct Transition {
    pub features: Vec<f32>,
    pub action: [f32; 2],
    /// The n-step discounted reward sum.
    pub reward: f32,
    pub next_features: Vec<f32>,
    /// Multiplies the bootstrapped value: `gamma^m`, or 0 at a terminal state.
    pub discount: f32,
    /// A demonstration (kept for good, eligible for the behaviour-cloning loss).
    pub demo: bool,
}

/// One environment step, before n-step accumulation.
#[derive(Debug, Clone)]
pub struct Step {
    pub features: Vec<f32>,
    pub action: [f32; 2],
    pub reward: f32,
}

/// Turns a stream of steps into n-step transitions.
#[derive(Debug)]
pub struct NStep {
    n: usize,
    gamma: f32,
    window: VecDeque<Step>,
}

impl NStep {
    pub fn new(n: usize, gamma: f32) -> Self {
        Self {
            n: n.max(1),
            gamma,
            window: VecDeque::new(),
        }
    }

    fn emit(&self, next_features: &[f32], terminal: bool, demo: bool) -> Option<Transition> {
        let first = self.window.front()?;
        let mut reward = 0.0;
        let mut g = 1.0;
        for s in &self.window {
            reward += g * s.reward;
            g *= self.gamma;
        }
        Some(Transition {
            features: first.features.clone(),
            action: first.action,
            reward,
            next_features: next_features.to_vec(),
            discount: if terminal { 0.0 } else { g },
            demo,
        })
    }

    /// Adds a step whose successor observation is `next_features`; returns the transition
    /// that became complete, if any.
    pub fn push(&mut self, step: Step, next_features: &[f32], demo: bool) -> Option<Transition> {
        self.window.push_back(step);
        if self.window.len() < self.n {
            return None;
        }
        let t = self.emit(next_features, false, demo);
        self.window.pop_front();
        t
    }

    /// Ends the episode after the last pushed step: `terminal` (left the road) or cut.
    /// Returns the shorter transitions still in the window.
    pub fn finish(&mut self, last_next: &[f32], terminal: bool, demo: bool) -> Vec<Transition> {
        let mut out = Vec::new();
        while !self.window.is_empty() {
            if let Some(t) = self.emit(last_next, terminal, demo) {
                out.push(t);
            }
            self.window.pop_front();
        }
        out
    }
}

/// Demonstrations (never evicted) and a ring of agent transitions.
#[derive(Debug, Default)]
pub struct Replay {
    demos: Vec<Transition>,
    agent: Vec<Transition>,
    capacity: usize,
    next: usize,
}

impl Replay {
    pub fn new(capacity: usize) -> Self {
        Self {
            demos: Vec::new(),
            agent: Vec::new(),
            capacity: capacity.max(1),
            next: 0,
        }
    }

    pub fn push(&mut self, t: Transition) {
        if t.demo {
            self.demos.push(t);
        } else if self.agent.len() < self.capacity {
            self.agent.push(t);
        } else {
            self.agent[self.next] = t;
            self.next = (self.next + 1) % self.capacity;
        }
    }

    pub fn len(&self) -> usize {
        self.demos.len() + self.agent.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn demos(&self) -> usize {
        self.demos.len()
    }

    pub fn get(&self, i: usize) -> &Transition {
        if i < self.demos.len() {
            &self.demos[i]
        } else {
            &self.agent[i - self.demos.len()]
        }
    }

    /// `n` indices drawn uniformly with replacement over demonstrations and agent
    /// transitions together.
    pub fn sample(&self, n: usize, rng: &mut impl Rng) -> Vec<usize> {
        let len = self.len();
        if len == 0 {
            return Vec::new();
        }
        (0..n).map(|_| rng.random_range(0..len)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn step(i: f32) -> Step {
        Step {
            features: vec![i],
            action: [i, -i],
            reward: i,
        }
    }

    #[test]
    fn three_step_returns_worked() {
        // gamma 0.5, rewards 1, 2, 3, 4 then the road is left.
        let mut n = NStep::new(3, 0.5);
        assert!(n.push(step(1.0), &[2.0], false).is_none());
        assert!(n.push(step(2.0), &[3.0], false).is_none());
        let t = n.push(step(3.0), &[4.0], false).unwrap();
        // 1 + 0.5*2 + 0.25*3 = 2.75, bootstrapped from f_3 with 0.125.
        assert_eq!(
            (t.features[0], t.reward, t.next_features[0], t.discount),
            (1.0, 2.75, 4.0, 0.125)
        );
        let t = n.push(step(4.0), &[5.0], false).unwrap();
        assert_eq!(
            (t.features[0], t.reward, t.discount),
            (2.0, 2.0 + 1.5 + 1.0, 0.125)
        );
        let rest = n.finish(&[5.0], true, false);
        // From step 3: 3 + 0.5*4 = 5, terminal; from step 4: 4, terminal.
        assert_eq!(rest.len(), 2);
        assert_eq!(
            (rest[0].features[0], rest[0].reward, rest[0].discount),
            (3.0, 5.0, 0.0)
        );
        assert_eq!(
            (rest[1].features[0], rest[1].reward, rest[1].discount),
            (4.0, 4.0, 0.0)
        );
        // Cut by the step limit instead: bootstrapped with gamma^m.
        let mut n = NStep::new(3, 0.5);
        n.push(step(1.0), &[2.0], false);
        let rest = n.finish(&[2.0], false, false);
        assert_eq!((rest[0].reward, rest[0].discount), (1.0, 0.5));
    }

    #[test]
    fn demonstrations_are_never_evicted() {
        let mut r = Replay::new(2);
        let t = |v: f32, demo| Transition {
            features: vec![v],
            action: [0.0; 2],
            reward: v,
            next_features: vec![v],
            discount: 0.9,
            demo,
        };
        r.push(t(100.0, true));
        for i in 0..5 {
            r.push(t(i as f32, false));
        }
        assert_eq!((r.len(), r.demos()), (3, 1));
        assert_eq!(r.get(0).reward, 100.0);
        // The ring holds the two newest: 3 and 4.
        let mut agent: Vec<f32> = (1..3).map(|i| r.get(i).reward).collect();
        agent.sort_by(f32::total_cmp);
        assert_eq!(agent, vec![3.0, 4.0]);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let idx = r.sample(300, &mut rng);
        assert!(idx.iter().all(|&i| i < 3));
        assert!(idx.contains(&0) && idx.contains(&2));
    }
}

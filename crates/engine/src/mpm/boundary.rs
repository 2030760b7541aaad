//! The model's boundary controls, for both integrators: effects of the model's list
//! ([`ControlEffect`]) that a controller drives, body forces on a set of particles and a
//! prescribed velocity or position of a boundary region (the clamped end of a rope). Each
//! control is a 3-vector sequence over the intervals of one schedule, piecewise constant or
//! piecewise linear in time, bounded per component; [`ControlPlan`] reads them.
use crate::mpm::SimError;
use crate::mpm::effect::Effect;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// How a control varies inside its intervals.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    /// One value per interval (`intervals` knots).
    Constant,
    /// Linear between knots at interval ends (`intervals + 1` knots), continuous in time.
    Linear,
}

impl Interpolation {
    /// Every value, in declaration order (the command line lists them by their serde names).
    pub const ALL: [Interpolation; 2] = [Interpolation::Constant, Interpolation::Linear];
}

/// Control intervals of `steps_per_interval` steps each, shared by all controls of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlSchedule {
    pub interpolation: Interpolation,
    pub steps_per_interval: usize,
    pub intervals: usize,
}

impl ControlSchedule {
    /// One piecewise-constant interval of `steps` steps: the schedule of a model without
    /// boundary controls.
    pub fn whole_run(steps: usize) -> ControlSchedule {
        ControlSchedule {
            interpolation: Interpolation::Constant,
            steps_per_interval: steps.max(1),
            intervals: 1,
        }
    }

    pub fn knots(&self) -> usize {
        match self.interpolation {
            Interpolation::Constant => self.intervals,
            Interpolation::Linear => self.intervals + 1,
        }
    }

    /// Steps covered by the schedule.
    pub fn steps(&self) -> usize {
        self.steps_per_interval * self.intervals
    }

    /// Knots and weights of the value at fraction `theta` in [0, 1] of step `step`. A
    /// piecewise-constant value uses the step's own interval for every RK4 stage, so a stage
    /// at the step's end never reads the next interval.
    pub fn knot_weights(&self, step: usize, theta: f64) -> [(usize, f64); 2] {
        let spi = self.steps_per_interval;
        match self.interpolation {
            Interpolation::Constant => {
                let j = (step / spi).min(self.intervals - 1);
                [(j, 1.0), (j, 0.0)]
            }
            Interpolation::Linear => {
                let tau = (step as f64 + theta) / spi as f64;
                let j = (tau.floor() as usize).min(self.intervals - 1);
                let alpha = tau - j as f64;
                [(j, 1.0 - alpha), (j + 1, alpha)]
            }
        }
    }
}

/// What a control acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ControlKind {
    /// An acceleration (force per unit mass) added to the grid forces of its particles:
    /// `f_i += sum_p w_ip m_p b(t)`.
    BodyForce,
    /// Its particles move kinematically with velocity `u(t)`: they hand `m_p u` to the grid,
    /// move with `dx/dt = u`, and ignore the grid's acceleration (a clamp the controller drives).
    PrescribedVelocity,
    /// The same kinematic region, driven by its offset `d(t)` from the start position: knots
    /// are offsets (bounded, so the region stays within reach), linear in time, and the
    /// particles move with `u = dd/dt`, constant over each interval. Knot 0 is held at 0.
    PrescribedPosition,
}

impl ControlKind {
    /// Whether the control moves its particles kinematically.
    pub fn is_kinematic(self) -> bool {
        matches!(
            self,
            ControlKind::PrescribedVelocity | ControlKind::PrescribedPosition
        )
    }
}

/// One boundary control, an effect of the model's list like the others: its kind, the
/// particles it acts on and its per-component bound. It has no grid hook; the pipeline reads
/// its value at each step from the model's [`ControlPlan`].
#[derive(Clone, Debug)]
pub struct ControlEffect {
    pub kind: ControlKind,
    pub name: String,
    pub particles: Vec<usize>,
    /// Largest allowed `|value[k]|` per component (0 freezes that component).
    pub bound: Vector3<f64>,
}

impl Effect for ControlEffect {
    fn name(&self) -> &'static str {
        match self.kind {
            ControlKind::BodyForce => "body force",
            ControlKind::PrescribedVelocity => "prescribed velocity",
            ControlKind::PrescribedPosition => "prescribed position",
        }
    }

    fn as_control(&self) -> Option<&ControlEffect> {
        Some(self)
    }
}

/// Knot values per control: `params[e][j]` is control `e`'s value at knot `j`.
pub type ControlParams = Vec<Vec<Vector3<f64>>>;

/// The boundary controls of a model's effect list, in list order, with their common
/// schedule: what the integrators and the controllers read ([`crate::mpm::model::Model::controls`]).
#[derive(Clone, Copy, Debug)]
pub struct ControlPlan<'a> {
    pub schedule: ControlSchedule,
    effects: &'a [Box<dyn Effect>],
    /// How many of `effects` are controls.
    count: usize,
}

/// Checks a schedule and its controls against `n` particles: each control acts on some of
/// them, with finite bounds, and no particle is in two prescribed-motion regions.
pub fn validate(
    schedule: &ControlSchedule,
    controls: &[ControlEffect],
    n: usize,
) -> Result<(), SimError> {
    let bad = |m: String| Err(SimError::InvalidScene(m));
    if schedule.steps_per_interval == 0 {
        return bad("control interval must be at least 1 step".into());
    }
    if schedule.intervals == 0 {
        return bad("control schedule needs at least one interval".into());
    }
    let mut clamped = vec![false; n];
    for e in controls {
        if e.particles.is_empty() {
            return bad(format!("control '{}' acts on no particles", e.name));
        }
        if let Some(&p) = e.particles.iter().find(|&&p| p >= n) {
            return bad(format!(
                "control '{}' names particle {p}, but the scene has {n}",
                e.name
            ));
        }
        if !e.bound.iter().all(|b| b.is_finite() && *b >= 0.0) {
            return bad(format!(
                "control '{}' has bound ({}, {}, {}); bounds must be finite and >= 0",
                e.name, e.bound[0], e.bound[1], e.bound[2]
            ));
        }
        if e.kind == ControlKind::PrescribedPosition
            && schedule.interpolation != Interpolation::Linear
        {
            return bad(format!(
                "control '{}' prescribes a position, which needs linear interpolation (a piecewise-constant position would jump)",
                e.name
            ));
        }
        if e.kind.is_kinematic() {
            for &p in &e.particles {
                if std::mem::replace(&mut clamped[p], true) {
                    return bad(format!(
                        "particle {p} is in two prescribed-motion regions (last '{}')",
                        e.name
                    ));
                }
            }
        }
    }
    Ok(())
}

impl<'a> ControlPlan<'a> {
    /// The controls among `effects`, in list order, under `schedule`.
    pub(crate) fn new(schedule: ControlSchedule, effects: &'a [Box<dyn Effect>]) -> Self {
        let count = effects.iter().filter(|e| e.as_control().is_some()).count();
        ControlPlan {
            schedule,
            effects,
            count,
        }
    }

    /// Number of controls.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The controls in order (the knot sequences' order).
    pub fn iter(&self) -> impl Iterator<Item = &'a ControlEffect> + 'a {
        self.effects.iter().filter_map(|e| e.as_control())
    }

    /// Control `e`, counted in [`ControlPlan::iter`]'s order.
    pub fn get(&self, e: usize) -> &'a ControlEffect {
        self.iter().nth(e).expect("a control of the plan")
    }

    /// Each control's per-component bound.
    pub fn bounds(&self) -> Vec<Vector3<f64>> {
        self.iter().map(|e| e.bound).collect()
    }

    /// All-zero knot values.
    pub fn zero_params(&self) -> ControlParams {
        vec![vec![Vector3::zeros(); self.schedule.knots()]; self.len()]
    }

    /// Checks that `params` has one finite value per knot of every control.
    pub fn check_params(&self, params: &ControlParams) -> Result<(), SimError> {
        if params.len() != self.len() {
            return Err(SimError::InvalidScene(format!(
                "{} control sequences for {} controls",
                params.len(),
                self.len()
            )));
        }
        for (e, knots) in self.iter().zip(params) {
            if knots.len() != self.schedule.knots() {
                return Err(SimError::InvalidScene(format!(
                    "control '{}' has {} knots, its schedule {}",
                    e.name,
                    knots.len(),
                    self.schedule.knots()
                )));
            }
            if let Some(j) = knots.iter().position(|k| !k.iter().all(|a| a.is_finite())) {
                return Err(SimError::InvalidScene(format!(
                    "control '{}' knot {j} is not finite",
                    e.name
                )));
            }
        }
        Ok(())
    }

    /// Clamps every knot into its control's bounds (the optimizers' projection); a
    /// prescribed position's first knot stays at 0 (the region starts where it is).
    pub fn project(&self, params: &mut ControlParams) {
        for (e, knots) in self.iter().zip(params.iter_mut()) {
            for k in knots.iter_mut() {
                for a in 0..3 {
                    k[a] = k[a].clamp(-e.bound[a], e.bound[a]);
                }
            }
            if let (ControlKind::PrescribedPosition, Some(k0)) = (e.kind, knots.first_mut()) {
                *k0 = Vector3::zeros();
            }
        }
    }

    /// Knots and weights of control `e`'s value (for a prescribed position, its velocity
    /// `(d_{j+1} - d_j) / (interval dt)` over the step's interval).
    fn weights(&self, e: usize, step: usize, theta: f64, dt: f64) -> [(usize, f64); 2] {
        if self.get(e).kind == ControlKind::PrescribedPosition {
            let spi = self.schedule.steps_per_interval;
            let j = (step / spi).min(self.schedule.intervals - 1);
            let rate = 1.0 / (spi as f64 * dt);
            [(j, -rate), (j + 1, rate)]
        } else {
            self.schedule.knot_weights(step, theta)
        }
    }

    /// Each control's value at fraction `theta` of step `step` (time step `dt`).
    pub fn values(
        &self,
        params: &ControlParams,
        step: usize,
        theta: f64,
        dt: f64,
    ) -> Vec<Vector3<f64>> {
        params
            .iter()
            .enumerate()
            .map(|(e, knots)| {
                self.weights(e, step, theta, dt)
                    .iter()
                    .map(|&(j, w)| w * knots[j])
                    .sum()
            })
            .collect()
    }

    /// Reverse of [`ControlPlan::values`]: adds dL/d(values) into the knot gradients.
    pub fn values_reverse(
        &self,
        step: usize,
        theta: f64,
        dt: f64,
        grad_values: &[Vector3<f64>],
        grad_params: &mut ControlParams,
    ) {
        for (e, (g, gk)) in grad_values.iter().zip(grad_params.iter_mut()).enumerate() {
            for &(j, w) in &self.weights(e, step, theta, dt) {
                gk[j] += w * g;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controls_are_effects_of_the_model_and_a_new_set_replaces_the_old() {
        let model = crate::scene::SceneConfig::reference()
            .model(vec![1e-6; 4])
            .unwrap();
        let physics = model.effects.len();
        let control = |kind, name: &str, particles| ControlEffect {
            kind,
            name: name.into(),
            particles,
            bound: Vector3::repeat(1.0),
        };
        let schedule = ControlSchedule {
            interpolation: Interpolation::Linear,
            steps_per_interval: 2,
            intervals: 3,
        };
        let clamp = control(ControlKind::PrescribedVelocity, "clamp", vec![0, 1]);
        let tip = control(ControlKind::BodyForce, "tip", vec![3]);
        let model = model.with_controls(schedule, vec![clamp, tip]).unwrap();
        assert_eq!(model.effects.len(), physics + 2);
        let names: Vec<&str> = model.controls().iter().map(|c| c.name.as_str()).collect();
        assert_eq!(names, ["clamp", "tip"]);
        assert_eq!(model.effects[physics].name(), "prescribed velocity");
        assert_eq!(model.kinematic_control(1), Some(0));
        assert_eq!(model.kinematic_control(3), None);
        assert_eq!(model.controls().zero_params().len(), 2);
        let again = control(ControlKind::BodyForce, "tip", vec![2]);
        let model = model.with_controls(schedule, vec![again]).unwrap();
        assert_eq!(model.effects.len(), physics + 1);
        assert!(!model.is_clamped(0));
        let overlap = vec![
            control(ControlKind::PrescribedVelocity, "a", vec![0, 1]),
            control(ControlKind::PrescribedVelocity, "b", vec![1]),
        ];
        let err = model.with_controls(schedule, overlap).unwrap_err();
        assert!(
            err.to_string().contains("two prescribed-motion regions"),
            "{err}"
        );
    }

    #[test]
    fn linear_schedule_is_continuous_and_constant_stays_in_its_interval() {
        let lin = ControlSchedule {
            interpolation: Interpolation::Linear,
            steps_per_interval: 4,
            intervals: 3,
        };
        // End of step 3 and start of step 4 are the same instant: knot 1.
        let a = lin.knot_weights(3, 1.0);
        let b = lin.knot_weights(4, 0.0);
        let at = |kw: [(usize, f64); 2], j: usize| {
            kw.iter().filter(|k| k.0 == j).map(|k| k.1).sum::<f64>()
        };
        assert!((at(a, 1) - 1.0).abs() < 1e-15 && (at(b, 1) - 1.0).abs() < 1e-15);
        // The last stage of the last step reaches the final knot.
        assert_eq!(lin.knot_weights(11, 1.0)[1], (3, 1.0));
        let con = ControlSchedule {
            interpolation: Interpolation::Constant,
            ..lin
        };
        assert_eq!(con.knot_weights(3, 1.0)[0], (0, 1.0));
        assert_eq!(con.knot_weights(4, 0.0)[0], (1, 1.0));
    }
}

//! Particle storage (structure of arrays), the checkpointable state, and the mutable view handed
//! to extensions.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{EngineError, ForceField, PeriodicBox, Real, SimConfig};

/// Structure-of-arrays particle storage. All vectors have the same length. The storage order is
/// fixed for the life of a simulation (the force loop works on a cell-sorted copy), so index `i`
/// always refers to the same particle and extensions may keep indices, unless the extension
/// allows reordering ([`crate::Extension::allows_reordering`]) and [`SimConfig::sort_every`]
/// is set: then the engine puts the storage into cell order every `sort_every` steps.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Particles {
    /// Positions, kept inside the box `[0, L)`.
    pub pos: Vec<DVec3>,
    /// Velocities.
    pub vel: Vec<DVec3>,
    /// Total force of the last force evaluation (needed for an exact restart).
    pub force: Vec<DVec3>,
    /// Type index into the [`ForceField`].
    pub ptype: Vec<u16>,
    /// Stable global id (keys the pair noise). Unique.
    pub id: Vec<u32>,
}

impl Particles {
    /// Empty storage with room for `n` particles.
    pub fn with_capacity(n: usize) -> Self {
        Self {
            pos: Vec::with_capacity(n),
            vel: Vec::with_capacity(n),
            force: Vec::with_capacity(n),
            ptype: Vec::with_capacity(n),
            id: Vec::with_capacity(n),
        }
    }

    /// Appends a particle with zero force.
    pub fn push(&mut self, pos: DVec3, vel: DVec3, ptype: u16, id: u32) {
        self.pos.push(pos);
        self.vel.push(vel);
        self.force.push(DVec3::ZERO);
        self.ptype.push(ptype);
        self.id.push(id);
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Checks lengths, finiteness, type range and id uniqueness.
    pub fn validate(&self, field: &ForceField) -> Result<(), EngineError> {
        let n = self.pos.len();
        if self.vel.len() != n || self.force.len() != n || self.ptype.len() != n || self.id.len() != n {
            return Err(EngineError::invalid(
                "particles",
                format!(
                    "array lengths differ: pos {}, vel {}, force {}, type {}, id {}",
                    n,
                    self.vel.len(),
                    self.force.len(),
                    self.ptype.len(),
                    self.id.len()
                ),
            ));
        }
        if n == 0 {
            return Err(EngineError::invalid("particles", "no particles"));
        }
        if n > u32::MAX as usize {
            return Err(EngineError::invalid("particles", "more than 2^32 − 1 particles"));
        }
        let nt = field.ntypes();
        for i in 0..n {
            if !(self.pos[i].is_finite() && self.vel[i].is_finite() && self.force[i].is_finite()) {
                return Err(EngineError::invalid(
                    format!("particle {i} (id {})", self.id[i]),
                    format!(
                        "non-finite state: pos {}, vel {}, force {}",
                        self.pos[i], self.vel[i], self.force[i]
                    ),
                ));
            }
            if self.ptype[i] as usize >= nt {
                return Err(EngineError::invalid(
                    format!("particle {i} (id {})", self.id[i]),
                    format!("type {} out of range for {nt} types", self.ptype[i]),
                ));
            }
        }
        let mut ids = self.id.clone();
        ids.sort_unstable();
        if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
            return Err(EngineError::invalid(
                "particle ids",
                format!("id {} is used twice", w[0]),
            ));
        }
        Ok(())
    }
}

/// Everything needed to continue a run bit-identically: settings, force field, particles
/// (including the forces of the last step, which the Groot–Warren scheme reuses) and the step
/// counter. The noise is a stateless hash of (seed, step, ids), so there is no RNG state to save.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimState {
    /// Box, dt, λ, seed, scheme.
    pub config: SimConfig,
    /// Types and pair parameters.
    pub field: ForceField,
    /// Particle arrays.
    pub particles: Particles,
    /// Number of completed steps.
    pub step: u64,
}

/// Mutable view of the particles handed to [`crate::Extension`] hooks. Slices, so the number of
/// particles cannot change; types and ids are read-only.
pub struct StateMut<'a> {
    /// Positions (inside the box on entry; an extension that moves particles must keep them so,
    /// e.g. with [`PeriodicBox::wrap`]).
    pub pos: &'a mut [DVec3],
    /// Velocities.
    pub vel: &'a mut [DVec3],
    /// Forces: in `add_forces`, the pair + body forces of this step, to be added to.
    pub force: &'a mut [DVec3],
    /// Types.
    pub ptype: &'a [u16],
    /// Global ids.
    pub id: &'a [u32],
    /// The box.
    pub domain: &'a PeriodicBox,
    /// Types and pair parameters.
    pub field: &'a ForceField,
    /// Time step.
    pub dt: Real,
    /// The step being taken: the step counter is `step` before and `step + 1` after it.
    pub step: u64,
}

//! The periodic orthorhombic box `[0, Lx) × [0, Ly) × [0, Lz)`.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{EngineError, Real};

/// A periodic orthorhombic box with its lower corner at the origin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PeriodicBox {
    lengths: DVec3,
}

impl PeriodicBox {
    /// A box of edge lengths `lengths` (model units, each finite and > 0).
    pub fn new(lengths: DVec3) -> Result<Self, EngineError> {
        if !(lengths.is_finite() && lengths.min_element() > 0.0) {
            return Err(EngineError::invalid(
                "box lengths",
                format!("must be finite and positive, got {lengths}"),
            ));
        }
        Ok(Self { lengths })
    }

    /// Edge lengths.
    #[inline]
    pub fn lengths(&self) -> DVec3 {
        self.lengths
    }

    /// Volume.
    #[inline]
    pub fn volume(&self) -> Real {
        self.lengths.x * self.lengths.y * self.lengths.z
    }

    /// Maps `p` into `[0, L)` along every axis.
    #[inline]
    pub fn wrap(&self, p: DVec3) -> DVec3 {
        DVec3::new(
            wrap1(p.x, self.lengths.x),
            wrap1(p.y, self.lengths.y),
            wrap1(p.z, self.lengths.z),
        )
    }

    /// Minimum-image separation `a − b`.
    #[inline]
    pub fn min_image(&self, a: DVec3, b: DVec3) -> DVec3 {
        let mut d = a - b;
        let l = self.lengths;
        d.x -= l.x * (d.x / l.x).round();
        d.y -= l.y * (d.y / l.y).round();
        d.z -= l.z * (d.z / l.z).round();
        d
    }
}

/// Wraps one coordinate into `[0, l)`. Exact (no rounding) for the common case of a particle that
/// left the box by less than one box length.
#[inline]
pub(crate) fn wrap1(x: Real, l: Real) -> Real {
    let mut y = x;
    if y >= l {
        y -= l;
    } else if y < 0.0 {
        y += l;
    }
    if !(y >= 0.0 && y < l) {
        // Far outside (or rounding put it exactly on l): general, still deterministic.
        y = x.rem_euclid(l);
        if y >= l {
            y = 0.0;
        }
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_stays_in_box() {
        let b = PeriodicBox::new(DVec3::new(3.0, 4.0, 5.0)).unwrap();
        for p in [
            DVec3::new(-1e-17, 4.0, 5.0 + 1e-12),
            DVec3::new(-30.5, 17.0, 1e6),
            DVec3::new(2.999_999_999_999_999_6, -4.0, 0.0),
        ] {
            let w = b.wrap(p);
            assert!(w.x >= 0.0 && w.x < 3.0, "{w}");
            assert!(w.y >= 0.0 && w.y < 4.0, "{w}");
            assert!(w.z >= 0.0 && w.z < 5.0, "{w}");
        }
        assert!(PeriodicBox::new(DVec3::new(1.0, 0.0, 1.0)).is_err());
        assert!(PeriodicBox::new(DVec3::new(1.0, Real::NAN, 1.0)).is_err());
    }

    #[test]
    fn min_image_is_shortest() {
        let b = PeriodicBox::new(DVec3::splat(10.0)).unwrap();
        let d = b.min_image(DVec3::new(0.5, 9.5, 5.0), DVec3::new(9.5, 0.5, 5.0));
        assert!((d - DVec3::new(1.0, -1.0, 0.0)).length() < 1e-12);
    }
}

//! Bounce-back of a particle on a moving triangle: the geometric kernel of the membrane–fluid
//! coupling (docs/engine.md, "Bounce-back on moving triangles").
//!
//! Over one step the particle and the triangle's three vertices move linearly in the step time
//! t ∈ [0, 1]: x(t) = x0 + t(x1 − x0), A(t) = A0 + t(A1 − A0), and so on. The particle is in the
//! triangle's plane when
//!
//! F(t) = (x(t) − A(t)) · [(B(t) − A(t)) × (C(t) − A(t))] = 0,
//!
//! a cubic in t (the normal is quadratic, the offset linear). [`crossing`] finds its roots in
//! (0, 1] on the monotone pieces between the roots of F′ (bisection to round-off) and takes the
//! earliest one whose point lies inside the triangle at that time. [`bounce`] reflects the
//! particle there in the triangle's frame: with u_w the velocity of the hit point (the
//! barycentric mix of the vertex velocities), v → 2u_w − v, and the particle travels the rest of
//! the step from the hit point. The impulse J = m(v_old − v_new) goes to the vertices in the
//! barycentric weights of the hit point, which conserves linear momentum (Σ w_k = 1) and angular
//! momentum (Σ w_k A_k(t*) = the hit point, where the particle received −J) exactly.
//!
//! Nothing here allocates or knows about cell lists: the caller finds candidate pairs (particles
//! within reach of a triangle's swept bounding box) and applies the results.

use glam::DVec3;

use crate::Real;

/// A triangle at the start (`a0`, `b0`, `c0`) and at the end (`a1`, `b1`, `c1`) of a step; each
/// vertex moves linearly in between. The orientation (A, B, C) defines the normal (B − A) × (C − A).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MovingTriangle {
    pub a0: DVec3,
    pub b0: DVec3,
    pub c0: DVec3,
    pub a1: DVec3,
    pub b1: DVec3,
    pub c1: DVec3,
}

impl MovingTriangle {
    /// The vertices at step time t ∈ [0, 1].
    #[inline]
    pub fn at(&self, t: Real) -> [DVec3; 3] {
        [
            self.a0 + (self.a1 - self.a0) * t,
            self.b0 + (self.b1 - self.b0) * t,
            self.c0 + (self.c1 - self.c0) * t,
        ]
    }

    /// Coefficients (c0, c1, c2, c3) of F(t) = c0 + c1 t + c2 t² + c3 t³ for a particle moving
    /// from `x0` to `x1`.
    fn cubic(&self, x0: DVec3, x1: DVec3) -> [Real; 4] {
        let (e1, e2) = (self.b0 - self.a0, self.c0 - self.a0);
        let (de1, de2) = (self.b1 - self.a1 - e1, self.c1 - self.a1 - e2);
        let n0 = e1.cross(e2);
        let nt = e1.cross(de2) + de1.cross(e2);
        let ntt = de1.cross(de2);
        let d0 = x0 - self.a0;
        let dd = (x1 - x0) - (self.a1 - self.a0);
        [
            d0.dot(n0),
            d0.dot(nt) + dd.dot(n0),
            d0.dot(ntt) + dd.dot(nt),
            dd.dot(ntt),
        ]
    }
}

/// Where and when a particle crosses a moving triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    /// Step time of the crossing, in (0, 1].
    pub t: Real,
    /// Barycentric weights of the hit point on the triangle at `t` (A, B, C; they sum to 1).
    pub weights: [Real; 3],
    /// The side the particle came from: +1 along the triangle's normal, −1 against it.
    pub side: Real,
}

/// Tolerance on the barycentric weights of a hit point (a crossing exactly on an edge is shared
/// by the two triangles; the caller keeps the earliest crossing of a particle, so a particle is
/// bounced once).
const EDGE_TOLERANCE: Real = 1e-12;

#[inline]
fn eval(c: &[Real; 4], t: Real) -> Real {
    ((c[3] * t + c[2]) * t + c[1]) * t + c[0]
}

/// The roots of F in (0, 1], in increasing order (at most three).
fn roots_in_step(c: &[Real; 4]) -> ([Real; 3], usize) {
    // split [0, 1] at the roots of F′ = c1 + 2c2 t + 3c3 t², so that F is monotone on each piece
    let (qa, qb, qc) = (3.0 * c[3], 2.0 * c[2], c[1]);
    let mut cuts = [0.0, 1.0, 1.0, 1.0];
    let mut n_cuts = 1;
    let mut push = |t: Real| {
        if t > 0.0 && t < 1.0 {
            cuts[n_cuts] = t;
            n_cuts += 1;
        }
    };
    if qa != 0.0 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            // numerically stable pair of roots
            let q = -0.5 * (qb + qb.signum() * disc.sqrt());
            let (r1, r2) = if q != 0.0 { (q / qa, qc / q) } else { (0.0, 0.0) };
            push(r1.min(r2));
            push(r1.max(r2));
        }
    } else if qb != 0.0 {
        push(-qc / qb);
    }
    cuts[n_cuts] = 1.0;
    let pieces = n_cuts;
    let mut roots = [0.0; 3];
    let mut n = 0;
    for k in 0..pieces {
        let (mut lo, mut hi) = (cuts[k], cuts[k + 1]);
        let (mut flo, fhi) = (eval(c, lo), eval(c, hi));
        // F is monotone on the piece: at most one root in it. A zero at its start is either the
        // particle starting in the plane (lo = 0: not a crossing of this step) or the end of the
        // previous piece, already counted.
        if flo == 0.0 {
            continue;
        }
        if fhi == 0.0 {
            roots[n] = hi;
            n += 1;
            continue;
        }
        if (flo > 0.0) == (fhi > 0.0) {
            continue;
        }
        // bisection to round-off: the bracket halves until it cannot shrink any further
        loop {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            let fm = eval(c, mid);
            if fm == 0.0 {
                hi = mid;
                break;
            }
            if (fm > 0.0) == (flo > 0.0) {
                lo = mid;
                flo = fm;
            } else {
                hi = mid;
            }
        }
        roots[n] = hi;
        n += 1;
    }
    (roots, n)
}

/// Barycentric weights of the point `p` (assumed in the plane) in the triangle `v`.
fn barycentric(p: DVec3, v: &[DVec3; 3]) -> [Real; 3] {
    let (e1, e2, d) = (v[1] - v[0], v[2] - v[0], p - v[0]);
    let n = e1.cross(e2);
    let nn = n.length_squared();
    let w1 = d.cross(e2).dot(n) / nn;
    let w2 = e1.cross(d).dot(n) / nn;
    [1.0 - w1 - w2, w1, w2]
}

/// The earliest crossing of the moving triangle by a particle moving from `x0` to `x1` during
/// the step, if any.
pub fn crossing(x0: DVec3, x1: DVec3, tri: &MovingTriangle) -> Option<Crossing> {
    let c = tri.cubic(x0, x1);
    let f0 = c[0];
    let (roots, n) = roots_in_step(&c);
    for &t in &roots[..n] {
        let v = tri.at(t);
        let p = x0 + (x1 - x0) * t;
        let w = barycentric(p, &v);
        if w.iter().all(|&x| x >= -EDGE_TOLERANCE) {
            let side = if f0 != 0.0 {
                f0.signum()
            } else {
                // started in the plane: the side it leaves is against the slope at the root
                let slope = c[1] + t * (2.0 * c[2] + 3.0 * c[3] * t);
                -slope.signum()
            };
            return Some(Crossing { t, weights: w, side });
        }
    }
    None
}

/// The outcome of a bounce.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounce {
    /// The crossing that was resolved.
    pub crossing: Crossing,
    /// Position at the end of the step, on the side the particle came from.
    pub position: DVec3,
    /// Velocity after the bounce, 2u_w − v.
    pub velocity: DVec3,
    /// Impulse given to each vertex (A, B, C): w_k·m(v − v_new); they sum to the particle's loss.
    pub vertex_impulse: [DVec3; 3],
}

/// Distance, relative to the triangle's longest edge, by which a bounced particle that would
/// end in the plane or beyond it is put back on its side.
const SIDE_OFFSET: Real = 1e-6;

/// Bounces a particle of mass `mass` that moved with velocity `v` (so from `x0` to `x0 + dt·v`)
/// on the moving triangle, if it crossed it. The particle ends on the side it came from: it
/// travels the rest of the step from the hit point with its new velocity, and if that would
/// leave it in or beyond the triangle's end-of-step plane near the hit point, it is put at the
/// hit point's place on the end-of-step triangle, `SIDE_OFFSET` × the longest edge off the
/// plane on its side.
pub fn bounce(x0: DVec3, v: DVec3, mass: Real, dt: Real, tri: &MovingTriangle) -> Option<Bounce> {
    let x1 = x0 + v * dt;
    let cr = crossing(x0, x1, tri)?;
    let w = cr.weights;
    let hit = x0 + (x1 - x0) * cr.t;
    let vel = [(tri.a1 - tri.a0) / dt, (tri.b1 - tri.b0) / dt, (tri.c1 - tri.c0) / dt];
    let u_w = vel[0] * w[0] + vel[1] * w[1] + vel[2] * w[2];
    let v_new = 2.0 * u_w - v;
    let mut position = hit + v_new * ((1.0 - cr.t) * dt);
    let end = tri.at(1.0);
    let n1 = (end[1] - end[0]).cross(end[2] - end[0]);
    let n1_len = n1.length();
    if n1_len > 0.0 {
        let n_hat = n1 / n1_len;
        let on_side = cr.side * (position - end[0]).dot(n_hat);
        let scale = (end[1] - end[0])
            .length()
            .max((end[2] - end[1]).length())
            .max((end[0] - end[2]).length());
        if on_side <= SIDE_OFFSET * scale {
            let p1 = end[0] * w[0] + end[1] * w[1] + end[2] * w[2];
            position = p1 + n_hat * (cr.side * SIDE_OFFSET * scale);
        }
    }
    let j = (v - v_new) * mass;
    Some(Bounce {
        crossing: cr,
        position,
        velocity: v_new,
        vertex_impulse: [j * w[0], j * w[1], j * w[2]],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator for the tests (SplitMix64).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> Real {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            (crate::rng::mix64(self.0) >> 11) as Real / (1u64 << 53) as Real
        }
        fn vec(&mut self) -> DVec3 {
            DVec3::new(self.next() - 0.5, self.next() - 0.5, self.next() - 0.5) * 2.0
        }
    }

    fn still(a: DVec3, b: DVec3, c: DVec3) -> MovingTriangle {
        MovingTriangle {
            a0: a,
            b0: b,
            c0: c,
            a1: a,
            b1: b,
            c1: c,
        }
    }

    /// A resting triangle in z = 0: a particle through its interior crosses at the right time
    /// and goes back along its path; one beside it or not reaching it does not cross.
    #[test]
    fn static_triangle() {
        let tri = still(DVec3::ZERO, DVec3::X, DVec3::Y);
        let (x0, v, dt) = (DVec3::new(0.2, 0.3, 0.4), DVec3::new(0.1, -0.2, -1.0), 0.5);
        let b = bounce(x0, v, 2.0, dt, &tri).expect("crosses");
        assert!((b.crossing.t - 0.8).abs() < 1e-15, "{}", b.crossing.t);
        assert_eq!(b.crossing.side, 1.0);
        assert!((b.velocity + v).length() < 1e-15);
        // back along the path: x0 + (2t − 1)Δt·v
        assert!((b.position - (x0 + v * (0.6 * dt))).length() < 1e-14, "{}", b.position);
        // beside the triangle (x + y > 1 at the plane), and not reaching the plane
        assert!(crossing(DVec3::new(0.7, 0.7, 0.1), DVec3::new(0.7, 0.7, -0.1), &tri).is_none());
        assert!(crossing(DVec3::new(0.2, 0.2, 0.3), DVec3::new(0.2, 0.2, 0.1), &tri).is_none());
        // from below, against the normal
        let c = crossing(DVec3::new(0.2, 0.2, -0.1), DVec3::new(0.2, 0.2, 0.1), &tri).unwrap();
        assert_eq!(c.side, -1.0);
    }

    /// Particles fired at moving (translating, rotating, deforming) triangles from many
    /// directions: every one aimed at a point of the moving triangle is found crossing, ends on
    /// the side it came from (of the end-of-step triangle's plane, near the hit point), and the
    /// impulses conserve linear and angular momentum to round-off. Momentum counts the vertex
    /// impulses at the vertices' places at the crossing time, where the particle received its own.
    #[test]
    fn moving_triangles_never_let_a_particle_through_and_conserve_momentum() {
        let mut rng = Rng(7);
        let dt = 0.01;
        let (mut bounced, mut would_cross) = (0, 0);
        for case in 0..20_000 {
            let a0 = rng.vec() * 0.2;
            let b0 = a0 + DVec3::new(0.8, 0.0, 0.0) + rng.vec() * 0.2;
            let c0 = a0 + DVec3::new(0.1, 0.8, 0.0) + rng.vec() * 0.2;
            // vertex displacements over the step up to 0.05 (velocities up to 5): translation,
            // rotation and deformation mixed
            let shift = rng.vec() * 0.03;
            let tri = MovingTriangle {
                a0,
                b0,
                c0,
                a1: a0 + shift + rng.vec() * 0.02,
                b1: b0 + shift + rng.vec() * 0.02,
                c1: c0 + shift + rng.vec() * 0.02,
            };
            // aim: a point strictly inside the triangle at a random time of the step
            let t_hit = 0.02 + 0.96 * rng.next();
            // uniform in the triangle, then pulled 10 % towards the centroid (strictly inside)
            let (r1, r2) = (rng.next(), rng.next());
            let (r1, r2) = if r1 + r2 > 1.0 { (1.0 - r1, 1.0 - r2) } else { (r1, r2) };
            let (w1, w2) = (1.0 / 3.0 + 0.9 * (r1 - 1.0 / 3.0), 1.0 / 3.0 + 0.9 * (r2 - 1.0 / 3.0));
            let v_t = tri.at(t_hit);
            let target = v_t[0] * (1.0 - w1 - w2) + v_t[1] * w1 + v_t[2] * w2;
            let n_t = (v_t[1] - v_t[0]).cross(v_t[2] - v_t[0]).normalize();
            // a random velocity with a clear normal component (up to 10 rc/τ)
            let mut v = rng.vec() * 6.0;
            let vn = 2.0 + 4.0 * rng.next();
            v += n_t * (if case % 2 == 0 { vn } else { -vn } - v.dot(n_t));
            let x0 = target - v * (t_hit * dt);
            let mass = 0.5 + rng.next();
            let Some(b) = bounce(x0, v, mass, dt, &tri) else {
                panic!("case {case}: no crossing found for a particle aimed at the triangle");
            };
            bounced += 1;
            let cr = b.crossing;
            assert!(
                cr.t <= t_hit + 1e-9,
                "case {case}: crossing at {} after the aimed {t_hit}",
                cr.t
            );
            // the side it came from, at the start
            let v0 = tri.at(0.0);
            let n0 = (v0[1] - v0[0]).cross(v0[2] - v0[0]);
            assert_eq!(cr.side, (x0 - v0[0]).dot(n0).signum(), "case {case}");
            // ends on that side of the end-of-step triangle's plane (where, unbounced, it
            // would mostly have ended on the other)
            let v1 = tri.at(1.0);
            let n1 = (v1[1] - v1[0]).cross(v1[2] - v1[0]).normalize();
            if cr.side * (x0 + v * dt - v1[0]).dot(n1) < 0.0 {
                would_cross += 1;
            }
            assert!(cr.side * (b.position - v1[0]).dot(n1) > 0.0, "case {case}: crossed");
            // linear momentum: particle gain + vertex impulses = 0
            let dp = (b.velocity - v) * mass + b.vertex_impulse[0] + b.vertex_impulse[1] + b.vertex_impulse[2];
            assert!(dp.length() < 1e-12 * mass * v.length(), "case {case}: {dp}");
            // angular momentum of the impulses about the origin, at the crossing time
            let hit = x0 + v * (cr.t * dt);
            let vt = tri.at(cr.t);
            let dl = hit.cross((b.velocity - v) * mass)
                + vt[0].cross(b.vertex_impulse[0])
                + vt[1].cross(b.vertex_impulse[1])
                + vt[2].cross(b.vertex_impulse[2]);
            assert!(dl.length() < 1e-11 * mass * v.length(), "case {case}: {dl}");
            // the relative velocity at the hit point is reversed
            let u_w = ((tri.a1 - tri.a0) * cr.weights[0]
                + (tri.b1 - tri.b0) * cr.weights[1]
                + (tri.c1 - tri.c0) * cr.weights[2])
                / dt;
            assert!(((b.velocity - u_w) + (v - u_w)).length() < 1e-12 * v.length().max(1.0));
        }
        assert_eq!(bounced, 20_000);
        assert!(
            would_cross > 15_000,
            "only {would_cross} of the particles would have crossed unbounced"
        );
    }
}

//! Limited-memory BFGS on vectors of `DVec3`, shared by the membrane's static solvers
//! (stretching at equilibrium, confinement into a tube).

use crate::forces::ForceError;
use crate::precondition::Preconditioner;
use glam::DVec3;
use std::collections::VecDeque;

/// Limited-memory BFGS with a backtracking (Armijo) line search, on vectors of `DVec3`.
/// A trial step that overstretches a link (the WLC energy is infinite there) is shortened.
pub(crate) struct Lbfgs {
    memory: usize,
    /// The (s, y) pairs, oldest first, with ρ = 1/(s·y) and y·y.
    pairs: VecDeque<Pair>,
    pub(crate) g: Vec<DVec3>,
    g_new: Vec<DVec3>,
    d: Vec<DVec3>,
    x_new: Vec<DVec3>,
    first_step: f64,
    /// Dropped pairs, reused: no allocation per iteration.
    spare: Vec<Pair>,
    alphas: Vec<f64>,
    /// P⁻¹ as the initial inverse Hessian (instead of γ I) when present and factorised.
    pub(crate) precondition: Option<Preconditioner>,
}

struct Pair {
    s: Vec<DVec3>,
    y: Vec<DVec3>,
    rho: f64,
    yy: f64,
}

fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p.dot(*q)).sum()
}

fn max_norm(a: &[DVec3]) -> f64 {
    a.iter().map(|v| v.length()).fold(0.0, f64::max)
}

impl Lbfgs {
    pub(crate) fn new(n: usize, memory: usize, first_step: f64) -> Self {
        let z = vec![DVec3::ZERO; n];
        Self {
            memory,
            pairs: VecDeque::new(),
            g: z.clone(),
            g_new: z.clone(),
            d: z.clone(),
            x_new: z,
            first_step,
            spare: Vec::new(),
            alphas: Vec::new(),
            precondition: None,
        }
    }

    fn preconditioned(&self) -> bool {
        self.precondition.as_ref().is_some_and(|p| p.is_factored())
    }

    /// Empties the memory (its buffers go to `spare`).
    fn forget(&mut self) {
        self.spare.extend(self.pairs.drain(..));
    }

    /// Minimises from `x` until max |g| < tol. Returns (iterations, final max |g|), or None
    /// when `stop` returned true (checked once per iteration; `x` is then partly relaxed).
    pub(crate) fn minimize(
        &mut self,
        x: &mut [DVec3],
        mut f: impl FnMut(&[DVec3], &mut [DVec3]) -> Result<f64, ForceError>,
        tol: f64,
        max_iter: usize,
        stop: &impl Fn() -> bool,
    ) -> Result<Option<(usize, f64)>, ForceError> {
        self.forget();
        let mut e = f(x, &mut self.g)?;
        let mut stalls = 0;
        for it in 0..max_iter {
            let gmax = max_norm(&self.g);
            if gmax < tol {
                return Ok(Some((it, gmax)));
            }
            if stop() {
                return Ok(None);
            }
            self.direction();
            let mut gd = dot(&self.g, &self.d);
            if gd >= 0.0 {
                // not a descent direction: restart with steepest descent
                self.forget();
                self.direction();
                gd = dot(&self.g, &self.d);
            }
            // first step of a fresh memory: limit the largest move
            let mut alpha = if self.pairs.is_empty() && !self.preconditioned() {
                (self.first_step / max_norm(&self.d).max(1e-300)).min(1.0)
            } else {
                1.0
            };
            let mut accepted = false;
            for _ in 0..60 {
                for ((xn, xi), di) in self.x_new.iter_mut().zip(x.iter()).zip(&self.d) {
                    *xn = *xi + *di * alpha;
                }
                match f(&self.x_new, &mut self.g_new) {
                    Ok(e_new)
                        if e_new <= e + 1e-4 * alpha * gd
                            || (e_new - e).abs() <= 1e-14 * e.abs().max(1.0)
                                && dot(&self.g_new, &self.d) < 0.9 * gd.abs() =>
                    {
                        self.remember(alpha);
                        x.copy_from_slice(&self.x_new);
                        std::mem::swap(&mut self.g, &mut self.g_new);
                        e = e_new;
                        accepted = true;
                        break;
                    }
                    Ok(_) | Err(ForceError::LinkOverstretched { .. }) => alpha *= 0.5,
                    Err(other) => return Err(other),
                }
            }
            if !accepted {
                // line search failed (round-off floor): restart the memory, try again a few times
                stalls += 1;
                self.forget();
                if stalls > 5 {
                    return Ok(Some((it, max_norm(&self.g))));
                }
            } else {
                stalls = 0;
            }
        }
        Ok(Some((max_iter, max_norm(&self.g))))
    }

    /// Stores the pair s = alpha d, y = g_new − g if s·y > 0 (dropping the oldest when full).
    fn remember(&mut self, alpha: f64) {
        let n = self.g.len();
        let mut p = self.spare.pop().unwrap_or_else(|| Pair {
            s: vec![DVec3::ZERO; n],
            y: vec![DVec3::ZERO; n],
            rho: 0.0,
            yy: 0.0,
        });
        let (mut sy, mut yy) = (0.0, 0.0);
        for (((s, y), d), (gn, g)) in
            p.s.iter_mut()
                .zip(&mut p.y)
                .zip(&self.d)
                .zip(self.g_new.iter().zip(&self.g))
        {
            *s = *d * alpha;
            *y = *gn - *g;
            sy += s.dot(*y);
            yy += y.dot(*y);
        }
        if sy > 1e-300 {
            (p.rho, p.yy) = (1.0 / sy, yy);
            if self.pairs.len() == self.memory {
                self.spare.extend(self.pairs.pop_front());
            }
            self.pairs.push_back(p);
        } else {
            self.spare.push(p);
        }
    }

    /// Two-loop recursion: d = −H g. Each pass over the vectors also computes the dot product
    /// the next step needs.
    fn direction(&mut self) {
        let k = self.pairs.len();
        let d = &mut self.d;
        if k == 0 {
            d.iter_mut().zip(&self.g).for_each(|(d, g)| *d = -*g);
            if let Some(p) = &mut self.precondition {
                p.apply(d);
            }
            return;
        }
        let alphas = &mut self.alphas;
        alphas.clear();
        alphas.resize(k, 0.0);
        d.copy_from_slice(&self.g);
        // newest to oldest: α_i = ρ_i s_i·d, d −= α_i y_i
        let mut sd = dot(&self.pairs[k - 1].s, d);
        for i in (0..k).rev() {
            let a = self.pairs[i].rho * sd;
            alphas[i] = a;
            let y = &self.pairs[i].y;
            sd = 0.0;
            if i > 0 {
                for ((dj, yj), sj) in d.iter_mut().zip(y).zip(&self.pairs[i - 1].s) {
                    *dj -= *yj * a;
                    sd += sj.dot(*dj);
                }
            } else {
                d.iter_mut().zip(y).for_each(|(dj, yj)| *dj -= *yj * a);
            }
        }
        // initial inverse Hessian P⁻¹, or γ I with γ = s·y / y·y of the newest pair
        // (the γ pass also computes the dot product the next pass needs)
        let mut yd = 0.0;
        if self.precondition.as_mut().is_some_and(|p| p.apply(d)) {
            yd = dot(&self.pairs[0].y, d);
        } else {
            let last = &self.pairs[k - 1];
            let gamma = 1.0 / (last.rho * last.yy);
            for (dj, yj) in d.iter_mut().zip(&self.pairs[0].y) {
                *dj *= gamma;
                yd += yj.dot(*dj);
            }
        }
        // oldest to newest: β = ρ_i y_i·d, d += (α_i − β) s_i; the last pass also negates d
        for i in 0..k {
            let c = alphas[i] - self.pairs[i].rho * yd;
            let s = &self.pairs[i].s;
            yd = 0.0;
            if i + 1 < k {
                for ((dj, sj), yj) in d.iter_mut().zip(s).zip(&self.pairs[i + 1].y) {
                    *dj += *sj * c;
                    yd += yj.dot(*dj);
                }
            } else {
                d.iter_mut().zip(s).for_each(|(dj, sj)| *dj = -(*dj + *sj * c));
            }
        }
    }
}

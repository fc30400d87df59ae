//! One Levenberg–Marquardt solver for the three least-squares fits of the
//! crate: the 2-D model with effects ([`super::nonlinear`]), the 3-D
//! ellipsoid ([`super::ellipsoid`]) and the 3-D ellipsoid with effects
//! ([`super::ellipsoid_effects`]).
//!
//! A fit describes its residuals by [`LeastSquares`]; the solver forms the
//! weighted normal equations JᵀWJ, JᵀWe and Σ w e² in one pass over the
//! samples ([`normal_equations`]), damps them by Marquardt's scaling (λ
//! times each diagonal entry, so parameters of very different units step
//! alike), solves them by Cholesky, accepts a step that does not raise the
//! cost and then divides λ by 10, and otherwise multiplies λ by 10 and tries
//! again ([`solve`]).
//!
//! The three fits were written apart and differ in details that change
//! results in the last bit; [`Options`] holds those differences, so each fit
//! keeps its arithmetic exactly.

use nalgebra::{DMatrix, DVector};

/// A least-squares problem: residuals of samples, and their derivatives in
/// the parameters.
pub trait LeastSquares {
    /// What every residual at one parameter vector shares (a matrix built
    /// from the parameters, say): computed once per pass over the samples.
    type Shared;

    /// The shared part at the parameters `p`.
    fn shared(&self, p: &[f64]) -> Self::Shared;

    /// The residual of sample `i` at `p`; with `row`, also its derivative
    /// in each parameter into `row` (`p.len()` entries, every one written).
    fn residual(&self, shared: &Self::Shared, p: &[f64], i: usize, row: Option<&mut [f64]>) -> f64;
}

/// How the weights enter the cost and the normal equations.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weighting {
    /// Every sample counts, its cost `(w·e)·e` (the 2-D fit; the 3-D base
    /// fit with every weight 1, where this is `e²`).
    EverySample,
    /// Only samples of positive weight count (the 3-D fit with effects,
    /// whose flagged outliers get weight 0), the trial cost summing
    /// `w·(e·e)`. The normal equations leave out samples of weight `<= 0`
    /// and the trial cost keeps those of weight `> 0`, as the fit always
    /// did (they differ only on a NaN weight).
    PositiveOnly,
}

/// What the three fits do differently.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Options {
    /// Iterations (counting those of earlier runs, `done` of [`solve`])
    /// before giving up.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this
    /// fraction.
    pub tolerance: f64,
    pub weighting: Weighting,
    /// Refuse to start when a diagonal entry of JᵀWJ is not positive (a
    /// parameter the data do not touch): [`Failure::Undetermined`].
    pub require_curvature: bool,
    /// Damp each diagonal entry by λ·max(entry, floor) instead of λ·entry,
    /// so a zero curvature is damped too.
    pub damping_floor: Option<f64>,
    /// Also stop when every component of an accepted step is within this
    /// fraction of its parameter.
    pub step_tolerance: Option<f64>,
    /// Refuse a trial whose parameter at this index is not positive (the
    /// field's magnitude).
    pub positive: Option<usize>,
    /// Whether the accepted step that meets a stop rule still divides λ by
    /// 10: the damping a later run on the same fit starts from.
    pub lower_damping_on_stop: bool,
    /// Judge each trial by the normal equations at it, whose Σ w e² is the
    /// trial cost to the bit with [`Weighting::EverySample`] (the same
    /// `w·e·e`, in the same order), instead of by the cost alone: an
    /// accepted trial then needs no second pass for its equations, and
    /// the run ends holding the equations at its parameters
    /// ([`Solved::equations`]). Worth it where trials are nearly always
    /// accepted (from a closed form); ignored with another weighting.
    pub trials_by_equations: bool,
}

/// What [`solve`] leaves: the iterations it took, and the normal
/// equations at the parameters it ends on when it holds them: always with
/// [`Options::trials_by_equations`] and every sample weighted; otherwise
/// only when it ends on a zero cost or on a damping past 1e12.
#[derive(Debug, Clone, PartialEq)]
pub struct Solved {
    pub iterations: usize,
    pub equations: Option<NormalEquations>,
}

/// JᵀWJ, JᵀWe and Σ w e² at one parameter vector.
#[derive(Debug, Clone, PartialEq)]
pub struct NormalEquations {
    pub jtj: DMatrix<f64>,
    pub jte: DVector<f64>,
    pub cost: f64,
}

/// Why Levenberg–Marquardt gave no parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// A diagonal entry of JᵀWJ at the start is not positive (with
    /// [`Options::require_curvature`]); the caller names the parameter.
    Undetermined { jtj: DMatrix<f64> },
    /// The iteration cap was reached; `iterations` counts earlier runs too.
    NoConvergence { iterations: usize },
}

/// JᵀWJ, JᵀWe and Σ w e² at `p`, in one pass over the samples (one per
/// weight). The fits' own sizes (4, 6 and 9 parameters: the 3-D models)
/// run with fixed-size accumulators the compiler lays out in full; every
/// sum is the same, in the same order, as for any other size.
pub fn normal_equations<P: LeastSquares>(
    problem: &P,
    p: &[f64],
    weights: &[f64],
    weighting: Weighting,
) -> NormalEquations {
    match p.len() {
        4 => normal_equations_of::<P, 4>(problem, p, weights, weighting),
        6 => normal_equations_of::<P, 6>(problem, p, weights, weighting),
        9 => normal_equations_of::<P, 9>(problem, p, weights, weighting),
        _ => normal_equations_any(problem, p, weights, weighting),
    }
}

/// [`normal_equations`] for `K` parameters.
fn normal_equations_of<P: LeastSquares, const K: usize>(
    problem: &P,
    p: &[f64],
    weights: &[f64],
    weighting: Weighting,
) -> NormalEquations {
    let mut row = [0.0; K];
    let mut upper = [[0.0; K]; K];
    let mut gradient = [0.0; K];
    let cost = each_residual(problem, p, weights, weighting, &mut row, |w, e, row| {
        for u in 0..K {
            let wu = w * row[u];
            gradient[u] += wu * e;
            for v in u..K {
                upper[u][v] += wu * row[v];
            }
        }
    });
    assemble(K, |u, v| upper[u][v], &gradient, cost)
}

/// [`normal_equations`] for any number of parameters.
fn normal_equations_any<P: LeastSquares>(
    problem: &P,
    p: &[f64],
    weights: &[f64],
    weighting: Weighting,
) -> NormalEquations {
    let k = p.len();
    let mut row = vec![0.0; k];
    // Flat row-major accumulators of the upper triangle: the hot loop of
    // the fits, kept free of matrix indexing and allocation.
    let mut upper = vec![0.0; k * k];
    let mut gradient = vec![0.0; k];
    let cost = each_residual(problem, p, weights, weighting, &mut row, |w, e, row| {
        for (u, &ru) in row.iter().enumerate() {
            let wu = w * ru;
            gradient[u] += wu * e;
            let target = &mut upper[u * k + u..(u + 1) * k];
            for (acc, &rv) in target.iter_mut().zip(&row[u..]) {
                *acc += wu * rv;
            }
        }
    });
    assemble(k, |u, v| upper[u * k + v], &gradient, cost)
}

/// The pass of [`normal_equations`]: each counted sample's residual `e`
/// and derivatives `row` at `p`, handed to `add` with its weight; returns
/// Σ w e².
fn each_residual<P: LeastSquares>(
    problem: &P,
    p: &[f64],
    weights: &[f64],
    weighting: Weighting,
    row: &mut [f64],
    mut add: impl FnMut(f64, f64, &[f64]),
) -> f64 {
    let shared = problem.shared(p);
    let mut cost = 0.0;
    for (i, &w) in weights.iter().enumerate() {
        if weighting == Weighting::PositiveOnly && w <= 0.0 {
            continue;
        }
        let e = problem.residual(&shared, p, i, Some(row));
        cost += w * e * e;
        add(w, e, row);
    }
    cost
}

/// The normal equations of `k` parameters from the upper triangle of JᵀWJ
/// (`upper(u, v)`, u ≤ v), JᵀWe and the cost.
fn assemble(
    k: usize,
    upper: impl Fn(usize, usize) -> f64,
    gradient: &[f64],
    cost: f64,
) -> NormalEquations {
    let jtj = DMatrix::from_fn(k, k, |u, v| if u <= v { upper(u, v) } else { upper(v, u) });
    NormalEquations {
        jtj,
        jte: DVector::from_row_slice(gradient),
        cost,
    }
}

/// Σ w e² at `p`: the cost a trial step is judged by.
pub fn cost<P: LeastSquares>(problem: &P, p: &[f64], weights: &[f64], weighting: Weighting) -> f64 {
    let shared = problem.shared(p);
    let mut sum = 0.0;
    for (i, &w) in weights.iter().enumerate() {
        match weighting {
            Weighting::EverySample => {
                let e = problem.residual(&shared, p, i, None);
                sum += w * e * e;
            }
            Weighting::PositiveOnly => {
                if w > 0.0 {
                    sum += w * problem.residual(&shared, p, i, None).powi(2);
                }
            }
        }
    }
    sum
}

/// One round of iteratively reweighted least squares: each weight set to
/// `weight` of its residual, in place; returns the largest change of a
/// weight (the fits stop reweighting below 1e-5).
pub fn reweight(weights: &mut [f64], residuals: &[f64], weight: impl Fn(f64) -> f64) -> f64 {
    let mut largest_change = 0.0f64;
    for (w, e) in weights.iter_mut().zip(residuals) {
        let new = weight(*e);
        largest_change = largest_change.max((new - *w).abs());
        *w = new;
    }
    largest_change
}

/// Runs Levenberg–Marquardt with fixed weights from `p`, in place; returns
/// the iterations it took (and the normal equations at the end when it
/// holds them). `lambda` is the damping to start from (at least 1e-6) and
/// is left where the run ended, for a later run on the same fit; `done`
/// counts iterations already spent towards the cap.
pub fn solve<P: LeastSquares>(
    problem: &P,
    p: &mut [f64],
    weights: &[f64],
    lambda: &mut f64,
    done: usize,
    options: &Options,
) -> Result<Solved, Failure> {
    let by_equations = options.trials_by_equations && options.weighting == Weighting::EverySample;
    let k = p.len();
    *lambda = lambda.max(1e-6);
    let mut trial = vec![0.0; k];
    // The equations at `p`.
    let mut at = normal_equations(problem, p, weights, options.weighting);
    if options.require_curvature && (0..k).any(|j| !(at.jtj[(j, j)] > 0.0)) {
        return Err(Failure::Undetermined { jtj: at.jtj });
    }
    let mut iterations = 0;
    loop {
        if done + iterations >= options.max_iterations {
            return Err(Failure::NoConvergence {
                iterations: done + iterations,
            });
        }
        iterations += 1;
        let held = |at| Solved {
            iterations,
            equations: Some(at),
        };
        let cost = at.cost;
        if cost == 0.0 {
            return Ok(held(at));
        }
        // Marquardt's scaling: damping proportional to each curvature, so
        // parameters of very different units step alike.
        let mut damped = at.jtj.clone();
        for j in 0..k {
            let curvature = match options.damping_floor {
                Some(floor) => at.jtj[(j, j)].max(floor),
                None => at.jtj[(j, j)],
            };
            damped[(j, j)] += *lambda * curvature;
        }
        let mut accepted = false;
        if let Some(step) = damped.cholesky().map(|c| c.solve(&(-&at.jte))) {
            for j in 0..k {
                trial[j] = p[j] + step[j];
            }
            let at_trial =
                by_equations.then(|| normal_equations(problem, &trial, weights, options.weighting));
            let new_cost = match &at_trial {
                Some(equations) => equations.cost,
                None => self::cost(problem, &trial, weights, options.weighting),
            };
            let admissible = options.positive.is_none_or(|j| trial[j] > 0.0);
            if new_cost.is_finite() && admissible && new_cost <= cost {
                let relative = (cost - new_cost) / cost;
                p.copy_from_slice(&trial);
                let small_step = options.step_tolerance.is_some_and(|tolerance| {
                    (0..k).all(|j| step[j].abs() <= tolerance * p[j].abs().max(1e-300))
                });
                let stop = relative < options.tolerance || small_step;
                if !stop || options.lower_damping_on_stop {
                    *lambda = (*lambda / 10.0).max(1e-15);
                }
                let at_p = match at_trial {
                    Some(equations) => equations,
                    None if stop => {
                        return Ok(Solved {
                            iterations,
                            equations: None,
                        });
                    }
                    None => normal_equations(problem, p, weights, options.weighting),
                };
                if stop {
                    return Ok(held(at_p));
                }
                accepted = true;
                at = at_p;
            }
        }
        if !accepted {
            *lambda *= 10.0;
            // No step, however short, lowers the cost: p is the minimum to
            // the precision of the arithmetic.
            if *lambda > 1e12 {
                return Ok(held(at));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle through points: centre (p0, p1), radius p2.
    struct Circle {
        points: Vec<[f64; 2]>,
    }

    impl LeastSquares for Circle {
        type Shared = ();

        fn shared(&self, _: &[f64]) {}

        fn residual(&self, _: &(), p: &[f64], i: usize, row: Option<&mut [f64]>) -> f64 {
            let [x, y] = self.points[i];
            let (dx, dy) = (x - p[0], y - p[1]);
            let d = dx.hypot(dy);
            if let Some(row) = row {
                row[0] = -dx / d;
                row[1] = -dy / d;
                row[2] = -1.0;
            }
            d - p[2]
        }
    }

    fn circle() -> (Circle, Vec<f64>) {
        // An arc, unevenly weighted, with a little deterministic noise.
        let points = (0..200)
            .map(|i| {
                let a = f64::from(i) * 0.02;
                let wobble = 0.01 * (f64::from(i) * 1.7).sin();
                [
                    3.0 + (2.0 + wobble) * a.cos(),
                    -1.0 + (2.0 - wobble) * a.sin(),
                ]
            })
            .collect();
        let weights = (0..200).map(|i| 0.5 + f64::from(i % 7) / 4.0).collect();
        (Circle { points }, weights)
    }

    fn options(trials_by_equations: bool, weighting: Weighting) -> Options {
        Options {
            max_iterations: 500,
            tolerance: 1e-12,
            weighting,
            require_curvature: false,
            damping_floor: None,
            step_tolerance: None,
            positive: None,
            lower_damping_on_stop: true,
            trials_by_equations,
        }
    }

    #[test]
    fn trials_judged_by_their_equations_take_the_same_steps() {
        let (problem, weights) = circle();
        // Far starts: some trials are refused on the way.
        for start in [[2.0, 0.0, 1.0], [4.0, -2.5, 3.0], [3.5, -0.5, 2.5]] {
            for weighting in [Weighting::EverySample, Weighting::PositiveOnly] {
                let run = |by_equations| {
                    let mut p = start.to_vec();
                    let mut lambda = 1e-3;
                    let options = options(by_equations, weighting);
                    let solved = solve(&problem, &mut p, &weights, &mut lambda, 0, &options);
                    (solved, p, lambda)
                };
                let (by_cost, p_cost, lambda_cost) = run(false);
                let (by_equations, p_eq, lambda_eq) = run(true);
                let bits = |p: &[f64]| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&p_eq), bits(&p_cost), "{start:?} {weighting:?}");
                assert_eq!(lambda_eq.to_bits(), lambda_cost.to_bits());
                let (Ok(by_cost), Ok(by_equations)) = (by_cost, by_equations) else {
                    panic!("{start:?} {weighting:?} did not converge");
                };
                assert_eq!(by_equations.iterations, by_cost.iterations);
                assert!(by_cost.iterations > 3, "{}", by_cost.iterations);
                // The equations held are those at the end, to the bit;
                // the weighting whose trial cost they are always holds
                // them (another, ending on a stop rule, does not).
                let at_end = normal_equations(&problem, &p_eq, &weights, weighting);
                match (weighting, by_equations.equations) {
                    (Weighting::EverySample, held) => assert_eq!(held, Some(at_end)),
                    (Weighting::PositiveOnly, Some(held)) => assert_eq!(held, at_end),
                    (Weighting::PositiveOnly, None) => {}
                }
            }
        }
    }
}

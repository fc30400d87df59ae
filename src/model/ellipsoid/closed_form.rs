//! The closed-form (algebraic) starts of the 3-D fit, each in one pass
//! over the points with memory independent of their number: the sphere
//! fit by a QR decomposition taken block by block (its rank test on the
//! design's own singular values, as an SVD of the whole design gives
//! them), Li & Griffiths' fit by its scatter matrix DᵀD summed block by
//! block. Neither builds the n-row design matrix (10 columns of 8 bytes for
//! every point: 160 MB at 2 M points).

use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen, Vector3};

use super::{Ellipsoid, Ellipsoid3Error, Ellipsoid3Model};

/// Rows taken at once: into one QR step of the sphere fit, or into one
/// partial sum of a scatter matrix (so a sum of millions of rows adds
/// blocks, not each row to a huge total).
const BLOCK: usize = 512;

/// Sphere fit: |p|² = 2c·p + k, linear least squares.
pub(super) fn sphere_fit(p: &[Vector3<f64>]) -> Result<Ellipsoid, Ellipsoid3Error> {
    // R of the QR decomposition of [D | t] (D's rows 2x, 2y, 2z, 1; t =
    // |p|²): D = QR₁₁, Qᵀt = R₁₂, so D x = t in least squares is
    // R₁₁ x = R₁₂, and R₁₁ has D's singular values.
    let r = streamed_r(p, |[x, y, z]| {
        [2.0 * x, 2.0 * y, 2.0 * z, 1.0, x * x + y * y + z * z]
    });
    if r.nrows() < 4 {
        return Err(Ellipsoid3Error::Degenerate);
    }
    let design_r = r.view((0, 0), (4, 4)).into_owned();
    let rhs = r.view((0, 4), (4, 1)).into_owned();
    let svd = design_r.svd(true, true);
    let largest = svd.singular_values.max();
    if svd.singular_values.min() <= largest * super::RANK_TOLERANCE {
        return Err(Ellipsoid3Error::Degenerate);
    }
    let x: DVector<f64> = svd
        .solve(&rhs, 0.0)
        .map_err(|_| Ellipsoid3Error::Degenerate)?
        .column(0)
        .into_owned();
    let o = Vector3::new(x[0], x[1], x[2]);
    let r2 = x[3] + o.norm_squared();
    if !(r2 > 0.0) {
        return Err(Ellipsoid3Error::Degenerate);
    }
    Ok(Ellipsoid {
        o,
        a: Matrix3::identity() / r2.sqrt(),
    })
}

/// The R factor (at most K × K, upper triangular) of the QR decomposition
/// of the matrix whose rows `row` gives for the points: the R of each
/// block of rows stacked on the next block and decomposed again.
fn streamed_r<const K: usize>(
    p: &[Vector3<f64>],
    row: impl Fn([f64; 3]) -> [f64; K],
) -> DMatrix<f64> {
    let mut r = DMatrix::<f64>::zeros(0, K);
    for block in p.chunks(BLOCK) {
        let above = r.nrows();
        let mut stacked = DMatrix::<f64>::zeros(above + block.len(), K);
        stacked.view_mut((0, 0), (above, K)).copy_from(&r);
        for (i, point) in block.iter().enumerate() {
            for (j, value) in row([point[0], point[1], point[2]]).into_iter().enumerate() {
                stacked[(above + i, j)] = value;
            }
        }
        r = stacked.qr().r();
    }
    r
}

/// Σ rowᵀrow over the points (K × K, symmetric): the scatter matrix DᵀD
/// of the design whose rows `row` gives, summed in blocks.
fn scatter<const K: usize>(p: &[Vector3<f64>], row: impl Fn([f64; 3]) -> [f64; K]) -> DMatrix<f64> {
    let mut total = [[0.0; K]; K];
    for block in p.chunks(BLOCK) {
        let mut part = [[0.0; K]; K];
        for point in block {
            let v = row([point[0], point[1], point[2]]);
            for a in 0..K {
                for b in a..K {
                    part[a][b] += v[a] * v[b];
                }
            }
        }
        for a in 0..K {
            for b in a..K {
                total[a][b] += part[a][b];
            }
        }
    }
    DMatrix::from_fn(K, K, |a, b| if a <= b { total[a][b] } else { total[b][a] })
}

/// S = DᵀD of Li & Griffiths' design D, whose row of a point is its
/// quadratic terms (x², y², z², then with `full` 2yz, 2xz, 2xy), then 2x,
/// 2y, 2z and 1.
fn li_griffiths_scatter(p: &[Vector3<f64>], full: bool) -> DMatrix<f64> {
    if full {
        scatter(p, |[x, y, z]| {
            [
                x * x,
                y * y,
                z * z,
                2.0 * y * z,
                2.0 * x * z,
                2.0 * x * y,
                2.0 * x,
                2.0 * y,
                2.0 * z,
                1.0,
            ]
        })
    } else {
        scatter(p, |[x, y, z]| {
            [x * x, y * y, z * z, 2.0 * x, 2.0 * y, 2.0 * z, 1.0]
        })
    }
}

/// Li & Griffiths' ellipsoid-specific fit. `full` selects the general
/// quadric (quadratic part a, b, c, d, e, f for x², y², z², 2yz, 2xz, 2xy)
/// or the axis-aligned one (a, b, c only); linear part 2gx, 2hy, 2iz and
/// the constant j. Minimises |Dv|² subject to kJ − I² = 1 (I = a + b + c,
/// J = ab + bc + ca − d² − e² − f²): the generalised eigenproblem
/// S̃ v1 = λ C1 v1 with S̃ = S11 − S12 S22⁻¹ S21 has exactly one positive
/// eigenvalue, whose eigenvector is the ellipsoid.
pub(super) fn li_griffiths(p: &[Vector3<f64>], full: bool) -> Result<Ellipsoid, Ellipsoid3Error> {
    let q = if full { 6 } else { 3 };
    let s = li_griffiths_scatter(p, full);
    let s11 = s.view((0, 0), (q, q)).into_owned();
    let s12 = s.view((0, q), (q, 4)).into_owned();
    let s22 = s.view((q, q), (4, 4)).into_owned();
    let s22_inv = s22.try_inverse().ok_or(Ellipsoid3Error::Degenerate)?;
    let reduced = &s11 - &s12 * &s22_inv * s12.transpose();
    let reduced = (&reduced + reduced.transpose()) / 2.0;
    // C1: the constraint's quadratic form on (a..f).
    let k = super::LI_GRIFFITHS_K;
    let mut c1 = DMatrix::<f64>::zeros(q, q);
    for i in 0..3 {
        for j in 0..3 {
            c1[(i, j)] = if i == j { -1.0 } else { k / 2.0 - 1.0 };
        }
    }
    for i in 3..q {
        c1[(i, i)] = -k;
    }
    // S̃ = L Lᵀ; L⁻¹ C1 L⁻ᵀ w = μ w with w = Lᵀ v, μ = 1/λ: symmetric.
    // Noiseless points make S̃ singular (the ellipsoid is its null
    // vector): a ridge at the arithmetic's precision keeps the Cholesky
    // factor and leaves that vector the solution.
    let ridge = super::RANK_TOLERANCE * (0..q).map(|i| reduced[(i, i)]).fold(0.0, f64::max);
    let chol = reduced
        .clone()
        .cholesky()
        .or_else(|| (reduced + DMatrix::identity(q, q) * ridge).cholesky())
        .ok_or(Ellipsoid3Error::Degenerate)?;
    let l = chol.l();
    let l_inv = l.clone().try_inverse().ok_or(Ellipsoid3Error::Degenerate)?;
    let m = &l_inv * &c1 * l_inv.transpose();
    let m = (&m + m.transpose()) / 2.0;
    let eig = SymmetricEigen::new(m);
    let (best, mu) =
        eig.eigenvalues
            .iter()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |acc, (i, &v)| {
                    if v > acc.1 { (i, v) } else { acc }
                },
            );
    if !(mu > 0.0) {
        return Err(Ellipsoid3Error::Degenerate);
    }
    let w = eig.eigenvectors.column(best).into_owned();
    let v1 = l_inv.transpose() * w;
    let v2 = -(&s22_inv * s12.transpose() * &v1);
    let quad = |i: usize| if i < q { v1[i] } else { 0.0 };
    let qm = Matrix3::new(
        quad(0),
        quad(5),
        quad(4),
        quad(5),
        quad(1),
        quad(3),
        quad(4),
        quad(3),
        quad(2),
    );
    let lin = Vector3::new(v2[0], v2[1], v2[2]);
    quadric_to_ellipsoid(qm, lin, v2[3])
}

/// pᵀQp + 2uᵀp + j = 0 → centre o = −Q⁻¹u, (p−o)ᵀ(Q/K)(p−o) = 1 with
/// K = oᵀQo − j, A = sqrt(Q/K).
fn quadric_to_ellipsoid(
    qm: Matrix3<f64>,
    u: Vector3<f64>,
    j: f64,
) -> Result<Ellipsoid, Ellipsoid3Error> {
    let (qm, u, j) = if qm.trace() < 0.0 {
        (-qm, -u, -j)
    } else {
        (qm, u, j)
    };
    let o = -(qm.try_inverse().ok_or(Ellipsoid3Error::Degenerate)? * u);
    let k = (o.transpose() * qm * o)[(0, 0)] - j;
    if !(k > 0.0) {
        return Err(Ellipsoid3Error::Degenerate);
    }
    let a = sqrt_spd(qm / k).ok_or(Ellipsoid3Error::Degenerate)?;
    Ok(Ellipsoid { o, a })
}

/// Square root of a symmetric positive definite matrix; `None` if it is
/// not positive definite.
fn sqrt_spd(m: Matrix3<f64>) -> Option<Matrix3<f64>> {
    let m = (m + m.transpose()) / 2.0;
    let eig = SymmetricEigen::new(m);
    if eig
        .eigenvalues
        .iter()
        .any(|&v| !(v > 0.0) || !v.is_finite())
    {
        return None;
    }
    let d = Matrix3::from_diagonal(&eig.eigenvalues.map(f64::sqrt));
    Some(eig.eigenvectors * d * eig.eigenvectors.transpose())
}

/// The closed-form ellipsoid of a model on scaled data.
pub(super) fn closed_form_scaled(
    p: &[Vector3<f64>],
    model: Ellipsoid3Model,
) -> Result<Ellipsoid, Ellipsoid3Error> {
    match model {
        Ellipsoid3Model::Offset => sphere_fit(p),
        Ellipsoid3Model::OffsetScale => li_griffiths(p, false),
        Ellipsoid3Model::Full => li_griffiths(p, true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points about an ellipsoid off the origin (semi-axes 1.2, 0.9 and 1,
    /// centre (0.1, −0.05, 0)), z squashed by `flat`, spread over the
    /// sphere of directions by golden-ratio steps.
    fn points(n: usize, flat: f64) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| {
                let (u, v) = (i as f64 * 0.618_034, i as f64 * 0.381_966 + 0.1);
                let e = (2.0 * (v % 1.0) - 1.0).asin();
                let a = std::f64::consts::TAU * (u % 1.0);
                Vector3::new(
                    1.2 * e.cos() * a.cos() + 0.1,
                    0.9 * e.cos() * a.sin() - 0.05,
                    flat * (e.sin() + 0.01 * (i as f64).sin()),
                )
            })
            .collect()
    }

    #[test]
    fn the_scatter_matrix_is_the_old_designs_own_product() {
        // The design the fit built before it summed the scatter matrix:
        // its columns in the order the constraint and the quadric read.
        for (full, q) in [(true, 6), (false, 3)] {
            let p = points(3 * BLOCK + 7, 1.0);
            let design = DMatrix::from_fn(p.len(), q + 4, |i, j| {
                let [x, y, z] = [p[i][0], p[i][1], p[i][2]];
                let quad = [x * x, y * y, z * z, 2.0 * y * z, 2.0 * x * z, 2.0 * x * y];
                if j < q {
                    quad[j]
                } else {
                    [2.0 * x, 2.0 * y, 2.0 * z, 1.0][j - q]
                }
            });
            let expected = design.transpose() * &design;
            let got = li_griffiths_scatter(&p, full);
            assert!(
                (got - &expected).norm() <= 1e-12 * expected.norm(),
                "full {full}"
            );
        }
    }

    /// The whole design's least squares and its rank test, as the sphere
    /// fit was before it was streamed: None when refused.
    fn sphere_by_whole_design(p: &[Vector3<f64>]) -> Option<DVector<f64>> {
        let n = p.len();
        let design = DMatrix::from_fn(n, 4, |i, j| if j < 3 { 2.0 * p[i][j] } else { 1.0 });
        let target = DVector::from_fn(n, |i, _| p[i].norm_squared());
        let svd = design.svd(true, true);
        if svd.singular_values.min() <= svd.singular_values.max() * super::super::RANK_TOLERANCE {
            return None;
        }
        svd.solve(&target, 0.0).ok()
    }

    #[test]
    fn the_streamed_sphere_fit_is_the_whole_designs_least_squares() {
        for n in [5, BLOCK, BLOCK + 1, 3 * BLOCK + 7] {
            let p = points(n, 1.0);
            let x = sphere_by_whole_design(&p).unwrap();
            let fitted = sphere_fit(&p).unwrap();
            for j in 0..3 {
                assert!((fitted.o[j] - x[j]).abs() <= 1e-12, "n {n}: o {j}");
            }
            let radius = (x[3] + x.rows(0, 3).norm_squared()).sqrt();
            assert!((1.0 / fitted.a[(0, 0)] - radius).abs() <= 1e-12, "n {n}: r");
        }
        // Flat clouds: a plane determines no sphere, nor does one within
        // the rank tolerance of a plane; one just outside it does. The
        // streamed fit refuses exactly where the whole design did.
        for flat in [0.0, 1e-13, 1e-12, 1e-8, 1e-6] {
            let p = points(2 * BLOCK + 3, flat);
            let whole = sphere_by_whole_design(&p).is_some();
            let streamed = sphere_fit(&p).is_ok();
            assert_eq!(streamed, whole, "flat {flat}");
            assert_eq!(streamed, flat >= 1e-8, "flat {flat}");
        }
    }
}

//! The triangle R of a tall, skinny matrix's QR decomposition, taken a
//! block of rows at a time: each block of rows is stacked under the R of
//! the rows before and reduced by Householder reflections to a new R
//! (a tall-skinny QR, as backward stable as one QR of all the rows).
//!
//! Written for the shape: the rows above a block are an upper triangle,
//! so the reflection of column `j` touches R's row `j` and the block only;
//! the reflector is the column itself, not scaled to unit length (no
//! division by each element); each column of the block is one contiguous
//! slice, so every pass is a plain loop over it.

/// Rows a block holds: a block of [`BLOCK`] rows of up to eight columns is
/// at most 256 KiB, and stays in the cache while its columns are swept.
pub const BLOCK: usize = 4096;
const _: () = assert!(BLOCK.is_power_of_two());

/// R (`K` × `K`, upper triangular, rows in order) of the rows fed to it so
/// far, and the block being filled.
#[derive(Debug)]
pub struct StreamedR<const K: usize> {
    r: [[f64; K]; K],
    /// The block, column by column.
    block: Box<[[f64; BLOCK]; K]>,
    /// Rows in the block.
    filled: usize,
}

impl<const K: usize> Default for StreamedR<K> {
    fn default() -> Self {
        StreamedR {
            r: [[0.0; K]; K],
            block: Box::new([[0.0; BLOCK]; K]),
            filled: 0,
        }
    }
}

impl<const K: usize> StreamedR<K> {
    /// Adds one row.
    pub fn push(&mut self, row: [f64; K]) {
        // (`filled` is below BLOCK, a power of two: the mask only shows
        // the compiler that every index is in bounds.)
        let at = self.filled & (BLOCK - 1);
        for (column, value) in self.block.iter_mut().zip(row) {
            column[at] = value;
        }
        self.filled += 1;
        if self.filled == BLOCK {
            self.absorb();
        }
    }

    /// R of every row pushed (its rows' signs are those the reflections
    /// gave: for columns of full rank, R is unique up to them).
    pub fn finish(mut self) -> [[f64; K]; K] {
        self.absorb();
        self.r
    }

    /// Reduces [R; block] to the new R, and empties the block.
    fn absorb(&mut self) {
        let m = self.filled;
        self.filled = 0;
        if m == 0 {
            return;
        }
        for j in 0..K {
            let (head, tail) = self.block.split_at_mut(j + 1);
            let column = &head[j][..m];
            let below = dot(column, column);
            if below == 0.0 {
                // Nothing under R's diagonal in this column: no reflection.
                continue;
            }
            // The reflection that takes (r_jj, column) to (beta, 0): its
            // axis v = (r_jj - beta, column), beta of the sign opposite to
            // r_jj's, so that r_jj - beta loses nothing to cancellation.
            let alpha = self.r[j][j];
            let norm = (alpha * alpha + below).sqrt();
            let beta = if alpha >= 0.0 { -norm } else { norm };
            let v0 = alpha - beta;
            let vv = v0 * v0 + below;
            for k in j + 1..K {
                let other = &mut tail[k - j - 1][..m];
                let c = 2.0 * (v0 * self.r[j][k] + dot(column, other)) / vv;
                self.r[j][k] -= c * v0;
                for (o, &v) in other.iter_mut().zip(column) {
                    *o -= c * v;
                }
            }
            self.r[j][j] = beta;
        }
    }
}

/// Σ aᵢbᵢ, in four running sums (which the compiler keeps in vector
/// registers).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut sums = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4
        .remainder()
        .iter()
        .zip(b4.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a4.zip(b4) {
        for i in 0..4 {
            sums[i] += x[i] * y[i];
        }
    }
    (sums[0] + sums[2]) + (sums[1] + sums[3]) + tail
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// R of all the rows in one Householder QR (nalgebra's), each row's
    /// sign made that of its diagonal (R is unique up to those).
    fn whole(rows: &[[f64; 5]]) -> [[f64; 5]; 5] {
        let r = DMatrix::from_fn(rows.len(), 5, |i, j| rows[i][j]).qr().r();
        std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)] * r[(i, i)].signum()))
    }

    fn streamed(rows: &[[f64; 5]]) -> [[f64; 5]; 5] {
        let mut s = StreamedR::<5>::default();
        for &row in rows {
            s.push(row);
        }
        let r = s.finish();
        std::array::from_fn(|i| std::array::from_fn(|j| r[i][j] * r[i][i].signum()))
    }

    fn assert_close(a: &[[f64; 5]; 5], b: &[[f64; 5]; 5], what: &str) {
        let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        for i in 0..5 {
            for j in 0..5 {
                assert!(
                    (a[i][j] - b[i][j]).abs() <= 1e-12 * scale,
                    "{what}: R[{i}][{j}] {} streamed, {} at once",
                    a[i][j],
                    b[i][j]
                );
            }
            for (j, below) in a[i].iter().enumerate().take(i) {
                assert_eq!(*below, 0.0, "{what}: R[{i}][{j}] below the diagonal");
            }
        }
    }

    /// Streamed, R is that of one QR of all the rows: within a block, at
    /// a block and a row, and over several blocks and a part (an R that
    /// lost the blocks before, or the last part, would be far off).
    #[test]
    fn the_streamed_triangle_is_that_of_one_qr() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for n in [5, 100, BLOCK, BLOCK + 1, 3 * BLOCK + 17] {
            let rows: Vec<[f64; 5]> = (0..n)
                .map(|_| {
                    let u: f64 = rng.random_range(-1.0..1.0);
                    let v: f64 = rng.random_range(-1.0..1.0);
                    [u * u, u, v, 1.0, v * v + 0.1 * u]
                })
                .collect();
            assert_close(&streamed(&rows), &whole(&rows), &format!("n = {n}"));
        }
    }

    /// A column with nothing under the diagonal (all zero) is left as it
    /// is, and the others still reduce: R is not unique then (a row of
    /// zeros may sit anywhere below), but RᵀR is still the rows' AᵀA.
    #[test]
    fn a_zero_column_needs_no_reflection() {
        let rows: Vec<[f64; 5]> = (0..BLOCK + 9)
            .map(|i| {
                let t = i as f64 * 0.01;
                [t.sin(), 0.0, t.cos(), 1.0, t]
            })
            .collect();
        let r = streamed(&rows);
        for a in 0..5 {
            for b in 0..5 {
                let rtr: f64 = (0..5).map(|k| r[k][a] * r[k][b]).sum();
                let ata: f64 = rows.iter().map(|row| row[a] * row[b]).sum();
                assert!(
                    (rtr - ata).abs() <= 1e-9 * ata.abs().max(1.0),
                    "(RᵀR)[{a}][{b}] {rtr}, AᵀA {ata}"
                );
            }
            assert_eq!(r[1][a], 0.0, "the zero column's row");
        }
    }
}

//! A CSV of numbers with a header, read by column name: the real
//! recordings of `../shared/data/real/`, as the tests take them apart.

use std::path::Path;

pub struct Table {
    pub names: Vec<String>,
    pub rows: Vec<Vec<f64>>,
}

impl Table {
    pub fn read(path: &Path) -> Table {
        let text =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut lines = text.lines();
        let names = lines.next().unwrap().split(',').map(String::from).collect();
        let rows = lines
            .filter(|l| !l.is_empty())
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        Table { names, rows }
    }

    /// The recording `file` of the run `run` of the sunsided set.
    pub fn sunsided(run: &str, file: &str) -> Table {
        Table::read(&super::shared_path(&format!(
            "data/real/sunsided-set-1/{run}/{file}"
        )))
    }

    pub fn col(&self, name: &str) -> Vec<f64> {
        let j = self.names.iter().position(|n| n == name).unwrap();
        self.rows.iter().map(|r| r[j]).collect()
    }

    /// Columns `a` and `b` of the rows whose t_s lies in [from, to).
    pub fn pair(&self, a: &str, b: &str, from: f64, to: f64) -> (Vec<f64>, Vec<f64>) {
        let t = self.col("t_s");
        let (xa, xb) = (self.col(a), self.col(b));
        (0..t.len())
            .filter(|&i| t[i] >= from && t[i] < to)
            .map(|i| (xa[i], xb[i]))
            .unzip()
    }
}
